"""The tree encoder shared by every learned model: padded observation -> node and graph embeddings.

:class:`TreeEncoder` reads the observation through :func:`agents.graph.to_pyg` (so any
leading batch shape works), runs ``num_layers`` message-passing layers of a PyG convolution
chosen by name over the tree edges (and optionally k-nearest-neighbour edges between
states), and pools the node embeddings (mean and max) together with an embedding of
``start``, ``goal`` and ``active_tree`` into one graph embedding per observation.

:class:`EncoderModule` is the same encoder as a TensorDict module (observation keys in,
``"embed"`` out): the first stage of every learned sampler, TorchRL actor and value head;
``agents.sb3.TreeFeaturesExtractor`` wraps it for Stable-Baselines3.

    encoder = TreeEncoder.from_space(env.observation_space, hidden_channels=64, num_layers=3)
    nodes, graph, batch = encoder(obs_tensors)     # (sum n_b, 64), (*batch_shape, 128), (sum n_b,)
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torch_geometric.nn import GATv2Conv, GCNConv, GraphConv, SAGEConv, global_max_pool, global_mean_pool

from agents.graph import knn_edge_index, to_pyg
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS

#: Convolution name -> factory(in_channels, out_channels, heads) (``conv=`` of TreeEncoder).
CONVS: dict[str, Callable[[int, int, int], nn.Module]] = {
    "graph": lambda i, o, heads: GraphConv(i, o, aggr="mean"),
    "sage": lambda i, o, heads: SAGEConv(i, o),
    "gcn": lambda i, o, heads: GCNConv(i, o),
    "gatv2": lambda i, o, heads: GATv2Conv(i, o, heads=heads, concat=False),
}
ACTIVATIONS: dict[str, Callable[[], nn.Module]] = {"relu": nn.ReLU, "elu": nn.ELU, "tanh": nn.Tanh,
                                                   "silu": nn.SiLU}


class TreeEncoder(nn.Module):
    """Padded tree observation -> ``(node_embeddings, graph_embedding, batch)``.

    Args:
        in_channels: node feature width (``2d + 1`` for ``node_features``).
        hidden_channels: width ``H`` of the node embeddings.
        num_layers: message-passing layers (each residual: ``h = h + act(conv(h))``).
        out_channels: width ``E`` of the graph embedding.
        state_dim: ``d`` (default ``(in_channels - 1) // 2``).
        conv: a key of :data:`CONVS` (``"graph"``, ``"sage"``, ``"gcn"``, ``"gatv2"``).
        knn: if > 0, a second convolution per layer over each node's ``knn`` nearest
            neighbours (Euclidean, on states scaled by the bounds) next to the tree edges.
        heads: attention heads of ``"gatv2"`` (averaged).
        act: a key of :data:`ACTIVATIONS`.
        feature_scale: per-channel divisor of the node features ``(in_channels,)``.
        state_low / state_high: state bounds ``(d,)``; start, goal and the k-NN positions
            are mapped to ``[-1, 1]`` with them.
        features: the observation key holding the node features.

    ``forward(obs)`` takes a Mapping of tensors (dict, ``TensorDict``; numpy arrays work
    too) with any leading batch shape ``S`` and returns node embeddings
    ``(num_nodes_total, H)``, graph embeddings ``(*S, E)`` and the node -> graph index
    ``(num_nodes_total,)`` (graphs numbered row-major over ``S``).
    """

    def __init__(self, in_channels: int, hidden_channels: int = 64, num_layers: int = 3,
                 out_channels: int = 128, *, state_dim: int | None = None, conv: str = "sage",
                 knn: int = 0, heads: int = 4, act: str = "relu",
                 feature_scale: torch.Tensor | np.ndarray | None = None,
                 state_low: torch.Tensor | np.ndarray | None = None,
                 state_high: torch.Tensor | np.ndarray | None = None,
                 features: str = "node_features") -> None:
        super().__init__()
        if conv not in CONVS:
            raise ValueError(f"unknown conv {conv!r}; known: {', '.join(sorted(CONVS))}")
        if act not in ACTIVATIONS:
            raise ValueError(f"unknown act {act!r}; known: {', '.join(sorted(ACTIVATIONS))}")
        if num_layers < 0 or knn < 0:
            raise ValueError("num_layers and knn must be >= 0")
        state_dim = (in_channels - 1) // 2 if state_dim is None else int(state_dim)
        self.in_channels, self.hidden_channels = int(in_channels), int(hidden_channels)
        self.num_layers, self.out_channels = int(num_layers), int(out_channels)
        self.state_dim, self.conv, self.knn, self.features = state_dim, conv, int(knn), features

        def vec(value, default: float, n: int) -> torch.Tensor:
            t = torch.full((n,), default) if value is None else torch.as_tensor(np.asarray(value, np.float32))
            if t.shape != (n,):
                raise ValueError(f"expected shape ({n},), got {tuple(t.shape)}")
            return t.float()

        scale = vec(feature_scale, 1.0, in_channels)
        low, high = vec(state_low, -1.0, state_dim), vec(state_high, 1.0, state_dim)
        if not torch.all(scale > 0) or not torch.all(high > low):
            raise ValueError("feature_scale must be positive and state_high > state_low")
        self.register_buffer("feature_scale", scale)
        self.register_buffer("state_center", (high + low) / 2)
        self.register_buffer("state_half_span", (high - low) / 2)

        self.act = ACTIVATIONS[act]()
        self.input = nn.Linear(in_channels, hidden_channels)
        self.tree_convs = nn.ModuleList(CONVS[conv](hidden_channels, hidden_channels, heads)
                                        for _ in range(num_layers))
        self.knn_convs = nn.ModuleList(CONVS[conv](hidden_channels, hidden_channels, heads)
                                       for _ in range(num_layers if knn else 0))
        self.context = nn.Sequential(nn.Linear(2 * state_dim + 1, hidden_channels), ACTIVATIONS[act]())
        self.readout = nn.Sequential(nn.Linear(3 * hidden_channels, hidden_channels), ACTIVATIONS[act](),
                                     nn.Linear(hidden_channels, out_channels))

    @classmethod
    def from_space(cls, observation_space: spaces.Dict, **kwargs) -> "TreeEncoder":
        """An encoder sized and scaled for an env's observation space (any state dim)."""
        feats = observation_space[kwargs.get("features", "node_features")]
        start = observation_space["start"]
        bound = np.maximum(np.abs(feats.low), np.abs(feats.high)).reshape(-1, feats.shape[-1]).max(0)
        kwargs.setdefault("state_dim", int(start.shape[-1]))
        kwargs.setdefault("feature_scale", np.where(bound > 0, bound, 1.0))
        kwargs.setdefault("state_low", start.low)
        kwargs.setdefault("state_high", start.high)
        return cls(int(feats.shape[-1]), **kwargs)

    def extra_repr(self) -> str:
        return f"conv={self.conv!r}, knn={self.knn}"

    def forward(self, obs: Mapping) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        graph = to_pyg(obs, self.features)
        batch_shape = torch.Size(obs[self.features].shape[:-2])
        B = int(np.prod(batch_shape)) if len(batch_shape) else 1
        if len(batch_shape):
            batch = graph.batch
        else:
            batch = torch.zeros(graph.x.shape[0], dtype=torch.long, device=graph.x.device)
        h = self.act(self.input(graph.x / self.feature_scale))
        edges = graph.edge_index
        if self.knn:
            near = knn_edge_index((graph.pos - self.state_center) / self.state_half_span, batch, self.knn)
        for i, conv in enumerate(self.tree_convs):
            msg = conv(h, edges)
            if self.knn:
                msg = msg + self.knn_convs[i](h, near)
            h = h + self.act(msg)
        start = (graph.start - self.state_center) / self.state_half_span
        goal = (graph.goal - self.state_center) / self.state_half_span
        ctx = self.context(torch.cat([start, goal, graph.active_tree.to(h.dtype).reshape(-1, 1)], -1))
        pooled = torch.cat([global_mean_pool(h, batch, size=B), global_max_pool(h, batch, size=B), ctx], -1)
        embed = self.readout(pooled).reshape(*batch_shape, self.out_channels)
        return h, embed, batch


class TreeGNNEncoder(nn.Module):
    """The supervised GNN sampler's backbone (:class:`agents.models.tree_samplers.TreeGNN`) with
    the encoder interface: padded observation -> ``(node_embeddings, graph_embedding, batch)``.

    The graph embedding is the GNN's tree context ``q`` (start, goal, active tree, each tree's
    mean embedding and size), width ``hidden_channels``. RL policies built on it share one
    backbone with the GNN sampler, so they can start from its trained weights
    (``gnn-mp train rl --encoder tree-gnn --init-from agents/checkpoints/tree_gnn_maze2d.pt``;
    ``backbone="tree-gnn"`` in the SB3 extractor's and the TorchRL modules' keyword arguments).
    Constructor arguments are :class:`TreeGNN`'s.
    """

    def __init__(self, **gnn_kwargs) -> None:
        super().__init__()
        from agents.models.tree_samplers import TreeGNN
        self.gnn_kwargs = dict(gnn_kwargs)
        self.gnn = TreeGNN(**gnn_kwargs)
        self.out_channels = self.gnn.hidden_channels

    @classmethod
    def from_space(cls, observation_space: spaces.Dict, **kwargs) -> "TreeGNNEncoder":
        """Scaled for an env's observation space; ``step_scale`` (a number or per dimension),
        ``periodic`` and ``num_trees`` are the task's (see ``train.tree_samplers.models.TASKS``)."""
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
        from agents.models.tree_samplers import causal_knn
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


#: Backbone name -> encoder class (``backbone=`` of the SB3 extractor, the TorchRL modules and RL policies).
ENCODERS: dict[str, type[nn.Module]] = {"tree": TreeEncoder, "tree-gnn": TreeGNNEncoder}


def encoder_from_space(observation_space: spaces.Dict, backbone: str = "tree", **kwargs) -> nn.Module:
    """The encoder ``backbone`` (a key of :data:`ENCODERS`) sized for an observation space."""
    if backbone not in ENCODERS:
        raise ValueError(f"unknown backbone {backbone!r}; known: {', '.join(ENCODERS)}")
    return ENCODERS[backbone].from_space(observation_space, **kwargs)


class EncoderModule(TensorDictModuleBase):
    """A :class:`TreeEncoder` as a TensorDict module: observation keys in, ``"embed"`` out.

    ``EncoderModule.from_space(observation_space, **encoder_kwargs)`` builds the encoder
    (``backbone="tree-gnn"``: the GNN sampler's backbone instead); ``module.encoder`` is it,
    ``module.out_channels`` its embedding width. Node embeddings are not written (their
    number varies per observation).
    """

    def __init__(self, encoder: nn.Module, out_key: str = "embed") -> None:
        super().__init__()
        self.encoder = encoder
        self.in_keys = list(OBSERVATION_KEYS)
        self.out_keys = [out_key]

    @classmethod
    def from_space(cls, observation_space: spaces.Dict, out_key: str = "embed", **kwargs) -> "EncoderModule":
        return cls(encoder_from_space(observation_space, **kwargs), out_key=out_key)

    @property
    def out_channels(self) -> int:
        return self.encoder.out_channels

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        _, embed, _ = self.encoder(tensordict)
        tensordict.set(self.out_keys[0], embed)
        return tensordict
