"""What training needs to know about each learned tree sampler: build it for a task, cut a
dataset into its training items, and score a batch of items (one *adapter* per model).

An adapter is the only model-specific piece of ``gnn-mp train sampler``: the loop in
:mod:`train.tree_samplers.training` and the DAgger rounds are written once. Task defaults
(architecture, scales, the sampling settings shipped with the weights) live here too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces

from agents.models.tree_samplers import TreeCVAE, TreeGNN, TreeGNNCVAE
from agents.models.tree_scorer import TreeGNNScorer
from gnn_mp_envs.tasks.pendulum import VELOCITY_WEIGHT
from train.tree_samplers.data import TreeDataset
from train.tree_samplers.runs import Run, ScorerRun, make_run, make_scorer_run


@dataclass(frozen=True)
class TaskDefaults:
    """Per-task facts the models need that the observation space does not say."""

    step_scale: float                      # ~ one extension in state units (relative positions, offsets)
    periodic: tuple[int, ...] = ()         # angle coordinates
    num_trees: int = 1                     # 2 for BiRRT
    max_snapshots: int = 96                # snapshots per run in an epoch (scorer: negative samples per run)
    metric_weights: tuple[float, ...] | None = None   # the planner's nearest-neighbour metric (None: Euclidean)
    sampler: dict[str, dict[str, Any]] = field(default_factory=dict)   # model -> sampling settings


#: Chosen on the validation split (see docs/learned_samplers.md); shipped with the weights.
TASKS: dict[str, TaskDefaults] = {
    "maze2d": TaskDefaults(step_scale=0.05, num_trees=1,
                           sampler={"gnn": {"uniform_mix": 0.25, "temperature": 0.5, "sigma_scale": 0.6},
                                    "cvae": {"uniform_mix": 0.5}, "gnn-cvae": {"uniform_mix": 0.5}}),
    # The pendulum's "gnn" is the sample scorer (TASK_HEADS): M=16 candidates, 20% uniform, 5% goal.
    "pendulum": TaskDefaults(step_scale=0.4, periodic=(0,), num_trees=1, metric_weights=(1.0, VELOCITY_WEIGHT),
                             sampler={"gnn": {"uniform_mix": 0.2, "goal_bias": 0.05, "candidates": 16,
                                              "temperature": 1.0},
                                      "cvae": {"uniform_mix": 0.5}, "gnn-cvae": {"uniform_mix": 0.5}}),
    "arm": TaskDefaults(step_scale=0.4, num_trees=2,
                        sampler={"gnn": {"uniform_mix": 0.25, "temperature": 0.5, "sigma_scale": 0.6},
                                 "cvae": {"uniform_mix": 0.5}, "gnn-cvae": {"uniform_mix": 0.5}}),
}


def space_scales(observation_space: spaces.Dict) -> dict[str, list[float]]:
    """State centre / half-span and node-feature scales from an env's observation space."""
    start = observation_space["start"]
    low, high = np.asarray(start.low, np.float64), np.asarray(start.high, np.float64)
    half = (high - low) / 2
    return {"state_center": ((high + low) / 2).tolist(), "state_scale": half.tolist(),
            "feature_scale": np.concatenate([2 * half, 2 * half, [1.0]]).tolist()}


class Adapter(Protocol):
    kind: str

    def build(self, task: str, observation_space: spaces.Dict, **overrides) -> tuple[torch.nn.Module, dict]: ...
    def items(self, model: torch.nn.Module, data: TreeDataset, view: str, rng: np.random.Generator,
              max_snapshots: int) -> list[Any]: ...
    def loss(self, model: torch.nn.Module, items: Sequence[Any],
             generator: torch.Generator | None = None) -> tuple[torch.Tensor, int, dict[str, float]]: ...


class GNNAdapter:
    """The causal tree GNN with its node-mixture head; items are runs, the loss their mixture NLL."""

    kind = "tree/gnn"
    model_class = TreeGNN
    #: The shipped architecture (also what RL's ``--encoder tree-gnn`` builds, to warm-start from it).
    hidden_channels, num_layers, knn = 64, 2, 6

    def ctor_args(self, task: str, observation_space: spaces.Dict, **overrides) -> dict:
        t = TASKS[task]
        d = int(observation_space["start"].shape[0])
        args = {"state_dim": d, "hidden_channels": self.hidden_channels, "num_layers": self.num_layers,
                "knn": self.knn, **space_scales(observation_space),
                "step_scale": [t.step_scale] * d, "periodic": list(t.periodic), "num_trees": t.num_trees}
        args.update(overrides)
        return args

    def build(self, task: str, observation_space: spaces.Dict, **overrides) -> tuple[torch.nn.Module, dict]:
        args = self.ctor_args(task, observation_space, **overrides)
        return self.model_class(**args), args

    def _gnn(self, model: torch.nn.Module) -> TreeGNN:
        return model

    def items(self, model, data, view, rng, max_snapshots) -> list[Run]:
        g = self._gnn(model)
        runs = [make_run(data, p, view, g.knn, g.step_scale, g.periodic, max_snapshots, rng) for p in range(len(data))]
        return [r for r in runs if r is not None]

    def loss(self, model, items, generator=None):
        total = sum(model.run_nll(*run.tree_args()).sum() for run in items)
        count = sum(len(run.sizes) for run in items)
        return total / max(count, 1), count, {}


