"""Classical samplers: uniform and goal-biased.

Their random streams are part of the benchmark's contract (same seed, same samples, same
counters): uniform draws one ``torch.rand(*batch, d)`` per call; goal-bias draws that, then
one ``torch.rand(*batch, 1)``. ``tests/test_samplers.py`` pins both.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

from agents.samplers.base import Sampler, batch_shape_of


class UniformSampler(Sampler):
    """Uniform over the sampling bounds: the RRT/BiRRT default."""

    reads = ("start",)

    def propose(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.uniform(batch_shape_of(obs["start"]))

    def act(self, obs: Mapping) -> np.ndarray:
        # No tensor conversion at all: only the batch shape of ``start`` is needed.
        return self.uniform(np.shape(obs["start"])[:-1]).numpy()


class GoalBiasSampler(Sampler):
    """Uniform, but with probability ``goal_bias`` the target of the active tree.

    For RRT (and BiRRT's start tree) the target is the goal; for BiRRT's goal tree it is
    the start, so both trees are pulled toward each other as in OMPL's goal biasing.
    """

    reads = ("start", "goal", "active_tree")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None,
                 goal_bias: float = 0.05) -> None:
        if not 0.0 <= goal_bias <= 1.0:
            raise ValueError(f"goal_bias must be in [0, 1], got {goal_bias}")
        super().__init__(low, high, seed)
        self.goal_bias = goal_bias

    @property
    def goal_bias(self) -> float:
        return self._goal_bias

    @goal_bias.setter
    def goal_bias(self, value: float) -> None:
        self._goal_bias = float(value)
        # torch compares a float32 tensor with a Python float in float32; act() compares
        # Python floats, so it uses the float32-rounded rate to pick exactly the same samples.
        self._goal_bias32 = float(np.float32(value))

    def propose(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        start = obs["start"]
        shape = batch_shape_of(start)
        sample = self.uniform(shape)
        target = torch.where(obs["active_tree"].reshape(*shape, 1) == 1, start, obs["goal"])
        pick = torch.rand(*shape, 1, generator=self.generator) < self.goal_bias
        return torch.where(pick, target.to(sample.dtype), sample)

    def act(self, obs: Mapping) -> np.ndarray:
        if np.ndim(obs["start"]) != 1:
            return super().act(obs)
        # Unbatched fast path: the same two draws as propose(), the choice made in Python.
        sample = self.uniform(())
        if torch.rand(1, generator=self.generator).item() < self._goal_bias32:
            target = obs["start"] if int(np.asarray(obs["active_tree"]).reshape(-1)[0]) == 1 else obs["goal"]
            return np.array(target, dtype=np.float32)   # a copy: obs may be live views
        return sample.numpy()
