"""Registry entries named as ``"module:attribute"`` strings, imported on first use (so that a
registry can name a class whose module pulls in torch or pybullet without importing it)."""

from __future__ import annotations

import importlib
from typing import Any, MutableMapping


def import_entry(entry: str) -> Any:
    """The object ``attribute`` of ``module`` named by ``"module:attribute"``."""
    module, sep, attribute = entry.partition(":")
    if not sep or not module or not attribute:
        raise ValueError(f"expected 'module:attribute', got {entry!r}")
    return getattr(importlib.import_module(module), attribute)


def resolved(registry: MutableMapping[str, Any], key: str) -> Any:
    """``registry[key]``, a ``"module:attribute"`` string imported (and stored back) the first time."""
    entry = registry[key]
    if isinstance(entry, str):
        entry = registry[key] = import_entry(entry)
    return entry


__all__ = ["import_entry", "resolved"]