class GNNCVAEAdapter(GNNAdapter):
    """The GNN-CVAE: the same runs; the loss is its ELBO (reconstruction + KL) per snapshot."""

    kind = "tree/gnn-cvae"
    model_class = TreeGNNCVAE
    kl_weight = 0.05

    def ctor_args(self, task, observation_space, **overrides):
        args = super().ctor_args(task, observation_space)
        args.update({"latent_channels": 4, **overrides})
        return args

    def _gnn(self, model):
        return model.gnn

    def loss(self, model, items, generator=None):
        total, count = 0.0, 0
        for run in items:
            value, n = model.run_loss(*run.tree_args(), kl_weight=self.kl_weight, generator=generator)
            total, count = total + value, count + int(n)
        return total / max(count, 1), count, {}


@dataclass
class PathStates:
    """CVAE items: one problem's condition and its solution-path states (roots excluded)."""

    condition: torch.Tensor   # (C,)
    states: torch.Tensor      # (L, d)


class CVAEAdapter:
    """Ichter et al.'s CVAE: condition = start, goal, obstacle rows; targets = solution-path states."""

    kind = "tree/cvae"
    kl_weight = 0.05

    def build(self, task, observation_space, **overrides):
        t = TASKS[task]
        d = int(observation_space["start"].shape[0])
        obstacles = int(np.prod(observation_space["obstacles"].shape))
        scales = space_scales(observation_space)
        args = {"state_dim": d, "condition_dim": 2 * d + obstacles, "hidden_channels": 128, "latent_channels": 4,
                "state_center": scales["state_center"], "state_scale": scales["state_scale"],
                "periodic": list(t.periodic), **overrides}
        return TreeCVAE(**args), args

    def items(self, model, data, view, rng, max_snapshots) -> list[PathStates]:
        out = []
        center, scale = model.state_center.numpy(), model.state_scale.numpy()
        for p in range(len(data)):
            states, parent, _ = data.tree(p)
            path = [j for j in data.path(p) if parent[j] >= 0]
            if not path:
                continue
            condition = np.concatenate([(data.start[p] - center) / scale, (data.goal[p] - center) / scale,
                                        data.obstacles[p].reshape(-1)]).astype(np.float32)
            out.append(PathStates(torch.as_tensor(condition), torch.as_tensor(states[path])))
        return out

    def loss(self, model, items, generator=None):
        x = torch.cat([it.states for it in items])
        c = torch.cat([it.condition.expand(len(it.states), -1) for it in items])
        value, metrics = model.loss(x, c, kl_weight=self.kl_weight, generator=generator)
        return value, len(x), metrics


class ScorerAdapter:
    """The GNN sample scorer (:class:`TreeGNNScorer`): items are runs of classification queries
    built from the dataset's iteration records (every sample that created a solution-path node,
    ``max_snapshots`` other samples per run; the ``view`` does not apply), the loss their binary
    cross-entropy. RRT (one tree) only."""

    kind = "tree/gnn-scorer"
    loss_name = "BCE per sample"

    def ctor_args(self, task: str, observation_space: spaces.Dict, **overrides) -> dict:
        t = TASKS[task]
        if t.num_trees != 1:
            raise ValueError(f"the sample scorer supports RRT (one tree); task {task!r} plans {t.num_trees} trees")
        d = int(observation_space["start"].shape[0])
        args = {"state_dim": d, "hidden_channels": 64, "num_layers": 2, "knn": 6, **space_scales(observation_space),
                "step_scale": [t.step_scale] * d, "periodic": list(t.periodic),
                "metric_weights": list(t.metric_weights or [1.0] * d)}
        args.update(overrides)
        return args

    def build(self, task, observation_space, **overrides):
        args = self.ctor_args(task, observation_space, **overrides)
        return TreeGNNScorer(**args), args

    def items(self, model, data, view, rng, max_snapshots) -> list[ScorerRun]:
        runs = [make_scorer_run(data, p, model, max_snapshots, rng) for p in range(len(data))]
        return [r for r in runs if r is not None]

    def loss(self, model, items, generator=None):
        """Mean BCE over the queries of ``items`` (stacked into one disjoint graph: one forward)."""
        offsets = np.concatenate([[0], np.cumsum([len(r.nodes) for r in items])])
        shift = lambda t, o: torch.where(t >= 0, t + int(o), t)  # noqa: E731
        nodes = torch.cat([r.nodes for r in items])
        goal = torch.cat([r.goal.expand(len(r.nodes), -1) for r in items])
        query_goal = torch.cat([r.goal.expand(len(r.near), -1) for r in items])
        logits = model(nodes, torch.cat([r.features for r in items]),
                       torch.cat([shift(r.parent, o) for r, o in zip(items, offsets)]),
                       torch.cat([shift(r.knn, o) for r, o in zip(items, offsets)]), goal,
                       torch.cat([r.near + int(o) for r, o in zip(items, offsets)]),
                       torch.cat([r.sizes + int(o) for r, o in zip(items, offsets)]),
                       torch.cat([r.samples for r in items]), query_goal)
        labels = torch.cat([r.labels for r in items])
        return F.binary_cross_entropy_with_logits(logits, labels), len(labels), {}


ADAPTERS: dict[str, Adapter] = {"gnn": GNNAdapter(), "cvae": CVAEAdapter(), "gnn-cvae": GNNCVAEAdapter()}


def adapter_for(model: str, task: str) -> Adapter:
    """The adapter of ``model`` for ``task`` (a task may ship another GNN head: see TASK_HEADS)."""
    return TASK_HEADS.get((model, task), ADAPTERS[model])


#: (model, task) -> adapter, where a task's best GNN head is not the node mixture.
TASK_HEADS: dict[tuple[str, str], Adapter] = {("gnn", "pendulum"): ScorerAdapter()}


__all__ = ["ADAPTERS", "Adapter", "CVAEAdapter", "GNNAdapter", "GNNCVAEAdapter", "ScorerAdapter", "TASKS", "TASK_HEADS",
           "TaskDefaults", "adapter_for", "space_scales"]
