"""The one shell around a training run, shared by ``gnn-mp train sampler``, ``train rl`` and
``train critical``: the run directory, ``config.json``, TensorBoard, the learning curve, the
checkpoint with its ``.json`` sidecar, and shipping into the package.

    run = TrainingRun.create("tree", "maze2d-gnn", seed=0)      # runs/tree/maze2d-gnn-seed0-<time>/
    run.write_config({...})                                     # config.json (plain values, atomic)
    run.writer.add_scalar("phase0/val_loss", 1.2, 1)            # runs/.../tb/
    ckpt = run.save_checkpoint("model.pt", model, "tree/gnn", ctor_args, meta={...})   # + model.json
    plot_learning_curve(run.path("learning_curve.png"), ...)
    run.ship(ckpt, "gnn", task="maze2d")                        # agents/checkpoints/gnn_maze2d.pt + .json

A fresh run never reuses a directory: the default name carries a timestamp (and ``-2``, ``-3``,
... when two runs start within a second), and a named ``--out`` that already holds a run is
refused unless the caller resumes it or passes ``overwrite``. Nothing trains into the shipped
directory; only :meth:`TrainingRun.ship` writes there, and it reads the file back first.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from gnn_mp_envs.utils.io import atomic_path, atomic_write_bytes, atomic_write_text
from train.args import UsageError, arg, positive_int, worker_count

#: Where run directories go by default: runs/<family>/<name>-seed<S>-<YYYYmmdd-HHMMSS>/.
RUNS_ROOT = Path("runs")
#: Files whose presence marks a directory as holding a finished or started run.
RUN_MARKERS = ("config.json",)


class RunError(UsageError):
    """A user-facing error about a run (its directory, a loss or policy gone non-finite): one line."""


def finite_loss(loss, where: str, lr: float) -> float:
    """``loss`` as a float, or a one-line :class:`RunError` when it is NaN or infinite (a learning
    rate too large for the model: stop before non-finite weights are saved)."""
    value = float(loss.detach())
    if not math.isfinite(value):
        raise RunError(f"the training loss became {value} at {where} (learning rate {lr:g}): lower --lr; "
                       "nothing was saved from this phase")
    return value


def non_finite_policy(exc: ValueError, lr: float) -> RunError | None:
    """A one-line :class:`RunError` for torch's refusal of a distribution over NaN parameters (a
    learning rate that drove an RL policy's weights to NaN), else None (another ValueError)."""
    text = str(exc)
    if not (text.startswith("Expected parameter") and "invalid values" in text):
        return None
    return RunError(f"the policy's outputs became NaN during training (learning rate {lr:g}): lower --lr; the "
                    "last evaluated policy stays in policy.pt")


@dataclass
class RunFlags:
    """The flags of the run shell, shared by ``gnn-mp train sampler`` and ``gnn-mp train rl``."""

    out: Path | None = arg(None, "run directory (default: a fresh runs/<family>/<name>-seed<S>-<time>/)")
    overwrite: bool = arg(False, "reuse an --out that already holds a run")
    ship: bool = arg(False, "also copy the result into the package's shipped weights "
                     "(agents/checkpoints/<name>_<task>.pt + .json)")
    threads: int = arg(1, "torch threads (the machine is shared: keep 1)", parse=worker_count)
    modules: list[str] = arg([], "import MODULE first: it registers a task (repeatable)", flag="--import",
                             metavar="MODULE", append=True)
    progress: bool = arg(True, "hide progress bars")


def shipped_dir() -> Path:
    from agents.checkpoints import SHIPPED_DIR
    return SHIPPED_DIR


def inside(path: Path, directory: Path) -> bool:
    try:
        Path(path).resolve().relative_to(Path(directory).resolve())
        return True
    except ValueError:
        return False


