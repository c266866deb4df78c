"""Checkpoints of every learned model: one file format, loaded with ``weights_only=True`` only.

This package is also where the small shipped weights live (``<sampler>_<task>.pt`` and
``critical_<model>.pt``, a ``.json`` sidecar each, :data:`SHIPPED_DIR`, :func:`shipped_checkpoint`).

A checkpoint is a ``torch.save`` of a dict holding plain types and tensors only, so that
``torch.load(weights_only=True)`` reads it and no pickled code ever runs::

    {"format_version": 1,            # FORMAT_VERSION; newer files are refused
     "kind": "critical/gnn",         # registered model kind -> constructor
     "ctor_args": {...},             # keyword arguments of the constructor (defaults filled in)
     "obs_spec": None | {...},       # what observation the model reads (samplers, policies)
     "state_dict": {...},            # the weights
     "meta": {...}}                  # free-form: training settings, history, scores

    save_checkpoint(path, model, "critical/gnn", {"hidden_channels": 32, ...}, meta={...})
    model, record = load_checkpoint(path, expected_kind="critical/gnn")   # eval mode, CPU

Model kinds are registered with :func:`register_model_kind` by the module that defines the
model (``agents.critical.models`` registers ``critical/<name>`` on import); the loader
imports :data:`BUILTIN_KIND_MODULES` first, so every built-in kind is known. Anything wrong with a
file (missing, empty, truncated, random bytes, not a checkpoint, newer format, unknown kind,
another kind than expected, weights that do not fit) raises :class:`CheckpointError` with
one line naming the file. An SB3 ``.zip`` of a ``gnn-mp train rl`` run reads as the record of its
policy, weights only (:data:`FOREIGN_READERS`, :mod:`agents.rl.sb3_files`). Files are written atomically (a temporary file beside the target,
then a rename), see :mod:`gnn_mp_envs.utils.io`.

:func:`save_training_state` / :func:`load_training_state` store resume states (optimizer
state dicts, epoch, history) with the same guarantees.
"""

from __future__ import annotations

import errno
import importlib
import inspect
import math
import pickle
import zipfile
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from gnn_mp_envs.utils.imports import import_entry
from gnn_mp_envs.utils.io import atomic_path

#: Version of the record layout written by :func:`save_checkpoint`; readers refuse newer ones.
FORMAT_VERSION = 1
#: The keys of a checkpoint record.
RECORD_KEYS = ("format_version", "kind", "ctor_args", "obs_spec", "state_dict", "meta")
#: Where the shipped weights live (this package's directory).
SHIPPED_DIR = Path(__file__).resolve().parent
#: Modules imported before a kind is looked up; each registers its kinds on import.
BUILTIN_KIND_MODULES = ("agents.tree.models", "agents.tree.scorer", "agents.rl.policies", "agents.critical.models")

#: Files of other libraries read as checkpoints, weights only: format -> ``module:function`` turning the
#: file into a record (imported when such a file is read; :func:`foreign_format` recognises them).
FOREIGN_READERS = {"sb3-zip": "agents.rl.sb3_files:sb3_zip_record"}

