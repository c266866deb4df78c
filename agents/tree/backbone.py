"""The supervised GNN sampler's causal backbone with the shared encoder interface, for RL policies.

Registered on the shared floor as the backbone ``"tree-gnn"`` (:data:`agents.nn.encoders.ENCODERS`):
an RL policy built on it (``gnn-mp train rl --encoder tree-gnn``) reaches it by that name and can
start from the GNN sampler's trained weights (``--init-from``).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch
from gymnasium import spaces
from torch import nn

from agents.nn.causal import causal_knn
from agents.nn.graph import to_pyg
from agents.tree.models import TreeGNN


class TreeGNNEncoder(nn.Module):
    """The supervised GNN sampler's backbone (:class:`agents.tree.models.TreeGNN`) with
    the encoder interface: padded observation -> ``(node_embeddings, graph_embedding, batch)``.

    The graph embedding is the GNN's tree context ``q`` (start, goal, active tree, each tree's
    mean embedding and size), width ``hidden_channels``. RL policies built on it share one
    backbone with the GNN sampler, so they can start from its trained weights
    (``gnn-mp train rl --encoder tree-gnn --init-from agents/checkpoints/gnn_maze2d.pt``;
    ``backbone="tree-gnn"`` in the SB3 extractor's and the TorchRL modules' keyword arguments).
    Constructor arguments are :class:`TreeGNN`'s.
    """

    def __init__(self, **gnn_kwargs) -> None:
        super().__init__()
        self.gnn_kwargs = dict(gnn_kwargs)
        self.gnn = TreeGNN(**gnn_kwargs)
        self.out_channels = self.gnn.hidden_channels

    @property
    def backbone(self) -> nn.Module:
        """The module a warm start copies weights into: the :class:`TreeGNN`."""
        return self.gnn

    def config(self) -> dict:
        """Constructor arguments that rebuild this encoder through the registry (``"class"``: its name)."""
        return {"class": "tree-gnn", **self.gnn_kwargs}

    @classmethod
    def from_space(cls, observation_space: spaces.Dict, **kwargs) -> "TreeGNNEncoder":
        """Scaled for an env's observation space; ``step_scale`` (a number or per dimension),
        ``periodic`` and ``num_trees`` are the task's (its ``TaskSpec``)."""
        start = observation_space["start"]
        low, high = np.asarray(start.low, np.float64), np.asarray(start.high, np.float64)
        d = int(low.shape[0])
        half = (high - low) / 2
        kwargs.setdefault("state_dim", d)
        kwargs.setdefault("state_center", ((high + low) / 2).tolist())
        kwargs.setdefault("state_scale", half.tolist())
        kwargs.setdefault("feature_scale", np.concatenate([2 * half, 2 * half, [1.0]]).tolist())
        step = kwargs.get("step_scale", 1.0)
        kwargs["step_scale"] = [float(step)] * d if np.ndim(step) == 0 else list(step)
        return cls(**kwargs)

    def forward(self, obs: Mapping) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        g = self.gnn
        graph = to_pyg(obs)
        batch_shape = torch.Size(obs["node_features"].shape[:-2])
        B = int(np.prod(batch_shape)) if len(batch_shape) else 1
        n = graph.x.shape[0]
        batch = graph.batch if len(batch_shape) else torch.zeros(n, dtype=torch.long)
        # Tree edges come both ways; a parent is always the earlier node (insertion order).
        e = graph.edge_index[:, graph.edge_index[0] < graph.edge_index[1]]
        parent = torch.full((n,), -1, dtype=torch.long)
        parent[e[1]] = e[0]
        tree_id = graph.x[:, 2 * g.state_dim].round().long().clamp(0, g.num_trees - 1)
        group = batch * g.num_trees + tree_id      # k-NN within one observation's tree
        knn = causal_knn(graph.pos.detach(), group, g.knn, g.step_scale, g.periodic)
        h = g.embed(graph.pos, graph.x, parent, knn)
        sums = h.new_zeros(B * g.num_trees, h.shape[1]).index_add_(0, group, h)
        counts = h.new_zeros(B * g.num_trees).index_add_(0, group, torch.ones_like(group, dtype=h.dtype))
        means = (sums / counts.clamp(min=1)[:, None]).view(B, g.num_trees, -1)
        active = graph.active_tree.reshape(-1).long().clamp(0, g.num_trees - 1)
        q = g.context(graph.start.reshape(B, -1), graph.goal.reshape(B, -1), active, means,
                      counts.view(B, g.num_trees))
        return h, q.reshape(*batch_shape, -1), batch


__all__ = ["TreeGNNEncoder"]
