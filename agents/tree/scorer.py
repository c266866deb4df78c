"""A learned tree sampler that *scores candidate samples* (the pendulum's GNN head).

The node-mixture head of :class:`agents.tree.models.TreeGNN` places samples around
tree nodes; on kinodynamic problems (the pendulum) where a sample lands matters less than
*which node the planner will extend* and toward where, and the mixture did not beat uniform
sampling there. :class:`TreeGNNScorer` keeps the causal tree GNN and replaces the head by a
classifier over candidate samples: draw ``M`` uniform candidates, score each, pick one with
``softmax(logit / temperature)`` (:class:`agents.tree.samplers.TreeScorerSampler`).

**Static (causal) layers.** As the tree GNN: node ``n`` receives messages from its parent and
from its ``knn`` nearest *earlier* nodes of its tree (nearest under the planner's metric,
:data:`metric_weights` times the wrapped difference), PyG :class:`~agents.nn.causal.RelativeConv` layers. An
embedding is fixed the moment its node is inserted.

**Frontier layer.** Node ``o`` also summarises the *newer* nodes that point at it at the
query time ``t``: its children and the later nodes that have ``o`` among their nearest
(:class:`FrontierConv`, a sum of ``MLP([h_s, (x_s - x_o) / step_scale, one_hot(type)])`` and
the count of each edge type). It tells the head how much the tree has already grown out of
``o``; online it is a running sum updated in ``O(knn)`` per insertion.

**Score.** For a candidate ``s`` with nearest tree node ``o`` (the node the planner extends)::

    logit(s) = MLP([h_o, frontier_sum_o / (1 + count_o), log1p(count_o), candidate features(s, x_o, goal)])

Trained as a classifier (binary cross-entropy): did this sample create the next node of the
eventual solution path? (:class:`train.tree.adapters.ScorerAdapter`.)

Node inputs are the environment's features (``[x_init - x_n, x_goal - x_n, tree_id]``), the
node's state, the goal, ``sin``/``cos`` of every periodic coordinate among them and the
node's depth in its tree (edges from the root; for kinodynamic trees, time).
"""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor
from torch_geometric.nn import MessagePassing

from agents.checkpoints import register_model_kind
from agents.nn.causal import CausalTreeTrunk, causal_knn, fixed_vector, mlp, wrap_periodic

#: Edge types of the causal graph: parent -> child, and k-NN (an earlier node -> a later one).
EDGE_TYPES = 2


def tree_depth(parent: Tensor) -> Tensor:
    """Edges from each node to its root, ``(N,)`` float (pointer jumping: ``log2(depth)`` steps;
    ``parent`` of a root is -1; several trees or runs may share the arrays)."""
    depth = (parent >= 0).float()
    anc = parent.clone()
    while bool((anc >= 0).any()):
        ok = anc >= 0
        a = anc.clamp(min=0)
        depth = torch.where(ok, depth + depth[a], depth)
        anc = torch.where(ok, anc[a], anc)
    return depth


