"""Numpy twins of the torch layers the tree models are built from, for the incremental engines.

The engines (:mod:`agents.tree.engine`) run a trained model's exact math in float64 numpy, one
new tree node at a time; these are the pieces they share: ``nn.Linear`` stacks with GELU
between them (:func:`mlp`), ``nn.LayerNorm`` (:func:`layer_norm`) and the weights read off a
module (:func:`linears`). ``tests/test_tree_engine.py`` checks each engine against its torch
model on the outputs that make an action.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.special import erf

from agents.samplers.base import wrap_periodic

Linear = tuple[np.ndarray, np.ndarray]
_add_reduce = np.add.reduce      # ndarray.sum's reduction without its Python wrapper (the same values)


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


def layer_norm(norm: tuple[np.ndarray, np.ndarray, float], x: np.ndarray) -> np.ndarray:
    """``torch.nn.LayerNorm`` over the last axis."""
    g, b, eps = norm
    width = x.shape[-1]
    centred = x - _add_reduce(x, -1, keepdims=True) / width          # x.mean's values, without its wrapper
    var = _add_reduce(centred * centred, -1, keepdims=True) / width
    return centred / np.sqrt(var + eps) * g + b


def nearest_k(dist: np.ndarray, k: int) -> np.ndarray:
    """``np.argsort(dist, axis=1, kind="stable")[:, :k]`` (ties to the lower index) without sorting
    whole rows: ``argpartition`` finds each row's k smallest distances, which are then ordered by
    (distance, index). A row whose k-th smallest value also occurs outside the chosen k (a tie at
    the boundary: the infinities of a small tree, or repeated states, common on the pendulum) sorts
    only its entries at or below that value, in index order (:func:`_tied_row`)."""
    n = dist.shape[1]
    if k >= n or n <= 64:
        return np.argsort(dist, axis=1, kind="stable")[:, :k]
    if dist.shape[0] == 1:      # one new node (the common case): the same steps on the row, in plain Python where k is small
        row = dist[0]
        part = row.argpartition(k - 1)[:k]
        vals = row[part]
        kth = vals.max()
        if np.count_nonzero(row == kth) != np.count_nonzero(vals == kth):
            return _tied_row(row, kth, k)[None]
        return np.array([j for _, j in sorted(zip(vals.tolist(), part.tolist()))], dtype=np.int64)[None]
    rows = np.arange(dist.shape[0])[:, None]
    part = np.argpartition(dist, k - 1, axis=1)[:, :k]
    vals = dist[rows, part]
    out = part[rows, np.lexsort((part, vals), axis=-1)]
    kth = vals.max(1, keepdims=True)
    tied = np.flatnonzero((dist == kth).sum(1) != (vals == kth).sum(1))     # a tie at the k-th value
    if len(tied):
        # every tied row at once: its entries at or below its k-th value, ordered by (row, value, index);
        # each row has at least k of them, and its first k are the stable sort's
        sub = dist[tied]
        r, c = np.nonzero(sub <= kth[tied])
        order = np.lexsort((c, sub[r, c], r))
        starts = np.searchsorted(r[order], np.arange(len(tied)))
        out[tied] = c[order][starts[:, None] + np.arange(k)]
    return out


def _tied_row(row: np.ndarray, kth: float, k: int) -> np.ndarray:
    """A row's stable-argsort first ``k`` when its ``k``-th smallest value ``kth`` is tied: every entry
    at or below ``kth`` is a candidate (at least ``k`` of them, in index order), and a stable sort
    of their values keeps the lower index first, as the full row's stable sort does."""
    candidates = np.flatnonzero(row <= kth)
    return candidates[np.argsort(row[candidates], kind="stable")[:k]]


def vector(t: torch.Tensor) -> np.ndarray:
    """A buffer as a float64 numpy copy."""
    return t.detach().numpy().astype(np.float64).copy()


__all__ = ["gelu", "layer_norm", "linears", "mlp", "nearest_k", "norms_of", "vector", "wrap_periodic"]