_KINDS: dict[str, Callable[..., nn.Module]] = {}


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used; the message is one line naming the file."""


def shipped_checkpoint(name: str, task: str | None = None) -> Path:
    """Where the package ships the weights of ``name`` (a sampler, ``critical_<model>``) for
    ``task``: ``<name>_<task>.pt`` (``<name>.pt`` without a task), a ``.json`` sidecar beside it."""
    return SHIPPED_DIR / (f"{name}_{task}.pt" if task else f"{name}.pt")


def resolve_checkpoint(name: str, task: str | None, checkpoint: str | Path | None, train_command: str) -> Path:
    """The file a learned sampler loads: ``checkpoint`` if given, else its shipped file for
    ``task``; a missing one is refused with the command that trains it."""
    if checkpoint is not None:
        if not Path(checkpoint).is_file():
            raise FileNotFoundError(f"{checkpoint}: no such checkpoint file")
        return Path(checkpoint)
    if task is None:
        raise ValueError(f"sampler {name!r} needs task= (its shipped weights are per task) or checkpoint=PATH")
    shipped = shipped_checkpoint(name, task)
    source = _weights_source(task)
    if not shipped.is_file() and source is not None and shipped_checkpoint(name, source).is_file():
        return shipped_checkpoint(name, source)        # a task that borrows another's weights
    if not shipped.is_file():
        raise FileNotFoundError(f"no shipped {name} weights for task {task!r} ({shipped.name}); "
                                f"train them with `{train_command}` and pass checkpoint=PATH (gnn-mp benchmark: "
                                f"--checkpoint {name}=PATH)")
    return shipped


def _weights_source(task: str) -> str | None:
    """``TaskSpec.weights_from`` of ``task`` (None for an unknown task)."""
    from gnn_mp_envs.registration import TASK_SPECS
    spec = TASK_SPECS.get(task)
    return None if spec is None else spec.weights_from


def check_trained_for(path: str | Path, trained_for: str | None, task: str | None) -> None:
    """Refuse weights trained for another task, in one line; a task whose ``TaskSpec.weights_from``
    names the weights' task takes them if both tasks have the same state bounds."""
    if task is None or trained_for is None or trained_for == task:
        return
    if _weights_source(task) != trained_for:
        raise ValueError(f"{path}: weights trained for task {trained_for!r}, not {task!r} (a task in the same "
                         f"state space can use them with TaskSpec(weights_from={trained_for!r}))")
    from gnn_mp_envs.registration import same_bounds, task_spec
    mine, theirs = task_spec(task).state_bounds(), task_spec(trained_for).state_bounds()
    if not same_bounds(mine, theirs):
        raise ValueError(f"{path}: task {task!r} takes weights from {trained_for!r}, but their state bounds differ "
                         f"({mine[0].tolist()}..{mine[1].tolist()} vs {theirs[0].tolist()}..{theirs[1].tolist()})")


def register_model_kind(kind: str, cls: Callable[..., nn.Module], *, overwrite: bool = False) -> None:
    """Make ``kind`` loadable: :func:`load_checkpoint` builds it as ``cls(**ctor_args)``."""
    if not isinstance(kind, str) or not kind:
        raise ValueError(f"a model kind is a non-empty string, got {kind!r}")
    if kind in _KINDS and _KINDS[kind] is not cls and not overwrite:
        raise ValueError(f"model kind {kind!r} is already registered to {_KINDS[kind]!r}")
    _KINDS[kind] = cls


def model_kinds() -> list[str]:
    """Every registered model kind (built-in ones included)."""
    _import_builtin_kinds()
    return sorted(_KINDS)


def _import_builtin_kinds() -> None:
    for module in BUILTIN_KIND_MODULES:
        importlib.import_module(module)


# ----------------------------------------------------------------------------- plain values


