"""Training examples as tensors: one *run* (a solved problem's tree and its snapshots) per item.

The causal GNN embeds a node from older nodes only, so one forward pass over a run's tree
serves every snapshot (a prefix of the tree in insertion order); a run carries the tree up to
its largest snapshot, the causal k-NN edges, and per snapshot its size, active tree and label.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from agents.models.tree_samplers import causal_knn
from train.tree_samplers.data import TreeDataset, reindex


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