def reverse_edges(parent: Tensor, knn: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The causal edges as ``(receiver, sender, type)``: the *older* node receives from the newer
    one (type 0: the newer node is its child, type 1: the newer node has it among its nearest)."""
    child = torch.nonzero(parent >= 0).flatten()
    rows, cols = torch.nonzero(knn >= 0, as_tuple=True)
    receiver = torch.cat([parent[child], knn[rows, cols]])
    sender = torch.cat([child, rows])
    etype = torch.cat([torch.zeros(len(child), dtype=torch.long), torch.ones(len(rows), dtype=torch.long)])
    return receiver, sender, etype


def frontier_edges(parent: Tensor, knn: Tensor, query_node: Tensor, query_time: Tensor) -> tuple[Tensor, Tensor]:
    """Edges of the frontier layer for a batch of queries: query ``q`` (node ``query_node[q]`` in
    the tree of the first ``query_time[q]`` rows) receives from every newer node ``s <
    query_time[q]`` that points at its node. Returns ``edge_index`` ``(2, E)`` (sender node,
    query) and the edge types ``(E,)``; vectorised (one sort, two searches)."""
    receiver, sender, etype = reverse_edges(parent, knn)
    n = max(len(parent), 1)
    key = receiver * n + sender
    order = torch.argsort(key, stable=True)
    key = key[order]
    lo = torch.searchsorted(key, query_node * n)
    hi = torch.searchsorted(key, query_node * n + query_time)       # senders < query_time
    counts = hi - lo
    slot = torch.repeat_interleave(torch.arange(len(query_node)), counts)
    first = torch.cumsum(counts, 0) - counts
    edge = order[lo[slot] + torch.arange(len(slot)) - first[slot]]
    return torch.stack([sender[edge], slot]), etype[edge]


class FrontierConv(MessagePassing):
    """Sum of ``MLP([h_s, rel, one_hot(type)])`` over the incoming edges, concatenated with the
    number of edges of each type: ``(Q, H + EDGE_TYPES)``. Senders are tree nodes, receivers
    queries (a bipartite graph, ``size=(N, Q)``). As :class:`~agents.nn.causal.RelativeConv`, the MLP's sender
    term is computed per node and its second (linear) layer after the sum."""

    def __init__(self, hidden_channels: int, state_dim: int) -> None:
        super().__init__(aggr="sum")
        self.net = mlp(hidden_channels + state_dim + EDGE_TYPES, hidden_channels, hidden_channels)

    def forward(self, h: Tensor, rel: Tensor, edge_type: Tensor, edge_index: Tensor, num_queries: int) -> Tensor:
        first, second = self.net[0], self.net[2]
        H = h.shape[-1]
        onehot = F.one_hot(edge_type, EDGE_TYPES).to(h.dtype)
        sender = F.linear(h, first.weight[:, :H])
        edge = F.linear(torch.cat([rel, onehot], -1), first.weight[:, H:], first.bias)
        out = self.propagate(edge_index, sender=sender, edge=edge, onehot=onehot, size=(h.shape[0], num_queries))
        total, counts = out[:, :H], out[:, H:]
        return torch.cat([F.linear(total, second.weight) + counts.sum(-1, keepdim=True) * second.bias, counts], -1)

    def message(self, sender_j: Tensor, edge: Tensor, onehot: Tensor) -> Tensor:
        return torch.cat([F.gelu(sender_j + edge), onehot], -1)


class TreeGNNScorer(CausalTreeTrunk):
    """Causal tree GNN (:class:`~agents.nn.causal.CausalTreeTrunk`) + frontier layer + candidate-sample scorer (see the module docstring).

    Args:
        state_dim: ``d``.
        hidden_channels / num_layers: node embedding width ``H`` and static message-passing layers.
        knn: causal nearest neighbours per node (planner metric).
        state_center / state_scale: ``(d,)``; states enter as ``(x - center) / scale``.
        feature_scale: ``(2d + 1,)`` divisor of the environment's node features.
        step_scale: ``(d,)`` unit of relative positions on edges (~ one extension).
        periodic: indices of angle coordinates (wrapped to ``[-pi, pi)``, also fed as sin/cos).
        metric_weights: ``(d,)`` the planner's nearest-neighbour metric,
            ``|| metric_weights * wrap(a - b) ||`` (default: Euclidean).
        depth_scale: divisor of a node's depth (edges from its root).
    """

    def __init__(self, state_dim: int, hidden_channels: int = 64, num_layers: int = 2, knn: int = 6, *,
                 state_center: Sequence[float] | None = None, state_scale: Sequence[float] | None = None,
                 feature_scale: Sequence[float] | None = None, step_scale: Sequence[float] | None = None,
                 periodic: Sequence[int] = (), metric_weights: Sequence[float] | None = None,
                 depth_scale: float = 40.0) -> None:
        super().__init__()
        d = int(state_dim)
        self.state_dim, self.hidden_channels = d, int(hidden_channels)
        self.num_layers, self.knn = int(num_layers), int(knn)
        self.depth_scale = float(depth_scale)

        p = len(set(periodic))
        self.build_trunk(4 * d + 2 + 6 * p, state_center=state_center, state_scale=state_scale,
                         feature_scale=feature_scale, step_scale=step_scale, periodic=periodic,
                         extra_buffers={"metric_weights": fixed_vector(metric_weights, 1.0, d)})
        H = self.hidden_channels
        self.frontier = FrontierConv(H, d)
        self.head = mlp(2 * H + EDGE_TYPES + 3 * d + 1 + 4 * p, H, 1, layers=3)

    # ------------------------------------------------------------------ inputs
    def _angles(self, x: Tensor) -> list[Tensor]:
        a = x[..., self.periodic]
        return [torch.sin(a), torch.cos(a)]

    def node_inputs(self, nodes: Tensor, features: Tensor, goal: Tensor, depth: Tensor) -> Tensor:
        """``(N, in)``: env features, state, goal (each scaled; periodic ones also as sin/cos), depth.
        ``goal`` is ``(d,)`` or ``(N, d)``."""
        d = self.state_dim
        goal = goal.expand(nodes.shape[0], d)
        return torch.cat([features / self.feature_scale, (nodes - self.state_center) / self.state_scale,
                          (goal - self.state_center) / self.state_scale, *self._angles(nodes),
                          *self._angles(features[..., d:2 * d]), *self._angles(goal),
                          (depth / self.depth_scale)[..., None]], -1)

    def candidate_features(self, samples: Tensor, near: Tensor, goal: Tensor) -> Tensor:
        """``(Q, 3d + 1 + 4p)``: offset from the nearest node (state units), its planner distance
        (step units), the offset to the goal, the sample (scaled; periodic ones also as sin/cos)."""
        rel = wrap_periodic(samples - near, self.periodic)
        to_goal = wrap_periodic(goal - samples, self.periodic)
        unit = torch.linalg.vector_norm(self.metric_weights * self.step_scale)
        dist = torch.linalg.vector_norm(self.metric_weights * rel, dim=-1, keepdim=True) / unit
        return torch.cat([rel / self.state_scale, dist, to_goal / self.state_scale,
                          (samples - self.state_center) / self.state_scale, *self._angles(samples),
                          *self._angles(to_goal)], -1)

    # ------------------------------------------------------------------ graph
    def causal_knn(self, nodes: Tensor, tree_id: Tensor) -> Tensor:
        """``(N, knn)`` earlier nearest nodes under the planner's metric (ties to the earlier node)."""
        return causal_knn(nodes, tree_id, self.knn, 1.0 / self.metric_weights, self.periodic)

    def nearest(self, samples: Tensor, nodes: Tensor) -> Tensor:
        """Index of each sample's nearest row of ``nodes`` under the planner's metric (first on ties)."""
        diff = wrap_periodic(samples[:, None] - nodes[None], self.periodic) * self.metric_weights
        return torch.argmin((diff * diff).sum(-1), dim=1)

    def embed(self, nodes: Tensor, features: Tensor, parent: Tensor, knn: Tensor, goal: Tensor) -> Tensor:
        """Static node embeddings ``(N, H)`` (causal: a node reads earlier nodes only)."""
        h = self.input(self.node_inputs(nodes, features, goal, tree_depth(parent)))
        return self.layers(h, nodes, parent, knn)

    # ------------------------------------------------------------------ scores
    def score(self, h_near: Tensor, frontier: Tensor, candidate: Tensor) -> Tensor:
        """Logits ``(Q,)`` from the nearest node's embedding, its frontier ``(Q, H + types)`` (sum,
        counts) and the candidate features."""
        H = self.hidden_channels
        total, counts = frontier[:, :H], frontier[:, H:]
        z = torch.cat([h_near, total / (1 + counts.sum(-1, keepdim=True)), torch.log1p(counts), candidate], -1)
        return self.head(z)[:, 0]

    def forward(self, nodes: Tensor, features: Tensor, parent: Tensor, knn: Tensor, goal: Tensor,
                query_node: Tensor, query_time: Tensor, samples: Tensor, query_goal: Tensor | None = None) -> Tensor:
        """Logits ``(Q,)`` of candidate ``samples[q]`` whose nearest node is ``query_node[q]`` in the
        tree of the first ``query_time[q]`` rows. Several runs may be stacked (disjoint indices;
        ``goal`` then per node ``(N, d)`` and ``query_goal`` per query ``(Q, d)``)."""
        h = self.embed(nodes, features, parent, knn, goal)
        edge_index, etype = frontier_edges(parent, knn, query_node, query_time)
        rel = self.relative(nodes[edge_index[0]], nodes[query_node[edge_index[1]]])
        front = self.frontier(h, rel, etype, edge_index, len(query_node))
        qgoal = goal.expand(len(query_node), -1) if query_goal is None else query_goal
        cand = self.candidate_features(samples, nodes[query_node], qgoal)
        return self.score(h[query_node], front, cand)


register_model_kind("tree/gnn-scorer", TreeGNNScorer)

__all__ = ["EDGE_TYPES", "FrontierConv", "TreeGNNScorer", "frontier_edges", "reverse_edges", "tree_depth"]
