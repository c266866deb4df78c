"""Sampler registry: every sampler is built by name through :func:`load_sampler`.

Learned samplers register themselves here too, so the benchmark and the training
scripts never need an if/elif chain over sampler names. Their base class,
:class:`agents.samplers.learned.LearnedSampler`, is importable from here too
(``from agents.samplers import LearnedSampler``); it is loaded on first use because it
pulls in PyTorch Geometric and TorchRL, which the classical samplers do not need.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from agents.samplers.base import SAMPLER_IN_KEYS, SAMPLER_OUT_KEYS, Sampler, batch_shape_of
from agents.samplers.baselines import GoalBiasSampler, UniformSampler

#: name -> factory(low, high, task, seed, **kwargs) -> Sampler
SamplerFactory = Callable[..., Sampler]
SAMPLERS: dict[str, SamplerFactory] = {}
DESCRIPTIONS: dict[str, str] = {}


def register_sampler(name: str, factory: SamplerFactory, description: str = "") -> None:
    """Add a sampler to the registry (names are unique)."""
    if name in SAMPLERS:
        raise ValueError(f"sampler {name!r} is already registered")
    SAMPLERS[name] = factory
    DESCRIPTIONS[name] = description


def available_samplers() -> list[str]:
    return sorted(SAMPLERS)


def load_sampler(name: str, low: np.ndarray, high: np.ndarray, task: str | None = None,
                 seed: int | None = None, **kwargs) -> Sampler:
    """Build the sampler ``name`` for a task with sampling bounds ``[low, high]``."""
    try:
        factory = SAMPLERS[name]
    except KeyError:
        raise ValueError(f"unknown sampler {name!r}; known: {', '.join(available_samplers())}") from None
    return factory(low=low, high=high, task=task, seed=seed, **kwargs)


register_sampler("uniform", lambda low, high, task=None, seed=None, **kw: UniformSampler(low, high, seed),
                 "uniform over the state bounds")
register_sampler("goal-bias", lambda low, high, task=None, seed=None, goal_bias=0.05, **kw:
                 GoalBiasSampler(low, high, seed, goal_bias),
                 "uniform with 5% samples at the active tree's target")


def _tree_sampler(name: str) -> SamplerFactory:
    """Factory of a learned tree sampler; imports the models (PyG) only when one is built."""
    def factory(low, high, task=None, seed=None, checkpoint=None, **settings):
        from agents.samplers.tree import load_tree_sampler
        return load_tree_sampler(name, low, high, task=task, seed=seed, checkpoint=checkpoint, **settings)
    return factory


register_sampler("gnn", _tree_sampler("gnn"), "learned (Algorithm 1): causal tree GNN, a node-mixture over the tree "
                 "(pendulum: a scorer of 16 uniform candidates); shipped weights per task with their uniform/goal mix")
register_sampler("cvae", _tree_sampler("cvae"), "learned baseline (Ichter et al. 2018): CVAE on start, goal and "
                 "obstacles; ignores the tree")
register_sampler("gnn-cvae", _tree_sampler("gnn-cvae"), "learned baseline: CVAE conditioned on the causal GNN's "
                 "tree context")


def __getattr__(name: str):
    if name == "LearnedSampler":
        from agents.samplers.learned import LearnedSampler
        return LearnedSampler
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DESCRIPTIONS", "SAMPLERS", "SAMPLER_IN_KEYS", "SAMPLER_OUT_KEYS", "Sampler", "UniformSampler",
           "GoalBiasSampler", "LearnedSampler", "available_samplers", "batch_shape_of", "load_sampler",
           "register_sampler"]