class TrainingRun:
    """A run directory and the files every training command writes into it."""

    def __init__(self, directory: Path) -> None:
        self.dir = Path(directory)
        self._writer = None

    # ------------------------------------------------------------------ directories
    @classmethod
    def create(cls, family: str, name: str, seed: int, *, out: Path | None = None, resume: bool = False,
               overwrite: bool = False, root: Path = RUNS_ROOT, now: float | None = None) -> "TrainingRun":
        """The run's directory: ``out`` if given, else a fresh ``root/family/name-seed<S>-<time>``.

        ``resume`` continues ``out`` (which must exist); an ``out`` holding another run is
        refused unless ``overwrite``; an ``out`` inside the shipped directory always is.
        """
        if out is not None:
            out = Path(out)
            if inside(out, shipped_dir()):
                raise RunError(f"--out {out} is inside the shipped checkpoint directory {shipped_dir()}; "
                               "train elsewhere and pass --ship to copy the result there")
            if resume and not out.is_dir():
                raise RunError(f"--resume: {out} is not a run directory")
            if not resume and not overwrite and any((out / m).exists() for m in RUN_MARKERS):
                raise RunError(f"--out {out} already holds a run; pass --resume to continue it, --overwrite to "
                               "replace it, or another --out")
            directory = out
        else:
            if resume:
                raise RunError("--resume needs --out RUN_DIR (the run to continue)")
            stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
            base = Path(root) / family / f"{name}-seed{seed}-{stamp}"
            directory, k = base, 1
            while directory.exists():
                k += 1
                directory = base.with_name(f"{base.name}-{k}")
        directory.mkdir(parents=True, exist_ok=True)
        return cls(directory)

    def path(self, name: str) -> Path:
        return self.dir / name

    def check_resumed_flags(self, current: Mapping[str, Any], free: Sequence[str]) -> None:
        """Refuse, in one line, a ``--resume`` whose flags differ from the run's ``config.json``
        (other than the ``free`` ones, e.g. the step budget): the saved weights may not fit, and a
        changed learning rate or discount would otherwise be ignored without a word."""
        path = self.path("config.json")
        try:
            stored = json.loads(path.read_text())
        except (OSError, ValueError):
            raise RunError(f"--resume: {path} is missing or unreadable; start a new --out") from None
        for key, value in _jsonable(dict(current)).items():
            if key not in free and key in stored and stored[key] != value:
                flag = "--" + key.replace("_", "-")
                raise RunError(f"--resume: {flag} is {value!r} here but {stored[key]!r} in {path}; resume with the "
                               f"run's flags or start a new --out")

    # ------------------------------------------------------------------ files
    def write_config(self, config: Mapping[str, Any], name: str = "config.json") -> Path:
        """``config`` (plain values: paths become strings) as indented JSON, atomically."""
        from agents.checkpoints import plain
        path = self.path(name)
        atomic_write_text(path, json.dumps(plain(_jsonable(config), "config"), indent=2) + "\n")
        return path

    @property
    def writer(self):
        """A TensorBoard ``SummaryWriter`` on ``tb/`` (created on first use)."""
        if self._writer is None:
            from torch.utils.tensorboard import SummaryWriter
            self._writer = SummaryWriter(str(self.path("tb")))
        return self._writer

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def save_checkpoint(self, name: str, model: Any, kind: str, ctor_args: Mapping[str, Any], *,
                        obs_spec: Mapping[str, Any] | None = None, meta: Mapping[str, Any] | None = None) -> Path:
        """``name`` (the one checkpoint format) and its ``.json`` sidecar holding ``meta``."""
        from agents.checkpoints import plain, save_checkpoint
        meta = plain(_jsonable(meta or {}), "meta")
        path = save_checkpoint(self.path(name), model, kind, ctor_args, obs_spec=obs_spec, meta=meta)
        atomic_write_text(path.with_suffix(".json"), json.dumps({"kind": kind, **meta}, indent=2) + "\n")
        return path

    def ship(self, checkpoint: Path, name: str, task: str | None = None,
             expected_kind: str | Sequence[str] | None = None) -> Path:
        """Copy ``checkpoint`` and its ``.json`` sidecar into the package as the shipped weights of
        ``name`` for ``task`` (:func:`agents.checkpoints.shipped_checkpoint`); the file is read
        back (kind checked) before anything is written."""
        from agents.checkpoints import load_checkpoint, read_checkpoint, shipped_checkpoint
        checkpoint = Path(checkpoint)
        if not checkpoint.is_file():
            raise RunError(f"--ship: no checkpoint was written at {checkpoint}")
        load_checkpoint(checkpoint, expected_kind=expected_kind)
        target = shipped_checkpoint(name, task)
        sidecar = checkpoint.with_suffix(".json")
        side = sidecar.read_bytes() if sidecar.is_file() else (
            json.dumps(read_checkpoint(checkpoint)["meta"], indent=2) + "\n").encode()
        atomic_write_bytes(target, checkpoint.read_bytes())
        atomic_write_bytes(target.with_suffix(".json"), side)
        print(f"shipped {checkpoint} -> {target}", flush=True)
        return target


def plot_learning_curve(path: Path, series: Mapping[str, tuple[Sequence[float], Sequence[float]]], *,
                        xlabel: str, ylabel: str, title: str = "",
                        right: Mapping[str, tuple[Sequence[float], Sequence[float]]] | None = None,
                        right_label: str = "", right_limits: tuple[float, float] | None = None,
                        vlines: Sequence[float] = ()) -> Path | None:
    """The learning curve of a run (PNG, atomic): ``series`` label -> (x, y) on the left axis,
    ``right`` on a second axis, dotted vertical lines at ``vlines`` (phase boundaries)."""
    if not any(len(x) for x, _ in series.values()):
        return None
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5.6, 3.4))
    colors = iter(["tab:blue", "tab:orange", "tab:purple", "tab:red"])
    for label, (x, y) in series.items():
        ax.plot(x, y, "o-" if len(x) < 30 else "-", color=next(colors), label=label, markersize=3)
    for v in vlines:
        ax.axvline(v, color="0.6", linestyle=":", linewidth=1)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    if right:
        ax2 = ax.twinx()
        for label, (x, y) in right.items():
            ax2.plot(x, y, "s--", color="tab:green", label=label, markersize=3)
        ax2.set_ylabel(right_label)
        if right_limits is not None:
            ax2.set_ylim(*right_limits)
        h2, l2 = ax2.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    ax.legend(handles, labels, fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return Path(path)


def _jsonable(value: Any) -> Any:
    """Paths as strings, tuples as lists, recursively (what ``json`` and ``plain`` accept)."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


__all__ = ["RUNS_ROOT", "RunError", "RunFlags", "TrainingRun", "plot_learning_curve"]
