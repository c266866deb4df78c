"""A candidate prior for RL pickers: the supervised GNN sample scorer over the whole tree.

The pendulum's supervised ``gnn`` (:class:`~agents.tree.scorer.TreeGNNScorer`) scores a candidate
state by the tree around its nearest node; a picker that starts from those scores starts where
supervision got to, and PPO learns what to change (a warm start that survives PPO's first
updates: the prior is an input, not weights PPO can overwrite). :class:`ScorerPrior` is the
:class:`~gnn_mp_envs.envs.candidates.CandidatePrior` the training env and the sampler both call:
the scorer's incremental engine (each new node embedded once, compiled) and its logits over a
temperature.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from agents.tree.engine import IncrementalTreeScorer
from agents.tree.scorer import TreeGNNScorer


class ScorerPrior:
    """``logits = scorer(candidates | tree) / temperature`` for the active tree of each observation."""

    def __init__(self, model: TreeGNNScorer, temperature: float = 1.0) -> None:
        if not (np.isfinite(temperature) and temperature > 0):
            raise ValueError(f"temperature must be finite and > 0, got {temperature}")
        self.engine = IncrementalTreeScorer(model)
        self.temperature = float(temperature)

    @classmethod
    def from_checkpoint(cls, path: str | Path, temperature: float = 1.0) -> "ScorerPrior":
        """The prior of a ``tree/gnn-scorer`` checkpoint (a zero-argument factory: ``partial`` of this)."""
        from agents.checkpoints import load_checkpoint
        model, _ = load_checkpoint(path, expected_kind="tree/gnn-scorer")
        return cls(model, temperature)

    def reset(self) -> None:
        self.engine.clear()

    def __call__(self, obs: Mapping, candidates: np.ndarray, active: int) -> np.ndarray:
        self.engine.ingest(obs)         # a new episode clears the caches by itself
        return self.engine.candidate_logits(np.ascontiguousarray(candidates, dtype=np.float64), int(active)) \
            / self.temperature


__all__ = ["ScorerPrior"]