def plain(value: Any, where: str = "value") -> Any:
    """``value`` as plain types ``torch.load(weights_only=True)`` accepts (for ctor args, meta).

    dicts (string keys), lists, tuples, str, int, float, bool and None pass; numpy scalars and
    arrays become Python numbers and lists, paths become strings. Anything else raises
    ``TypeError`` naming where it was found.
    """
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, (str, int)):
                raise TypeError(f"{where}: key {k!r} is not a string")
            out[k] = plain(v, f"{where}[{k!r}]")
        return out
    if isinstance(value, (list, tuple)):
        items = [plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if isinstance(value, tuple) else items
    if hasattr(value, "tolist") and type(value).__module__ == "numpy":   # numpy scalar / array
        return plain(value.tolist(), where)
    raise TypeError(f"{where}: {type(value).__name__} is not a plain value "
                    "(use dicts, lists, str, int, float, bool, None)")


def _complete_ctor_args(cls: Callable[..., nn.Module], ctor_args: Mapping[str, Any], kind: str) -> dict:
    """``ctor_args`` with the constructor's remaining defaults filled in (checked to bind)."""
    try:
        sig = inspect.signature(cls)
    except (TypeError, ValueError):   # no introspectable signature: keep what was given
        return dict(ctor_args)
    try:
        bound = sig.bind(**ctor_args)
    except TypeError as exc:
        raise TypeError(f"constructor arguments do not fit {kind}: {exc}") from None
    bound.apply_defaults()
    params = sig.parameters
    out = {}
    for name, value in bound.arguments.items():
        if params[name].kind is inspect.Parameter.VAR_KEYWORD:
            out.update(value)
        elif params[name].kind is not inspect.Parameter.VAR_POSITIONAL:
            out[name] = value
    return out


# ----------------------------------------------------------------------------- saving


def _save_named(record: Mapping[str, Any], tmp: Path, path: Path) -> None:
    """``torch.save(record, tmp)``; a failed write (disk full, file-size limit: torch raises a
    ``RuntimeError`` from its stream writer) becomes an ``OSError`` naming ``path``, which the
    CLIs print as one line."""
    try:
        torch.save(record, tmp)
    except RuntimeError as exc:
        raise OSError(errno.EIO, f"could not write the checkpoint ({str(exc).splitlines()[0]})", str(path)) from None


def _write(record: Mapping[str, Any], path: Path) -> None:
    """``record`` to ``path`` atomically (a temporary file renamed into place)."""
    with atomic_path(path) as tmp:
        _save_named(record, tmp, path)


def checkpoint_record(model: nn.Module | Mapping[str, torch.Tensor], kind: str, ctor_args: Mapping[str, Any], *,
                      obs_spec: Mapping[str, Any] | None = None, meta: Mapping[str, Any] | None = None) -> dict:
    """The record :func:`save_checkpoint` writes (what :func:`read_checkpoint` returns), in memory."""
    _import_builtin_kinds()
    if kind not in _KINDS:
        raise ValueError(f"unknown model kind {kind!r}; known: {', '.join(sorted(_KINDS))}")
    cls = _KINDS[kind]
    if isinstance(model, nn.Module):
        if isinstance(cls, type) and not isinstance(model, cls):
            raise TypeError(f"a {type(model).__name__} is not a {kind} model ({cls.__name__})")
        state = model.state_dict()
    else:
        state = model
    if not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
        raise TypeError("the state dict must map names to tensors")
    return {
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "ctor_args": plain(_complete_ctor_args(cls, plain(dict(ctor_args), "ctor_args"), kind), "ctor_args"),
        "obs_spec": None if obs_spec is None else plain(dict(obs_spec), "obs_spec"),
        "state_dict": {k: v.detach().cpu() for k, v in state.items()},
        "meta": plain(dict(meta or {}), "meta"),
    }


def save_checkpoint(path: str | Path, model: nn.Module | Mapping[str, torch.Tensor], kind: str,
                    ctor_args: Mapping[str, Any], *, obs_spec: Mapping[str, Any] | None = None,
                    meta: Mapping[str, Any] | None = None) -> Path:
    """Write ``model`` (a module or its state dict) as a ``kind`` checkpoint; returns the path.

    ``ctor_args`` must rebuild the model with the registered constructor of ``kind``; the
    constructor's defaults are stored too, so a later change of a default does not change
    what the file loads as. ``ctor_args``, ``obs_spec`` and ``meta`` must be plain values
    (:func:`plain`). The file is written to a temporary name in the same directory and
    renamed into place.
    """
    record = checkpoint_record(model, kind, ctor_args, obs_spec=obs_spec, meta=meta)
    path = Path(path)
    _write(record, path)
    return path


def save_training_state(path: str | Path, state: Mapping[str, Any]) -> Path:
    """Write a resume state (tensors, optimizer state dicts, numbers, lists, dicts) atomically.

    Only what ``torch.load(weights_only=True)`` reads back is accepted; check with
    :func:`load_training_state`.
    """
    path = Path(path)
    _write({"format_version": FORMAT_VERSION, "training_state": dict(state)}, path)
    return path


# ----------------------------------------------------------------------------- loading


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    first = text[0].strip() if text else ""
    if len(first) > 100:
        first = first[:97] + "..."
    name = type(exc).__name__
    return f"{name}: {first}" if first else name


def foreign_format(path: str | Path) -> str | None:
    """``"sb3-zip"`` for a Stable-Baselines3 ``.zip`` (``model.save``: members ``data`` and
    ``policy.pth``), None for anything else (a ``torch.save`` file is a zip too, laid out otherwise)."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return None
    return "sb3-zip" if {"data", "policy.pth"} <= names else None


def _read(path: Path) -> Any:
    """``torch.load(weights_only=True)`` with every failure turned into one CheckpointError line (a
    file of :data:`FOREIGN_READERS`, an SB3 ``.zip``, is turned into a record by its reader, weights only)."""
    if not path.exists():
        raise CheckpointError(f"{path}: no such checkpoint file")
    if path.is_dir():
        raise CheckpointError(f"{path}: is a directory, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(f"{path}: not a regular file, not a checkpoint")
    size = path.stat().st_size
    if size == 0:
        raise CheckpointError(f"{path}: empty file, not a checkpoint")
    foreign = foreign_format(path)
    if foreign is not None:
        return import_entry(FOREIGN_READERS[foreign])(path)
    try:
        return torch.load(path, weights_only=True, map_location="cpu")
    except pickle.UnpicklingError as exc:
        # weights_only refuses anything but tensors and plain containers: code, classes, ...
        lines = [ln.strip() for ln in str(exc).splitlines()]
        detail = next((ln for ln in lines if "GLOBAL" in ln or "Unsupported global" in ln), None)
        if detail:
            raise CheckpointError(f"{path}: refused, it holds more than weights and plain values "
                                  f"(loading would import or run code): {detail[:120]}") from None
        raise CheckpointError(f"{path}: not a readable checkpoint (truncated, corrupt or not written by "
                              f"torch.save; {size} bytes)") from None
    except (EOFError, OSError, RuntimeError, ValueError, zipfile.BadZipFile, KeyError, IndexError,
            AttributeError, TypeError, UnicodeDecodeError, OverflowError, MemoryError) as exc:
        if isinstance(exc, OSError) and exc.filename and exc.errno not in (None, 22):
            raise CheckpointError(f"{path}: cannot read: {exc.strerror or exc}") from None
        raise CheckpointError(f"{path}: not a readable checkpoint (truncated, corrupt or not written by "
                              f"torch.save; {size} bytes; {type(exc).__name__})") from None


def _check_version(path: Path, record: Any, what: str) -> None:
    if not isinstance(record, dict) or "format_version" not in record:
        keys = sorted(map(str, record)) if isinstance(record, dict) else type(record).__name__
        legacy = " (an old-format critical checkpoint: convert it)" if isinstance(record, dict) and \
            {"model", "hparams", "state_dict"} <= set(record) else ""
        raise CheckpointError(f"{path}: not a {what} (no format_version; found {keys}){legacy}")
    version = record["format_version"]
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise CheckpointError(f"{path}: unknown format version {version!r}")
    if version > FORMAT_VERSION:
        raise CheckpointError(f"{path}: format version {version} is newer than this code reads "
                              f"({FORMAT_VERSION}); update gnn-mp-envs")


def read_checkpoint(path: str | Path, expected_kind: str | Collection[str] | None = None) -> dict:
    """The validated record of a checkpoint file, without building the model."""
    path = Path(path)
    record = _read(path)
    _check_version(path, record, "checkpoint")
    missing = [k for k in RECORD_KEYS if k not in record]
    if missing:
        raise CheckpointError(f"{path}: not a checkpoint (missing keys: {', '.join(missing)})")
    kind = record["kind"]
    if not isinstance(kind, str):
        raise CheckpointError(f"{path}: not a checkpoint (kind is {type(kind).__name__}, not a string)")
    if not isinstance(record["ctor_args"], dict) or not isinstance(record["state_dict"], dict):
        raise CheckpointError(f"{path}: not a checkpoint (ctor_args and state_dict must be dicts)")
    if expected_kind is not None:
        allowed = [expected_kind] if isinstance(expected_kind, str) else list(expected_kind)
        if kind not in allowed:
            raise CheckpointError(f"{path}: holds a {kind!r} model, expected "
                                  f"{' or '.join(repr(k) for k in allowed)}")
    _import_builtin_kinds()
    if kind not in _KINDS:
        raise CheckpointError(f"{path}: unknown model kind {kind!r} (known: {', '.join(sorted(_KINDS))})")
    return record


def _state_mismatch(model: nn.Module, state: Mapping[str, Any]) -> str | None:
    """One line describing why ``state`` does not fit ``model``, or None."""
    own = model.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    def shape(v: Any) -> str:
        return str(tuple(v.shape)) if isinstance(v, torch.Tensor) else type(v).__name__

    shapes = [f"{k} {shape(state[k])} vs {shape(own[k])}" for k in own
              if k in state and (not isinstance(state[k], torch.Tensor) or state[k].shape != own[k].shape)]
    parts = []
    for label, items in (("missing", missing), ("unexpected", unexpected), ("shape mismatch", shapes)):
        if items:
            more = f" (+{len(items) - 3} more)" if len(items) > 3 else ""
            parts.append(f"{label}: {', '.join(items[:3])}{more}")
    return "; ".join(parts) or None


def load_checkpoint(path: str | Path, expected_kind: str | Collection[str] | None = None
                    ) -> tuple[nn.Module, dict]:
    """``(model, record)`` from a checkpoint file: the model is built, loaded and in eval mode.

    Reads with ``torch.load(weights_only=True, map_location="cpu")`` only. ``expected_kind``
    (a kind or several) refuses files holding another model. Raises :class:`CheckpointError`
    (one line, naming the file) for anything unusable.
    """
    path = Path(path)
    record = read_checkpoint(path, expected_kind)
    kind = record["kind"]
    # the stored weights checked against a skeleton on the meta device first: constructor arguments
    # of a crafted file (hidden_channels=4096) cannot allocate gigabytes before they are refused
    try:
        with torch.device("meta"):
            skeleton = _KINDS[kind](**record["ctor_args"])
    except Exception:        # a constructor that cannot run on meta tensors: checked after building
        skeleton = None
    problem = _state_mismatch(skeleton, record["state_dict"]) if isinstance(skeleton, nn.Module) else None
    if problem:
        raise CheckpointError(f"{path}: weights do not fit {kind}: {problem}")
    try:
        model = _KINDS[kind](**record["ctor_args"])
    except (TypeError, ValueError, KeyError, RuntimeError, AssertionError) as exc:
        raise CheckpointError(f"{path}: constructor arguments do not fit {kind}: {_one_line(exc)}") from None
    problem = _state_mismatch(model, record["state_dict"])
    if problem:
        raise CheckpointError(f"{path}: weights do not fit {kind}: {problem}")
    try:
        model.load_state_dict(record["state_dict"])
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: weights do not fit {kind}: {_one_line(exc)}") from None
    model.eval()
    return model, record


def load_training_state(path: str | Path) -> dict:
    """A resume state written by :func:`save_training_state` (``weights_only=True``)."""
    path = Path(path)
    record = _read(path)
    _check_version(path, record, "training state")
    if not isinstance(record.get("training_state"), dict):
        raise CheckpointError(f"{path}: not a training state (missing key: training_state)")
    return record["training_state"]


def count_parameters(state: Mapping[str, torch.Tensor]) -> int:
    """Number of values in a state dict."""
    return int(sum(math.prod(v.shape) for v in state.values()))


__all__ = ["FORMAT_VERSION", "FOREIGN_READERS", "SHIPPED_DIR", "CheckpointError", "checkpoint_record", "count_parameters",
           "foreign_format", "load_checkpoint",
           "load_training_state", "model_kinds", "plain", "read_checkpoint", "register_model_kind",
           "resolve_checkpoint", "save_checkpoint", "save_training_state", "shipped_checkpoint"]
