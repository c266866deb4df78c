"""Argument parsing shared by the ``gnn-mp`` entry points.

Each entry point keeps its flags in one dataclass (CleanRL's habit): a field's default,
type and help text are written once, next to each other, and :func:`add_dataclass_arguments`
turns them into argparse flags. :func:`from_namespace` builds the dataclass back from the
parsed flags, so the training and benchmark functions take the dataclass, not ``argparse``.

    @dataclass
    class Args:
        epochs: int = arg(20, "passes over the training set")
        out: Path | None = arg(None, "checkpoint file (default: a run directory)")

    parser = OneLineParser(prog="gnn-mp thing")
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))

It also holds what every entry point shares about bad input: :class:`UsageError` and the checks
of flags more than one entry point takes (:func:`check_output_path`, :func:`check_ray_address`).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import types
import typing
from pathlib import Path
from typing import Any, Callable


class UsageError(Exception):
    """A user-facing error (bad flags, unknown names, missing or unwritable files): one line on
    stderr, exit status 2, no traceback."""


class OneLineParser(argparse.ArgumentParser):
    """argparse, but errors are a single line on stderr (usage stays available via --help);
    ``--help`` shows every flag's default."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", argparse.ArgumentDefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def arg(default: Any, help: str, *, flag: str | tuple[str, ...] | None = None,
        choices: typing.Sequence[Any] | None = None, metavar: str | None = None,
        parse: Callable[[str], Any] | None = None, append: bool = False, const: Any = None) -> Any:
    """A dataclass field carrying its command-line help (and optional flag name(s), choices, parser).

    ``append``: the flag may be repeated, each value parsed on its own (a ``dict`` field
    collects ``(key, value)`` pairs). ``const``: the flag's value may be left out and then is
    ``const``. Mutable defaults are copied per instance.
    """
    meta = {"help": help, "flag": flag, "choices": choices, "metavar": metavar, "parse": parse,
            "append": append, "const": const}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


# ---------------------------------------------------------------------------- value parsers
def bounded(cast: Callable[[str], float], minimum: float, strict: bool, noun: str,
            maximum: float | None = None) -> Callable[[str], float]:
    """An argparse type: ``cast(text)`` that must be ``> minimum`` (strict) or ``>= minimum``, and at
    most ``maximum`` (a count or size beyond it would exhaust the machine rather than run)."""
    def parse(text: str):
        try:
            value = cast(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if not (value > minimum if strict else value >= minimum) or (
                isinstance(value, float) and not math.isfinite(value)):  # NaN and inf too
            raise argparse.ArgumentTypeError(f"must be a finite number {'>' if strict else '>='} {minimum}, "
                                             f"got {text}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be at most {maximum:,}, got {text}")
        return value
    parse.__name__ = noun
    parse.maximum = maximum     # the bound, as tools/fuzz_cli.py reads it (None: none)
    return parse


#: The largest count any flag takes (problems, steps, rounds, maps): beyond it a run would not end.
MAX_COUNT = 10 ** 9
#: The largest network width or candidate count: beyond it one forward pass would not fit in memory.
MAX_SIZE = 4096
#: The largest number of processes, Ray actors, environments or threads one command starts.
MAX_WORKERS = 256

positive_int = bounded(int, 1, False, "a positive integer", MAX_COUNT)
non_negative_int = bounded(int, 0, False, "a non-negative integer", MAX_COUNT)
positive_float = bounded(float, 0, True, "a positive number")
#: The longest time budget a flag takes: a 30-day run (a larger one is a typo, not a budget).
MAX_MINUTES = 60 * 24 * 30
minutes_float = bounded(float, 0, True, "a positive number of minutes", MAX_MINUTES)
non_negative_float = bounded(float, 0, False, "a non-negative number")
size_int = bounded(int, 1, False, "a positive integer", MAX_SIZE)
worker_count = bounded(int, 1, False, "a positive integer", MAX_WORKERS)
#: Temperatures divide logits: below this the softmax underflows to NaN.
temperature_float = bounded(float, 1e-3, False, "a number >= 0.001")
_any_non_negative_int = bounded(int, 0, False, "a non-negative integer")


def seed_int(text: str) -> int:
    """An argparse type: a seed in ``[0, 2**32)`` (what numpy's and torch's generators both take)."""
    value = _any_non_negative_int(text)
    if value >= 2 ** 32:
        raise argparse.ArgumentTypeError(f"a seed must be below 2**32, got {text}")
    return value


seed_int.maximum = 2 ** 32 - 1


#: The share of this machine's physical memory that what one command's counts keep may fill
#: (:func:`check_fits_in_memory`): a count beyond it is refused before any work, in one line.
MEMORY_SHARE = 0.5


def machine_memory() -> int:
    """Physical memory of this machine (bytes)."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_fits_in_memory(flags: str, count: int, bytes_each: int, what: str) -> None:
    """A one-line :class:`UsageError` naming ``flags`` when ``count`` items of at least ``bytes_each``
    bytes (``what`` they are) would not fit in :data:`MEMORY_SHARE` of this machine's memory: a count
    that would run for days and then fail, refused at once (``train sampler --problems 10**9``)."""
    need, have = count * bytes_each, machine_memory()
    if need > MEMORY_SHARE * have:
        raise UsageError(f"{flags}: {count:,} {what} need at least {need / 2 ** 30:,.1f} GiB, more than "
                         f"{MEMORY_SHARE:.0%} of this machine's {have / 2 ** 30:.0f} GiB")


#: Figure formats matplotlib's Agg backend writes (``FigureCanvasBase.get_supported_filetypes``),
#: so a bad suffix is refused before any work instead of failing at the end.
FIGURE_SUFFIXES = ("eps", "jpeg", "jpg", "pdf", "pgf", "png", "ps", "raw", "rgba", "svg", "svgz", "tif",
                   "tiff", "webp")


def path_arg(text: str) -> Path:
    """An argparse type: a file or directory name; ``''`` is refused (``Path('')`` would silently
    be the current directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a path, got ''")
    return Path(text)


def figure_path(text: str) -> Path:
    """An argparse type: a figure file whose suffix names a format matplotlib writes (``.png``, ``.svg``, ...)."""
    path = path_arg(text)
    if path.suffix.lower().lstrip(".") not in FIGURE_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text}: the suffix must name a figure format "
                                         f"({', '.join('.' + s for s in ('png', 'svg', 'pdf', 'jpg'))}, ...)")
    return path


