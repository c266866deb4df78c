"""Lazy numba compilation of the planner's innermost loops.

Each loop is written as a plain Python function and compiled on first use; where numba cannot be
imported (the sphere checker needs it, the other tasks do not) the loop runs as that function (the
same operations, so the same floats), and tests hold the two to equality.
"""

from __future__ import annotations

from typing import Callable


def lazy_njit(func: Callable) -> Callable[[], Callable | None]:
    """A getter of ``func`` compiled by numba (``cache=True``: cached next to its module), built on
    its first call, so that importing a task module never compiles; the getter returns None when
    numba is not installed."""
    compiled: list = []

    def get() -> Callable | None:
        if not compiled:
            try:
                from numba import njit
            except ImportError:
                compiled.append(None)
            else:
                compiled.append(njit(cache=True)(func))
        return compiled[0]

    get.__doc__ = f"``{func.__name__}`` compiled by numba, or None without numba."
    get.__wrapped__ = func
    return get
