"""Training examples as tensors: one *run* (a solved problem's tree and its snapshots) per item.

The causal GNN embeds a node from older nodes only, so one forward pass over a run's tree
serves every snapshot (a prefix of the tree in insertion order); a run carries the tree up to
its largest snapshot, the causal k-NN edges, and per snapshot its size, active tree and label.
The sample scorer's items (:class:`ScorerRun`) are the same trees with the iterations' samples
as classification queries.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import torch

from agents.nn.causal import causal_knn, wrap_periodic
from train.tree.data import TreeDataset, reindex


@dataclass
class Run:
    nodes: torch.Tensor       # (N, d)
    features: torch.Tensor    # (N, 2d+1)
    parent: torch.Tensor      # (N,)
    tree_id: torch.Tensor     # (N,)
    knn: torch.Tensor         # (N, k)
    start: torch.Tensor       # (1, d)
    goal: torch.Tensor        # (1, d)
    obstacles: torch.Tensor   # (M, 1+w)
    sizes: torch.Tensor       # (T,) snapshot sizes
    active: torch.Tensor      # (T,)
    labels: torch.Tensor      # (T, d) the next sample of each snapshot

    def tree_args(self) -> tuple[torch.Tensor, ...]:
        """The positional arguments of ``TreeGNN.run_nll`` / ``TreeGNNCVAE.run_loss``."""
        return (self.nodes, self.features, self.parent, self.tree_id, self.knn, self.start, self.goal,
                self.sizes, self.active, self.labels)


def make_run(data: TreeDataset, p: int, view: str, knn: int, step_scale: torch.Tensor, periodic: torch.Tensor,
             max_snapshots: int, rng: np.random.Generator, max_nodes: int = 4000) -> Run | None:
    """Problem ``p`` as a :class:`Run` (at most ``max_snapshots`` snapshots, drawn with ``rng``,
    of trees up to ``max_nodes`` nodes); None when it has no snapshot."""
    rows, sizes, active, labels = data.snapshots(p, view)
    keep = sizes <= max_nodes
    sizes, active, labels = sizes[keep], active[keep], labels[keep]
    if len(sizes) == 0:
        return None
    if len(sizes) > max_snapshots:
        pick = np.sort(rng.choice(len(sizes), max_snapshots, replace=False))
        sizes, active, labels = sizes[pick], active[pick], labels[pick]
    n = int(sizes.max())
    rows = rows[:n]
    states, parent, tree_id = data.tree(p)
    a = data.node_ptr[p]
    nodes = torch.as_tensor(states[rows])
    tid = torch.as_tensor(tree_id[rows].astype(np.int64))
    return Run(nodes=nodes, features=torch.as_tensor(data.node_features[a + rows]),
               parent=torch.as_tensor(reindex(parent, rows).astype(np.int64)), tree_id=tid,
               knn=causal_knn(nodes, tid, knn, step_scale, periodic),
               start=torch.as_tensor(data.start[p])[None], goal=torch.as_tensor(data.goal[p])[None],
               obstacles=torch.as_tensor(data.obstacles[p]), sizes=torch.as_tensor(sizes),
               active=torch.as_tensor(active), labels=torch.as_tensor(states[labels]))


@dataclass
class ScorerRun:
    """A solved problem as sample-classification queries (:class:`TreeGNNScorer`): the tree up
    to its largest query, and per query the sample, its nearest node, the tree size then and
    the label (did the sample create a node of the final solution path)."""

    nodes: torch.Tensor        # (N, d)
    features: torch.Tensor     # (N, 2d+1)
    parent: torch.Tensor       # (N,)
    knn: torch.Tensor          # (N, k) causal nearest (planner metric)
    goal: torch.Tensor         # (d,)
    near: torch.Tensor         # (Q,) nearest node of each sample (the node the planner extended)
    sizes: torch.Tensor        # (Q,) tree size before the sample's iteration
    samples: torch.Tensor      # (Q, d)
    labels: torch.Tensor       # (Q,) 1.0: the sample created the next solution-path node


def sample_labels(data: TreeDataset, p: int) -> np.ndarray:
    """Per iteration of problem ``p``: True where its sample created a node of the final solution path."""
    on_path = np.zeros(data.node_ptr[p + 1] - data.node_ptr[p], dtype=bool)
    on_path[data.path(p)] = True
    created = data.iter_created[data.iter_ptr[p]:data.iter_ptr[p + 1]]
    return (created >= 0) & on_path[np.maximum(created, 0)]


def make_scorer_run(data: TreeDataset, p: int, model, negatives: int, rng: np.random.Generator,
                    max_nodes: int = 4000) -> ScorerRun | None:
    """Problem ``p``'s queries: every sample that created a solution-path node (positives) and
    ``negatives`` other samples drawn with ``rng``, of iterations on trees up to ``max_nodes``
    nodes; None when there is none. ``model`` (a :class:`TreeGNNScorer`) gives the metric."""
    i0, i1 = data.iter_ptr[p], data.iter_ptr[p + 1]
    sizes = data.iter_nodes[i0:i1].astype(np.int64)
    active = data.iter_active[i0:i1].astype(np.int64)
    created = data.iter_created[i0:i1].astype(np.int64)
    label = sample_labels(data, p)
    ok = sizes <= max_nodes
    pos = np.flatnonzero(label & ok)
    neg = np.flatnonzero(~label & ok)
    neg = np.sort(rng.choice(neg, min(negatives, len(neg)), replace=False))
    q = np.concatenate([pos, neg])
    if len(q) == 0:
        return None
    n = int(sizes[q].max())
    states, parent, tree_id = data.tree(p)
    nodes = torch.as_tensor(states[:n])
    tid = torch.as_tensor(tree_id[:n].astype(np.int64))
    samples = torch.as_tensor(data.iter_sample[i0:i1][q])
    # nearest node: the created node's parent, else the planner's nearest in the tree of that iteration
    near = np.where(created[q] >= 0, parent[np.maximum(created[q], 0)], -1).astype(np.int64)
    blocked = np.flatnonzero(near < 0)
    if len(blocked):
        with torch.no_grad():
            diff = wrap_periodic(samples[blocked, None] - nodes[None], model.periodic) * model.metric_weights
            dist = (diff * diff).sum(-1)
            later = torch.arange(n)[None] >= torch.as_tensor(sizes[q][blocked])[:, None]
            other = tid[None] != torch.as_tensor(active[q][blocked])[:, None]
            near[blocked] = torch.argmin(dist.masked_fill(later | other, float("inf")), 1).numpy()
    a = data.node_ptr[p]
    return ScorerRun(nodes=nodes, features=torch.as_tensor(data.node_features[a:a + n]),
                     parent=torch.as_tensor(parent[:n].astype(np.int64)), knn=model.causal_knn(nodes, tid),
                     goal=torch.as_tensor(data.goal[p]), near=torch.as_tensor(near),
                     sizes=torch.as_tensor(sizes[q]), samples=samples,
                     labels=torch.as_tensor(label[q].astype(np.float32)))


# ---------------------------------------------------------------------------- symmetry augmentation
@dataclass(frozen=True)
class Symmetry:
    """A linear map of ``x - centre`` (periodic coordinates wrapped after) under which a task's
    problems are equally likely (``TaskSpec.symmetries``): a training example mapped by it is
    another valid example. Distances are preserved, so causal k-NN edges and labels' roles stay."""

    matrix: torch.Tensor      # (d, d), orthogonal
    centre: torch.Tensor      # (d,)
    periodic: torch.Tensor    # (d,) bool

    def _wrap(self, x: torch.Tensor) -> torch.Tensor:
        return wrap_periodic(x, self.periodic) if bool(self.periodic.any()) else x

    def states(self, x: torch.Tensor) -> torch.Tensor:
        return self._wrap((x - self.centre) @ self.matrix.T + self.centre)

    def deltas(self, v: torch.Tensor) -> torch.Tensor:
        return self._wrap(v @ self.matrix.T)

    def features(self, f: torch.Tensor) -> torch.Tensor:
        """The environment's node features ``[x_init - x_n, x_goal - x_n, tree_id]``."""
        d = self.matrix.shape[0]
        return torch.cat([self.deltas(f[:, :d]), self.deltas(f[:, d:2 * d]), f[:, 2 * d:]], -1)


def symmetries_of(matrices: Sequence, low: np.ndarray, high: np.ndarray, periodic: torch.Tensor) -> list[Symmetry]:
    """The task's symmetry matrices as :class:`Symmetry` maps about the state box's centre."""
    centre = torch.as_tensor((np.asarray(low, np.float64) + np.asarray(high, np.float64)) / 2, dtype=torch.float32)
    return [Symmetry(torch.as_tensor(np.asarray(m, np.float64), dtype=torch.float32), centre, periodic.bool())
            for m in matrices]


def transformed(item: Run | ScorerRun, sym: Symmetry) -> Run | ScorerRun:
    """A training item mapped by ``sym`` (a new item; the original is untouched)."""
    if isinstance(item, Run):
        return replace(item, nodes=sym.states(item.nodes), features=sym.features(item.features),
                       start=sym.states(item.start), goal=sym.states(item.goal), labels=sym.states(item.labels))
    if isinstance(item, ScorerRun):
        return replace(item, nodes=sym.states(item.nodes), features=sym.features(item.features),
                       goal=sym.states(item.goal), samples=sym.states(item.samples))
    return item

