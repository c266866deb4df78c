"""Classical samplers: uniform and goal-biased."""

from __future__ import annotations

import numpy as np
import torch

from agents.samplers.base import Sampler, batch_shape_of


class UniformSampler(Sampler):
    """Uniform over the sampling bounds: the RRT/BiRRT default."""

    def forward(self, nodes, node_features, parent, mask, num_nodes, start, goal, active_tree):
        return self.uniform(batch_shape_of(start))


class GoalBiasSampler(Sampler):
    """Uniform, but with probability ``goal_bias`` the target of the active tree.

    For RRT (and BiRRT's start tree) the target is the goal; for BiRRT's goal tree it is
    the start, so both trees are pulled toward each other as in OMPL's goal biasing.
    """

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None,
                 goal_bias: float = 0.05) -> None:
        if not 0.0 <= goal_bias <= 1.0:
            raise ValueError(f"goal_bias must be in [0, 1], got {goal_bias}")
        self.goal_bias = float(goal_bias)
        super().__init__(low, high, seed)

    def forward(self, nodes, node_features, parent, mask, num_nodes, start, goal, active_tree):
        shape = batch_shape_of(start)
        sample = self.uniform(shape)
        target = torch.where(torch.as_tensor(active_tree).reshape(*shape, 1) == 1, start, goal)
        pick = torch.rand(*shape, 1, generator=self.generator) < self.goal_bias
        return torch.where(pick, target.to(sample.dtype), sample)
