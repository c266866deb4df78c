"""The picker's candidate priors, by their former import path (``from agents.rl.prior import ScorerPrior``).

They are the tree method's (:mod:`agents.tree.prior`); this module hands them out through the shared
floor's registry (:func:`agents.nn.priors.prior_class`) without importing the tree method.
"""

from __future__ import annotations

from typing import Any

from agents.nn.priors import prior_class

_KINDS = {"ScorerPrior": "tree/gnn-scorer", "MixturePrior": "tree/gnn"}


def __getattr__(name: str) -> Any:
    if name in _KINDS:
        return prior_class(_KINDS[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["MixturePrior", "ScorerPrior"]
