"""The causal tree GNN trunk: what :class:`agents.tree.models.TreeGNN` and
:class:`agents.tree.scorer.TreeGNNScorer` share.

A causal graph network over the planner's tree: node ``n`` receives messages only from its parent
and from its ``knn`` nearest *earlier* nodes of the same tree (:class:`RelativeConv` layers,
messages built from the sender's embedding and the relative position ``(x_j - x_n) /
step_scale``), so a node's embedding is fixed the moment it is inserted.

:class:`CausalTreeTrunk` holds the trunk's buffers (``state_center``, ``state_scale``,
``feature_scale``, ``step_scale``, ``periodic``), its layers (``input``, ``parent_convs``,
``knn_convs``, ``updates``, ``norms``) and the message-passing loop (:meth:`CausalTreeTrunk.layers`);
a model inherits it and adds its input features and its head. The attribute names are part of the
checkpoint format (the state dict keys of the shipped ``tree/gnn``, ``tree/gnn-cvae`` and
``tree/gnn-scorer`` weights): a model calls :meth:`CausalTreeTrunk.build_trunk` in its constructor
at the place the layers belong in its state dict.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch_geometric.nn import MessagePassing


def mlp(in_channels: int, hidden_channels: int, out_channels: int, layers: int = 2) -> nn.Sequential:
    """``layers`` linear layers with GELU between them."""
    mods: list[nn.Module] = []
    width = in_channels
    for _ in range(layers - 1):
        mods += [nn.Linear(width, hidden_channels), nn.GELU()]
        width = hidden_channels
    return nn.Sequential(*mods, nn.Linear(width, out_channels))


def fixed_vector(values: Sequence[float] | Tensor | None, default: float, n: int) -> Tensor:
    """``n`` float32 values (``default`` everywhere when ``values`` is None); refuses another length."""
    t = torch.full((n,), default) if values is None else torch.as_tensor(values, dtype=torch.float32)
    if t.shape != (n,):
        raise ValueError(f"expected {n} values, got {tuple(t.shape)}")
    return t.float()


def wrap_periodic(delta: Tensor, periodic: Tensor) -> Tensor:
    """Wrap the periodic columns (a bool mask) of a state difference into ``[-pi, pi)``."""
    if not bool(periodic.any()):
        return delta
    wrapped = torch.remainder(delta + math.pi, 2 * math.pi) - math.pi
    return torch.where(periodic, wrapped, delta)


def causal_knn(nodes: Tensor, tree_id: Tensor, k: int, step_scale: Tensor, periodic: Tensor,
               chunk: int = 1024) -> Tensor:
    """``(N, k)`` indices of each node's ``k`` nearest *earlier* nodes of its own tree (-1 pads),
    distances in ``step_scale`` units (periodic columns wrapped), ties to the earlier node.
    Exact; chunked over rows."""
    n = nodes.shape[0]
    out = torch.full((n, k), -1, dtype=torch.long)
    if n < 2 or k == 0:
        return out
    index = torch.arange(n)
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        diff = wrap_periodic(nodes[None, :hi] - nodes[lo:hi, None], periodic) / step_scale
        dist = (diff * diff).sum(-1)                                     # (rows, hi)
        allowed = (index[None, :hi] < index[lo:hi, None]) & (tree_id[None, :hi] == tree_id[lo:hi, None])
        dist = dist.masked_fill(~allowed, float("inf"))
        kk = min(k, hi)
        d, j = torch.sort(dist, dim=1, stable=True)   # ties (duplicate states) go to the earlier node
        d, j = d[:, :kk], j[:, :kk]
        out[lo:hi, :kk] = torch.where(torch.isfinite(d), j, torch.full_like(j, -1))
    return out


class RelativeConv(MessagePassing):
    """Mean of ``MLP([h_j, (x_j - x_i) / step_scale])`` over the incoming edges ``j -> i`` (0 for
    a node without any).

    The MLP is ``Linear -> GELU -> Linear``; computed as PyG message passing with the same
    result but less work per edge: the first layer's sender part ``W_h h_j`` is computed once per
    node (the online sampler caches it), and the second, linear layer is applied after the mean.
    """

    def __init__(self, hidden_channels: int, state_dim: int) -> None:
        super().__init__(aggr="mean")
        self.net = mlp(hidden_channels + state_dim, hidden_channels, hidden_channels)

    def forward(self, h: Tensor, rel: Tensor, edge_index: Tensor) -> Tensor:
        """``rel`` is ``(E, d)``: the scaled relative position of each edge's sender."""
        first, second = self.net[0], self.net[2]
        H = h.shape[-1]
        sender = F.linear(h, first.weight[:, :H])                                   # (N, H) per node
        edge = F.linear(rel, first.weight[:, H:], first.bias)                       # (E, H)
        mean = self.propagate(edge_index, sender=sender, edge=edge, size=(h.shape[0], h.shape[0]))
        has_edges = torch.zeros(h.shape[0], 1, dtype=h.dtype).index_fill_(0, edge_index[1], 1.0)
        return second(mean) * has_edges

    def message(self, sender_j: Tensor, edge: Tensor) -> Tensor:
        return F.gelu(sender_j + edge)


