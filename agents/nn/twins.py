"""Numpy twins of the torch layers the tree models are built from, for the incremental engines.

The engines (:mod:`agents.tree.engine`) run a trained model's exact math in float64 numpy, one
new tree node at a time; these are the pieces they share: ``nn.Linear`` stacks with GELU
between them (:func:`mlp`, the scorer's candidate head) and the weights read off a module
(:func:`linears`, :func:`norms_of`); the per-node work itself is compiled
(:mod:`agents.tree.compiled`). ``tests/test_tree_engine.py`` checks each engine against its
torch model on the outputs that make an action.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.special import erf

from agents.samplers.base import wrap_periodic

Linear = tuple[np.ndarray, np.ndarray]


def gelu(x: np.ndarray) -> np.ndarray:
    """``torch.nn.GELU()`` (the exact, erf form)."""
    return 0.5 * x * (1.0 + erf(x / math.sqrt(2.0)))


def linears(module: torch.nn.Module) -> list[Linear]:
    """``(W^T, b)`` float64 of every ``nn.Linear`` in ``module`` (a Sequential or a single layer), in order."""
    layers = [module] if isinstance(module, torch.nn.Linear) else [m for m in module if isinstance(m, torch.nn.Linear)]
    return [(m.weight.detach().numpy().T.astype(np.float64).copy(), m.bias.detach().numpy().astype(np.float64).copy())
            for m in layers]


def mlp(layers: list[Linear], x: np.ndarray) -> np.ndarray:
    """A stack of linear layers with GELU between them (``agents.tree.models.mlp``)."""
    dot = np.dot if x.ndim <= 2 else np.matmul      # np.dot: matmul's BLAS call, bit for bit, cheaper (1-D, 2-D)
    for i, (w, b) in enumerate(layers):
        x = dot(x, w) + b
        if i < len(layers) - 1:
            x = gelu(x)
    return x


def norms_of(modules: torch.nn.ModuleList) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """``(weight, bias, eps)`` of each ``nn.LayerNorm``."""
    return [(n.weight.detach().numpy().astype(np.float64).copy(), n.bias.detach().numpy().astype(np.float64).copy(),
             n.eps) for n in modules]


def vector(t: torch.Tensor) -> np.ndarray:
    """A buffer as a float64 numpy copy."""
    return t.detach().numpy().astype(np.float64).copy()


__all__ = ["gelu", "linears", "mlp", "norms_of", "vector", "wrap_periodic"]
