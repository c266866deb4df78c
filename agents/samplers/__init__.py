"""Sampler registry: every sampler is built by name through :func:`load_sampler`.

Learned samplers register themselves here too, so the benchmark and the training
scripts never need an if/elif chain over sampler names. Their base class,
:class:`agents.samplers.learned.LearnedSampler`, is importable from here too
(``from agents.samplers import LearnedSampler``). Classes are loaded on first use (listing the
registry, ``gnn-mp samplers``, imports no torch); the learned samplers' models (PyTorch
Geometric) load only when one is built.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:
    from agents.samplers.base import Sampler

#: name -> factory(low, high, task, seed, **kwargs) -> Sampler
SamplerFactory = Callable[..., "Sampler"]
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


def _uniform(low, high, task=None, seed=None, **kw):
    from agents.samplers.baselines import UniformSampler
    return UniformSampler(low, high, seed)


def _goal_bias(low, high, task=None, seed=None, goal_bias=0.05, **kw):
    from agents.samplers.baselines import GoalBiasSampler
    return GoalBiasSampler(low, high, seed, goal_bias)


register_sampler("uniform", _uniform, "uniform over the state bounds")
register_sampler("goal-bias", _goal_bias, "uniform with 5% samples at the active tree's target")


# RL policies (issue #10, agents/samplers/rl.py; imported on first use: it needs torch_geometric)
def _rl_factory(name: str) -> SamplerFactory:
    return lambda **kw: importlib.import_module("agents.samplers.rl").load_rl_sampler(name, **kw)


for _name, _what in (("rl-ppo", "SB3 PPO"), ("rl-sac", "SB3 SAC"), ("rl-ppo-torchrl", "TorchRL PPO")):
    register_sampler(_name, _rl_factory(_name), f"{_what} policy over the tree view (gnn-mp train rl; per-task weights)")


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


#: Names importable from here, loaded on first use: name -> module.
_LAZY = {"Sampler": "agents.samplers.base", "SAMPLER_IN_KEYS": "agents.samplers.base",
         "SAMPLER_OUT_KEYS": "agents.samplers.base", "batch_shape_of": "agents.samplers.base",
         "UniformSampler": "agents.samplers.baselines", "GoalBiasSampler": "agents.samplers.baselines",
         "LearnedSampler": "agents.samplers.learned"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DESCRIPTIONS", "SAMPLERS", "SAMPLER_IN_KEYS", "SAMPLER_OUT_KEYS", "Sampler", "UniformSampler",
           "GoalBiasSampler", "LearnedSampler", "available_samplers", "batch_shape_of", "load_sampler",
           "register_sampler"]
