"""Samplers: the interface and its base (:mod:`.base`), the classical samplers (:mod:`.baselines`)
and, re-exported from :mod:`agents.registry`, ``load_sampler`` and the registry.

The learned samplers live with their method: :mod:`agents.tree` (GNN, CVAE, GNN-CVAE, the
pendulum's scorer) and :mod:`agents.rl` (RL policies). Names below load on first use, so
``from agents.samplers import load_sampler`` imports no torch.
"""

from __future__ import annotations

import importlib

from agents.registry import SAMPLERS, available_samplers, descriptions, load_sampler, register_sampler

#: Names importable from here, loaded on first use: name -> module.
_LAZY = {"Sampler": "agents.samplers.base", "ModelSampler": "agents.samplers.base",
         "SAMPLER_IN_KEYS": "agents.samplers.base", "SAMPLER_OUT_KEYS": "agents.samplers.base",
         "active_target": "agents.samplers.base", "UniformSampler": "agents.samplers.baselines",
         "GoalBiasSampler": "agents.samplers.baselines", "SamplerModule": "agents.samplers.module"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["SAMPLERS", "SAMPLER_IN_KEYS", "SAMPLER_OUT_KEYS", "GoalBiasSampler", "ModelSampler", "Sampler",
           "SamplerModule", "UniformSampler", "active_target", "available_samplers", "descriptions", "load_sampler",
           "register_sampler"]
