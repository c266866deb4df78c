"""Numpy twins of torch layers: a trained model's math in numpy, for inference one step at a time.

Two kits, one per use:

* float64 (the tree models' incremental engines, :mod:`agents.tree.engine`): ``nn.Linear`` stacks
  with GELU between them (:func:`mlp`, the scorer's candidate head) and the weights read off a module
  (:func:`linears`, :func:`norms_of`, :func:`vector`); the per-node work itself is compiled
  (:mod:`agents.tree.compiled`). ``tests/test_tree_engine.py`` checks each engine against its torch
  model on the outputs that make an action.
* float32 (the RL policies' numpy forwards, :mod:`agents.rl.sampler`): an ``nn.Sequential`` of linear
  layers and ReLU / Tanh as ``(W^T, b, activation)`` triples (:func:`numpy_layers`,
  :func:`numpy_linear`) and their forward (:func:`numpy_mlp`); ``tests/test_rl.py`` and
  ``tests/test_rl_pick.py`` compare them with the torch policies.
"""

from __future__ import annotations

import math
from typing import Any, Callable

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
    """A stack of linear layers with GELU between them (:func:`agents.nn.causal.mlp`)."""
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


#: Activation modules with a float32 numpy twin (what :func:`numpy_layers` accepts).
NUMPY_ACTS: dict[type, Callable[[np.ndarray], np.ndarray]] = {torch.nn.Tanh: np.tanh,
                                                              torch.nn.ReLU: lambda x: np.maximum(x, 0.0)}


def numpy_layers(seq: torch.nn.Sequential) -> list[tuple[np.ndarray, np.ndarray, Any]]:
    """An MLP's ``(W^T, b, activation or None)`` per linear layer, float32 arrays (ValueError: an
    activation without a numpy twin)."""
    out, mods = [], list(seq)
    for i, m in enumerate(mods):
        if isinstance(m, torch.nn.Linear):
            act = mods[i + 1] if i + 1 < len(mods) and not isinstance(mods[i + 1], torch.nn.Linear) else None
            if act is not None and type(act) not in NUMPY_ACTS:
                raise ValueError(f"no numpy twin for activation {type(act).__name__}")
            out.append((*numpy_linear(m)[:2], None if act is None else NUMPY_ACTS[type(act)]))
    return out


def numpy_linear(m: torch.nn.Module) -> tuple[np.ndarray, np.ndarray, None]:
    """``(W^T, b, None)`` of one linear layer (torch's or PyG's; no bias: zeros), float32."""
    w = m.weight.detach().numpy()
    bias = np.zeros(w.shape[0], np.float32) if m.bias is None else m.bias.detach().numpy().copy()
    return w.T.copy(), bias, None


def numpy_mlp(layers: list[tuple[np.ndarray, np.ndarray, Any]], x: np.ndarray) -> np.ndarray:
    """The forward of :func:`numpy_layers`' layers."""
    for w, b, act in layers:
        x = x @ w + b
        x = act(x) if act is not None else x
    return x


__all__ = ["NUMPY_ACTS", "gelu", "linears", "mlp", "norms_of", "numpy_layers", "numpy_linear", "numpy_mlp", "vector",
           "wrap_periodic"]