def name_list(text: str) -> list[str]:
    """A comma-separated list of names (at least one)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of names")
    return names


def _int_list(text: str) -> list[int]:
    try:
        return [int(v) for v in name_list(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _float_list(text: str) -> list[float]:
    try:
        return [float(v) for v in name_list(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


#: The plugin modules this process imported (:func:`import_modules`), in order: module -> the file its
#: top-level module was loaded from when that came from the current directory (and whether that is a
#: package's ``__init__.py``), else None. Worker processes and Ray actors import the same
#: (:func:`plugin_sources`, :func:`import_plugin_sources`).
_PLUGINS: dict[str, tuple[str, bool] | None] = {}
#: Top-level modules loaded from the current directory: name -> (file, is a package).
_FROM_DIRECTORY: dict[str, tuple[str, bool]] = {}


def _load_from_file(top: str, file: Path, package: bool) -> None:
    """Load the top-level module or package ``top`` from ``file`` (a package's ``__init__.py``: its
    submodules then import through the package's ``__path__``); no directory joins ``sys.path``."""
    import importlib.util
    import sys
    if file.is_dir():                # a namespace package: a module whose submodules import from the folder
        namespace = types.ModuleType(top)
        namespace.__path__ = [str(file)]
        sys.modules[top] = namespace
        _FROM_DIRECTORY[top] = (str(file), True)
        return
    spec = (importlib.util.spec_from_file_location(top, file, submodule_search_locations=[str(file.parent)])
            if package else importlib.util.spec_from_file_location(top, file))
    module = importlib.util.module_from_spec(spec)
    sys.modules[top] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[top]
        raise
    _FROM_DIRECTORY[top] = (str(file), package)


def _load_from_current_directory(top: str) -> None:
    """Load the top-level module or package ``top`` from the current directory when nothing
    installed provides it (its submodules then import through the package's ``__path__``)."""
    import importlib.util
    import os
    import sys
    if not top.isidentifier() or top in sys.modules or importlib.util.find_spec(top) is not None:
        return
    here = Path(os.getcwd()).resolve()
    package, plain = here / top / "__init__.py", here / f"{top}.py"
    if package.is_file():
        _load_from_file(top, package, True)
    elif plain.is_file():
        _load_from_file(top, plain, False)


def _imported(module: str, load) -> None:
    """``load()`` (which imports ``module``), its failure as a one-line ``ValueError``; the module recorded
    as a plugin of this process."""
    try:
        load()
    except ImportError as exc:
        raise ValueError(f"cannot import module {module!r}: {exc}") from None
    except Exception as exc:     # the module's own code failed: say where, in one line
        line = str(exc).splitlines()[0] if str(exc) else ""
        raise ValueError(f"--import {module}: the module raised {type(exc).__name__}"
                         + (f": {line}" if line else "")) from None
    top = module.split(".")[0]
    _PLUGINS.setdefault(module, _FROM_DIRECTORY.get(top) or _local_origin(top))


def _local_origin(top: str) -> tuple[str, bool] | None:
    """The file of the imported top-level module ``top`` and whether it is a package, where it is no
    installed module (not under site-packages or the standard library): a directory this process has
    on ``sys.path`` (pytest's root, ``PYTHONPATH``) that a Ray actor, started elsewhere, does not have.
    None for an installed module, which every process imports by name."""
    import sys
    import sysconfig
    module = sys.modules.get(top)
    file = getattr(module, "__file__", None)
    if file is None:                 # a namespace package (a folder without __init__.py): its one folder
        folders = list(getattr(module, "__path__", []))
        if len(folders) != 1:
            return None
        file = folders[0]
    path = Path(file).resolve()
    installed = [Path(p).resolve() for key in ("stdlib", "platstdlib", "purelib", "platlib")
                 if (p := sysconfig.get_paths().get(key))]
    if any(part in ("site-packages", "dist-packages") for part in path.parts) or any(
            path.is_relative_to(root) for root in installed):
        return None
    return str(path), path.is_dir() or path.name == "__init__.py"


def import_modules(modules: typing.Iterable[str]) -> None:
    """Import modules that call ``register_task`` / ``register_sampler`` (``--import MODULE``);
    a one-line ``ValueError`` naming the module that cannot be imported.

    A module that is not installed is looked up in the current directory (``my_pkg.tasks``:
    ``./my_pkg/``), without ``PYTHONPATH=.``: the directory never joins ``sys.path``, so a
    ``train.py`` or ``agents/`` there cannot shadow this package's own modules. The worker
    processes and Ray actors of :mod:`train.workers` import the same modules, from the same files."""
    import importlib
    for module in modules:
        def load(module=module):
            _load_from_current_directory(module.split(".")[0])
            importlib.import_module(module)
        _imported(module, load)


#: What another process needs to import one plugin module as this one did: its name, and the file
#: of its top-level module when that came from the current directory (and whether it is a package).
PluginSource = tuple[str, "str | None", bool]


def plugin_sources(modules: typing.Iterable[str] = ()) -> tuple[PluginSource, ...]:
    """The plugin modules of this process (``modules`` imported first, if not yet), as
    :func:`import_plugin_sources` imports them in a worker process or Ray actor: by name when
    installed, else from the file this process loaded, whatever that process's current directory."""
    import_modules(modules)
    return tuple((module, *(where or (None, False))) for module, where in _PLUGINS.items())


def import_plugin_sources(sources: typing.Iterable[PluginSource]) -> None:
    """In a worker process or Ray actor: import the parent's plugin modules (:func:`plugin_sources`), a
    module the parent loaded from its current directory from that file (no directory joins
    ``sys.path``; a file missing here, on another machine, falls back to an installed module of that
    name); a one-line ``ValueError`` as :func:`import_modules`."""
    import importlib
    import sys
    for module, file, package in sources:
        top = module.split(".")[0]

        def load(module=module, top=top, file=file, package=package):
            if file is not None and top not in sys.modules and Path(file).exists():
                _load_from_file(top, Path(file), package)
            importlib.import_module(module)
        _imported(module, load)


# ---------------------------------------------------------------------------- checks of shared flags
def check_output_path(flag: str, path: Path, is_dir: bool) -> None:
    """Fail before any work when an output cannot be written (wrong kind, parent is a file, no access):
    a one-line :class:`UsageError` naming ``flag``."""
    if path.exists() and path.is_dir() != is_dir:
        raise UsageError(f"{flag} {path}: expected a {'directory' if is_dir else 'file'}")
    if path.exists() and not is_dir and not path.is_file():
        raise UsageError(f"{flag} {path}: not a regular file (a device, FIFO or socket is never replaced)")
    parent = path if (is_dir and path.exists()) else path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise UsageError(f"{flag} {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK):
        raise UsageError(f"{flag} {path}: {parent} is not writable")


def check_ray_address(address: str, timeout: float = 5.0) -> None:
    """Fail at once when nothing listens at a Ray address (``HOST:PORT`` or ``ray://HOST:PORT``):
    ``ray.init`` would retry for many minutes before giving up. A one-line :class:`UsageError`."""
    import socket
    if address == "auto":            # what ray.init("auto") joins: RAY_ADDRESS, else this machine's running head
        address = os.environ.get("RAY_ADDRESS", "")
        if not address:
            try:
                address = Path("/tmp/ray/ray_current_cluster").read_text().strip()
            except OSError:
                raise UsageError("--ray auto: no running Ray instance on this machine (start one with `ray "
                                 "start --head`, or give its address)") from None
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        if not 0 < int(port) < 65536:
            raise ValueError(port)
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            return
    except (ValueError, OverflowError):
        raise UsageError(f"--ray {address}: expected HOST:PORT, ray://HOST:PORT or auto") from None
    except OSError as exc:
        raise UsageError(f"cannot reach Ray at {address}: {exc.strerror or exc}") from None


# ---------------------------------------------------------------------------- dataclass -> flags
def _unwrap_optional(tp: Any) -> tuple[Any, bool]:
    """``X | None`` -> (X, True); anything else -> (tp, False)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0], True
    return tp, False


def _parser_for(tp: Any) -> tuple[Callable[[str], Any] | None, bool]:
    """(argparse type, is_sequence) for a field annotation."""
    origin = typing.get_origin(tp)
    if origin in (list, tuple):
        (item, *_) = typing.get_args(tp) or (str,)
        return {int: _int_list, float: _float_list}.get(item, name_list), True
    if tp is Path:
        return path_arg, False
    if tp in (int, float, str):
        return tp, False
    return None, False


def add_dataclass_arguments(parser: argparse.ArgumentParser, cls: type, skip: typing.Iterable[str] = ()) -> None:
    """Add one ``--flag`` per field of the dataclass ``cls`` (``snake_case`` -> ``--snake-case``).

    Booleans become switches: ``--name`` when the default is False, ``--no-name`` when it
    is True. Lists and tuples are comma-separated. A field's ``arg(parse=...)`` overrides
    the parser chosen from its annotation.
    """
    hints = typing.get_type_hints(cls)
    skip = set(skip)
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init:
            continue
        meta = f.metadata
        tp, _optional = _unwrap_optional(hints[f.name])
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        help_text = meta.get("help", "")
        if tp is bool:
            flag = meta.get("flag") or ("--no-" if default else "--") + f.name.replace("_", "-")
            parser.add_argument(flag, dest=f.name, action="store_false" if default else "store_true",
                                help=help_text + "%(default).0s")   # a switch: no "(default: ...)"
            continue
        flags = meta.get("flag") or "--" + f.name.replace("_", "-")
        flags = (flags,) if isinstance(flags, str) else tuple(flags)
        if meta.get("append"):
            parser.add_argument(*flags, dest=f.name, action="append", type=meta.get("parse") or str,
                                default=[], metavar=meta.get("metavar"), help=help_text + "%(default).0s")
            continue
        parse, _ = _parser_for(tp)
        parse = meta.get("parse") or parse
        if parse is None:
            raise TypeError(f"{cls.__name__}.{f.name}: no command-line parser for {hints[f.name]!r}; "
                            "give arg(parse=...)")
        help_text = help_text or ""
        if default is None:
            help_text += "%(default).0s"   # the help says what None means
        elif isinstance(default, (list, tuple)):
            # Comma-separated default in --help instead of a Python repr ("%(default).0s" prints
            # nothing and stops the formatter from appending the repr).
            help_text += f" (default: {','.join(map(str, default))})%(default).0s"
        optional = {"nargs": "?", "const": meta["const"]} if meta.get("const") is not None else {}
        parser.add_argument(*flags, dest=f.name, type=parse, default=default, choices=meta.get("choices"),
                            metavar=meta.get("metavar"), help=help_text, **optional)


def from_namespace(cls: type, ns: argparse.Namespace, **overrides: Any):
    """The dataclass ``cls`` built from parsed flags (fields absent from ``ns`` keep their default)."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    names = set(fields)
    values = {k: v for k, v in vars(ns).items() if k in names}
    for name, value in values.items():
        if typing.get_origin(_unwrap_optional(hints[name])[0]) is dict and isinstance(value, list):
            keys = [k for k, _ in value]
            repeated = sorted({k for k in keys if keys.count(k) > 1})
            if repeated:     # --checkpoint gnn=A --checkpoint gnn=B: which one was meant?
                flag = fields[name].metadata.get("flag") or f"--{name.replace('_', '-')}"
                flag = flag if isinstance(flag, str) else flag[0]
                raise ValueError(f"{flag} given twice for {', '.join(map(repr, repeated))}")
            values[name] = dict(value)   # repeated KEY=VALUE flags
    values.update(overrides)
    return cls(**values)
