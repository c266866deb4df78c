"""What training needs to know about each learned tree sampler: build it for a task, cut a
dataset into its training items, and score a batch of items (one *adapter* per model).

An adapter is the only model-specific piece of ``gnn-mp train sampler``: the loop in
:mod:`train.tree.training` and the DAgger rounds are written once. The task facts the models
need (step scale, periodic coordinates, number of trees, the planner's metric, which GNN head,
the sampling settings shipped with the weights) come from the task's
:class:`~gnn_mp_envs.registration.TaskSpec`, so a task registered from outside the package
trains as it benchmarks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces

from agents.rl.run_config import TREE_GNN_ARCH
from agents.tree.models import TreeCVAE, TreeGNN, TreeGNNCVAE
from agents.tree.scorer import TreeGNNScorer
from gnn_mp_envs.registration import TaskSpec, task_spec
from train.tree.args import MODELS as ARG_MODELS
from train.tree.data import TreeDataset
from train.tree.items import Run, ScorerRun, make_run, make_scorer_run


@dataclass(frozen=True)
class TaskScales:
    """A task's facts as the models take them (from its ``TaskSpec`` and one probe environment)."""

    spec: TaskSpec
    observation_space: spaces.Dict
    step_scale: float        # the spec's, else the problems' step size

    @property
    def state_dim(self) -> int:
        return int(self.observation_space["start"].shape[0])

    def space_scales(self) -> dict[str, list[float]]:
        """State centre / half-span and node-feature scales from the observation space."""
        start = self.observation_space["start"]
        low, high = np.asarray(start.low, np.float64), np.asarray(start.high, np.float64)
        half = (high - low) / 2
        return {"state_center": ((high + low) / 2).tolist(), "state_scale": half.tolist(),
                "feature_scale": np.concatenate([2 * half, 2 * half, [1.0]]).tolist()}


def task_scales(task: str) -> TaskScales:
    """The :class:`TaskScales` of a registered task (builds its benchmark environment once)."""
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401  (registers the built-in ids)
    spec = task_spec(task)
    env = gym.make(spec.env_id, max_nodes=2, disable_env_checker=True)
    try:
        env.reset(seed=0, options={"index": 0})
        step = spec.step_scale if spec.step_scale is not None else float(env.unwrapped.problem.step_size)
        return TaskScales(spec, env.observation_space, float(step))
    finally:
        env.close()


class Adapter(Protocol):
    kind: str

    def build(self, scales: TaskScales, **overrides) -> tuple[torch.nn.Module, dict]: ...
    def items(self, model: torch.nn.Module, data: TreeDataset, view: str, rng: np.random.Generator,
              max_snapshots: int) -> list[Any]: ...
    def loss(self, model: torch.nn.Module, items: Sequence[Any],
             generator: torch.Generator | None = None) -> tuple[torch.Tensor, int, dict[str, float]]: ...


class GNNAdapter:
    """The causal tree GNN with its node-mixture head; items are runs, the loss their mixture NLL."""

    kind = "tree/gnn"
    model_class = TreeGNN
    #: The shipped architecture (also what RL's ``--encoder tree-gnn`` builds, to warm-start from it).
    hidden_channels, num_layers, knn = (TREE_GNN_ARCH[k] for k in ("hidden_channels", "num_layers", "knn"))

    def ctor_args(self, scales: TaskScales, **overrides) -> dict:
        d, spec = scales.state_dim, scales.spec
        args = {"state_dim": d, "hidden_channels": self.hidden_channels, "num_layers": self.num_layers,
                "knn": self.knn, **scales.space_scales(), "step_scale": [scales.step_scale] * d,
                "periodic": list(spec.periodic), "num_trees": spec.num_trees()}
        args.update(overrides)
        return args

    def build(self, scales: TaskScales, **overrides) -> tuple[torch.nn.Module, dict]:
        args = self.ctor_args(scales, **overrides)
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

    def ctor_args(self, scales, **overrides):
        args = super().ctor_args(scales)
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

    def build(self, scales, **overrides):
        d = scales.state_dim
        obstacles = int(np.prod(scales.observation_space["obstacles"].shape))
        space = scales.space_scales()
        args = {"state_dim": d, "condition_dim": 2 * d + obstacles, "hidden_channels": 128, "latent_channels": 4,
                "state_center": space["state_center"], "state_scale": space["state_scale"],
                "periodic": list(scales.spec.periodic), **overrides}
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

    def ctor_args(self, scales: TaskScales, **overrides) -> dict:
        spec, d = scales.spec, scales.state_dim
        if spec.num_trees() != 1:
            raise ValueError(f"the sample scorer supports RRT (one tree); task {spec.name!r} plans "
                             f"{spec.num_trees()} trees")
        args = {"state_dim": d, "hidden_channels": 64, "num_layers": 2, "knn": 6, **scales.space_scales(),
                "step_scale": [scales.step_scale] * d, "periodic": list(spec.periodic),
                "metric_weights": list(spec.metric_weights or [1.0] * d)}
        args.update(overrides)
        return args

    def build(self, scales, **overrides):
        args = self.ctor_args(scales, **overrides)
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
MODELS = tuple(ADAPTERS)
assert MODELS == ARG_MODELS, "train.tree.args.MODELS names the adapters' models"


def adapter_for(model: str, task: str) -> Adapter:
    """The adapter of ``model`` for ``task``: the ``gnn`` head is the one its ``TaskSpec`` names
    (``"scorer"``: :class:`ScorerAdapter`, else the node mixture)."""
    if model == "gnn" and task_spec(task).gnn_head == "scorer":
        return ScorerAdapter()
    return ADAPTERS[model]


__all__ = ["ADAPTERS", "MODELS", "Adapter", "CVAEAdapter", "GNNAdapter", "GNNCVAEAdapter", "ScorerAdapter",
           "TaskScales", "adapter_for", "task_scales"]
