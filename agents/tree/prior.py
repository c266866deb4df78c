"""Candidate priors from the supervised tree models: what a candidate picker ranks its candidates by.

The pendulum's supervised ``gnn`` (:class:`~agents.tree.scorer.TreeGNNScorer`) scores a candidate
state by the tree around its nearest node; a picker that starts from those scores starts where
supervision got to, and PPO learns what to change (a warm start that survives PPO's first
updates: the prior is an input, not weights PPO can overwrite). :class:`ScorerPrior` is the
:class:`~gnn_mp_envs.envs.candidates.CandidatePrior` the training env and the sampler both call:
the scorer's incremental engine (each new node embedded once, compiled) and its logits over a
temperature. :class:`MixturePrior` is the same protocol over a supervised ``tree/gnn`` sampler (the
maze2d and arm ``gnn``): a candidate's logit is its log-density under the GNN's mixture at the
current tree, so ``gnn-pick`` ranks the picker's candidates by what supervision learned.

They live with the tree method; the RL picker (:mod:`agents.rl`) reaches them by the model's
checkpoint kind through the shared floor's registry (:mod:`agents.nn.priors`), never by import.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from agents.nn.twins import wrap_periodic
from agents.tree.engine import IncrementalTreeGNN, IncrementalTreeScorer
from agents.tree.models import TreeGNN
from agents.tree.scorer import TreeGNNScorer


class ScorerPrior:
    """``logits = scorer(candidates | tree) / temperature`` for the active tree of each observation."""

    #: The model it reads, and its settings (read from a checkpoint's ``meta["sampler"]``).
    model_class = TreeGNNScorer
    settings = ("temperature",)

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


class MixturePrior:
    """``logits = log q(candidate | tree)``: the density of the supervised GNN sampler's mixture
    (node weights at ``temperature``, Gaussians at ``sigma_scale`` times the learned scales)."""

    model_class = TreeGNN
    settings = ("temperature", "sigma_scale")

    def __init__(self, model: TreeGNN, temperature: float = 1.0, sigma_scale: float = 1.0) -> None:
        for name, value in (("temperature", temperature), ("sigma_scale", sigma_scale)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        self.engine = IncrementalTreeGNN(model)
        self.temperature, self.sigma_scale = float(temperature), float(sigma_scale)
        self.periodic = self.engine.periodic.astype(bool)

    def reset(self) -> None:
        self.engine.clear()

    def __call__(self, obs: Mapping, candidates: np.ndarray, active: int) -> np.ndarray:
        e = self.engine
        rows = e.new_rows(obs)
        probabilities, _, shift = e.grown_mixture(obs, rows, int(active), self.temperature)
        n = e.n
        mean = e.states[:n] + e.offsets[:n, active] + shift                         # (n, d)
        log_sigma = e.log_sigma[:n, active] + np.log(self.sigma_scale)              # (n, d)
        delta = np.asarray(candidates, np.float64)[:, None, :] - mean[None]         # (K, n, d)
        delta = wrap_periodic(delta, self.periodic)
        z = delta * np.exp(-log_sigma)[None]
        log_normal = -0.5 * (z * z).sum(-1) - log_sigma.sum(-1)[None] - 0.5 * e.d * np.log(2 * np.pi)
        joint = log_normal + np.log(np.maximum(probabilities[:n], 1e-300))[None]     # (K, n)
        top = joint.max(1, keepdims=True)
        return (top[:, 0] + np.log(np.exp(joint - top).sum(1))).astype(np.float64)


__all__ = ["MixturePrior", "ScorerPrior"]