class CausalTreeTrunk(nn.Module):
    """The causal tree GNN's trunk: buffers, input MLP, ``num_layers`` residual layers of parent
    and causal k-NN messages (``h <- LayerNorm(h + MLP([h, parent message, k-NN message]))``).

    A model sets ``state_dim``, ``hidden_channels`` and ``num_layers`` and calls
    :meth:`build_trunk`; its ``embed`` computes the input rows and runs :meth:`layers`.
    """

    state_dim: int
    hidden_channels: int
    num_layers: int

    def build_trunk(self, input_channels: int, *, state_center: Sequence[float] | None,
                    state_scale: Sequence[float] | None, feature_scale: Sequence[float] | None,
                    step_scale: Sequence[float] | None, periodic: Sequence[int],
                    extra_buffers: Mapping[str, Tensor] | None = None) -> None:
        """Register the trunk's buffers (``extra_buffers`` after ``step_scale``, before
        ``periodic``) and build its layers for ``input_channels`` inputs per node."""
        d, H = self.state_dim, self.hidden_channels
        self.register_buffer("state_center", fixed_vector(state_center, 0.0, d))
        self.register_buffer("state_scale", fixed_vector(state_scale, 1.0, d))
        self.register_buffer("feature_scale", fixed_vector(feature_scale, 1.0, 2 * d + 1))
        self.register_buffer("step_scale", fixed_vector(step_scale, 1.0, d))
        for name, value in (extra_buffers or {}).items():
            self.register_buffer(name, value)
        mask = torch.zeros(d, dtype=torch.bool)
        mask[list(periodic)] = True
        self.register_buffer("periodic", mask)
        self.input = mlp(input_channels, H, H)
        self.parent_convs = nn.ModuleList(RelativeConv(H, d) for _ in range(self.num_layers))
        self.knn_convs = nn.ModuleList(RelativeConv(H, d) for _ in range(self.num_layers))
        self.updates = nn.ModuleList(mlp(3 * H, H, H) for _ in range(self.num_layers))
        self.norms = nn.ModuleList(nn.LayerNorm(H) for _ in range(self.num_layers))

    def relative(self, sender: Tensor, receiver: Tensor) -> Tensor:
        return wrap_periodic(sender - receiver, self.periodic) / self.step_scale

    def edges(self, parent: Tensor, knn: Tensor) -> tuple[Tensor, Tensor]:
        """Edge indices ``(2, E)`` (sender, receiver) of the parent and the causal k-NN edges."""
        child = torch.nonzero(parent >= 0).flatten()
        parent_edges = torch.stack([parent[child], child])
        rows, cols = torch.nonzero(knn >= 0, as_tuple=True)
        knn_edges = torch.stack([knn[rows, cols], rows])
        return parent_edges, knn_edges

    def layers(self, h: Tensor, nodes: Tensor, parent: Tensor, knn: Tensor, use_parent: bool = True,
               use_knn: bool = True) -> Tensor:
        """The message-passing layers over input rows ``h`` ``(N, H)`` (indices global to ``nodes``);
        ``use_parent`` / ``use_knn`` False: that message is zero (an ablation)."""
        parent_edges, knn_edges = self.edges(parent, knn)
        rel_p = self.relative(nodes[parent_edges[0]], nodes[parent_edges[1]])
        rel_k = self.relative(nodes[knn_edges[0]], nodes[knn_edges[1]])
        zero = torch.zeros_like(h)
        for layer in range(self.num_layers):
            mp = self.parent_convs[layer](h, rel_p, parent_edges) if use_parent else zero
            mk = self.knn_convs[layer](h, rel_k, knn_edges) if use_knn else zero
            h = self.norms[layer](h + self.updates[layer](torch.cat([h, mp, mk], -1)))
        return h


__all__ = ["CausalTreeTrunk", "RelativeConv", "causal_knn", "fixed_vector", "mlp", "wrap_periodic"]
