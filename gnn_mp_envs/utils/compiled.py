"""The one way the project compiles with numba: :func:`jit`, and :func:`lazy_njit` for modules that
must not import numba when they are imported.

Every compiled function is a plain Python function (the tests' twin: ``compiled.py_func``, or the
getter's ``__wrapped__``) compiled ``nopython`` without the GIL, cached on disk. A cached function is
used only while no source file of the packages has changed (:func:`sources_stamp`; numba alone looks at
the function's own file, so a change to a compiled function it calls in another module would leave it
stale). The cache never stops the package: where numba's own places for it (next to the module, then
the user's cache folder) are not writable, the cache goes to a folder of the temporary directory, and
where none works the code is compiled in every process; a damaged cache file (an interrupted write)
is dropped and rewritten.
Each of these is said once, in one line on stderr.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
import tempfile
import types
from pathlib import Path
from typing import Any, Callable

#: Where the cache goes when numba finds no writable place of its own.
FALLBACK_CACHE_DIR = os.path.join(tempfile.gettempdir(), f"gnn-mp-envs-numba-{os.getuid()}")
_SAID: set[str] = set()


def _say(key: str, message: str) -> None:
    if key not in _SAID:
        _SAID.add(key)
        print(f"gnn-mp-envs: {message}", file=sys.stderr, flush=True)


#: The packages whose sources every cached function's validity depends on (compiled code calls across them).
PACKAGES = ("gnn_mp_envs", "agents")


@functools.lru_cache(maxsize=1)
def sources_stamp() -> str:
    """A digest of the name, size and modification time of every source file of :data:`PACKAGES`: the
    stamp numba's cache keeps with compiled code, so that any change to the sources recompiles."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            st = path.stat()
            digest.update(f"{path.relative_to(root)}:{st.st_size}:{st.st_mtime_ns};".encode())
    return digest.hexdigest()


def _tolerant_cache(py_func: Callable) -> Any:
    """numba's on-disk cache of ``py_func`` that a damaged file cannot break (None: no cache anywhere)."""
    from numba.core import caching, config

    class TolerantCache(caching.FunctionCache):
        def __init__(self, py_func: Callable) -> None:
            super().__init__(py_func)
            self._cache_file._source_stamp = sources_stamp()     # every package source, not the one file

        def load_overload(self, sig: Any, target_context: Any) -> Any:
            try:
                return super().load_overload(sig, target_context)
            except Exception as exc:    # a truncated index or data file: drop it, compile, write it anew
                for path in (self._cache_file._index_path,):
                    try:
                        os.remove(path)
                    except OSError:
                        pass
                _say(f"damaged:{self._cache_path}", f"numba's cache in {self._cache_path} was damaged "
                     f"({type(exc).__name__}); recompiling and rewriting it")
                return None

        def save_overload(self, sig: Any, data: Any) -> None:
            try:
                super().save_overload(sig, data)
            except Exception as exc:
                _say(f"save:{self._cache_path}", f"could not write numba's cache in {self._cache_path} "
                     f"({type(exc).__name__}); compiled code is not kept")

    try:
        return TolerantCache(py_func)
    except RuntimeError:                     # "no locator available": no writable place next to it
        pass
    if config.CACHE_DIR != FALLBACK_CACHE_DIR:
        try:
            os.makedirs(FALLBACK_CACHE_DIR, mode=0o700, exist_ok=True)
            config.CACHE_DIR = FALLBACK_CACHE_DIR
            cache = TolerantCache(py_func)
            _say("fallback-dir", f"numba's cache goes to {FALLBACK_CACHE_DIR} (the package folder and the "
                 "user's cache folder are not writable)")
            return cache
        except (OSError, RuntimeError):
            pass
    _say("no-cache", "no writable folder for numba's cache: the compiled code is rebuilt in every process")
    return None


def jit(func: Callable | None = None, *, inline: bool = False) -> Any:
    """``func`` compiled by numba (``njit``, ``nogil``, cached on disk as the module says); ``inline``:
    inlined into the compiled functions that call it (small helpers of a hot loop). Compiled on the
    first call, like any numba function; usable as ``@jit`` or ``@jit(inline=True)``."""
    if func is None:
        return lambda f: jit(f, inline=inline)
    from numba import njit
    dispatcher = njit(nogil=True, inline="always" if inline else "never")(func)
    dispatcher._cache = _tolerant_cache(dispatcher.py_func) or dispatcher._cache
    return dispatcher


#: Dispatchers :func:`announce_compilation` was asked about in this process (it looks once each).
_ASKED: set = set()


def announce_compilation(dispatcher: Any, what: str, duration: str, where: str) -> bool:
    """Print one line to stderr when ``dispatcher``'s first call in this process will compile it (no
    signature loaded yet and no cache for the current sources on disk): ``duration`` that would
    otherwise look like a hang before a progress bar moves. Called right before the call, it looks once
    per dispatcher and process; later calls cost a set lookup. Whether it printed; never raises (it
    reads numba's cache index, an internal API: if that changes, it stays silent)."""
    if dispatcher in _ASKED:
        return False
    _ASKED.add(dispatcher)
    try:
        if dispatcher.signatures or dispatcher._cache._cache_file._load_index():
            return False
    except Exception:       # noqa: BLE001  (a numba without these internals: no notice, nothing else changes)
        return False
    print(f"gnn-mp: compiling {what} (numba; first use of this checkout or install, {duration}, then cached: "
          f"numba's cache, next to {where} by default)", file=sys.stderr, flush=True)
    return True


_SPECIALIZED: dict[tuple[Callable, str], Any] = {}


def specialized(func: Callable, tag: str, **bindings: Callable) -> Any:
    """:func:`jit` of ``func`` with the global names ``bindings`` bound to other compiled functions (a
    loop calling a problem's compiled steer), one per ``tag``: its own name (``<name>__<tag>``), so its
    own cache files. numba would specialise a function passed as an argument too, but could not cache it."""
    key = (func, tag)
    if key not in _SPECIALIZED:
        bound = types.FunctionType(func.__code__, {**func.__globals__, **bindings}, f"{func.__name__}__{tag}",
                                   func.__defaults__, func.__closure__)
        bound.__qualname__, bound.__doc__ = f"{func.__qualname__}__{tag}", func.__doc__
        _SPECIALIZED[key] = jit(bound)
    return _SPECIALIZED[key]


def lazy_njit(func: Callable, calls: dict[str, Callable[[], Callable | None]] | None = None
              ) -> Callable[[], Callable | None]:
    """A getter of :func:`jit` ``(func)``, built on its first call, so that importing a module never
    imports numba or compiles; the getter returns None when numba is not installed. ``calls``: global
    name -> the getter of another such function that ``func`` calls by that name (it calls the plain
    function in Python, the compiled one once compiled)."""
    compiled: list = []

    def get() -> Callable | None:
        if not compiled:
            try:
                import numba  # noqa: F401
            except ImportError:
                compiled.append(None)
            else:
                bound = func
                if calls:
                    names = {**func.__globals__, **{name: getter() for name, getter in calls.items()}}
                    bound = types.FunctionType(func.__code__, names, func.__name__, func.__defaults__,
                                               func.__closure__)
                    bound.__qualname__, bound.__doc__ = func.__qualname__, func.__doc__
                compiled.append(jit(bound))
        return compiled[0]

    get.__doc__ = f"``{func.__name__}`` compiled by numba, or None without numba."
    get.__wrapped__ = func
    return get
