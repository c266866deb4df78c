"""A PyG encoder of the tree observation: padded observation -> node and graph embeddings.

:class:`TreeEncoder` reads the observation through :func:`agents.nn.graph.tree_graph` (so any
leading batch shape works), runs ``num_layers`` message-passing layers of a PyG convolution
chosen by name over the tree edges (and optionally k-nearest-neighbour edges between
states), and pools the node embeddings (mean and max) together with an embedding of
``start``, ``goal`` and ``active_tree`` into one graph embedding per observation.

The RL policies build on it (:mod:`agents.rl.sb3`, :mod:`agents.rl.torchrl`), and so can a sampler
of your own. :data:`ENCODERS` is the registry of encoders by name (``backbone=`` of the RL
policies): ``"tree"``, this one; ``"tree-gnn"``, the GNN sampler's causal backbone
(:class:`agents.tree.backbone.TreeGNNEncoder`, named here and imported on first use);
:func:`register_encoder` adds one. :class:`CandidateEncoder` reads a picker's candidates.

    encoder = TreeEncoder.from_space(env.observation_space, hidden_channels=64, num_layers=3)
    nodes, graph, batch = encoder(obs_tensors)     # (sum n_b, 64), (*batch_shape, 128), (sum n_b,)
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np
import torch
from gymnasium import spaces
from torch import nn
from torch_geometric.nn import GATv2Conv, GCNConv, GraphConv, SAGEConv, global_max_pool, global_mean_pool

from agents.nn.graph import knn_edge_index, tree_graph
from gnn_mp_envs.utils.imports import resolved

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
        graph = tree_graph(obs, self.features)
        batch_shape = graph.batch_shape
        B = graph.counts.numel()
        batch = graph.batch
        h = self.act(self.input(graph.x / self.feature_scale))
        tree_edges = MeanEdges(graph.edge_index, h)
        if self.knn:
            near = MeanEdges(knn_edge_index((graph.pos - self.state_center) / self.state_half_span, batch, self.knn), h)
        for i, conv in enumerate(self.tree_convs):
            msg = tree_edges.conv(conv, h)
            if self.knn:
                msg = msg + near.conv(self.knn_convs[i], h)
            h = h + self.act(msg)
        start = (graph.start - self.state_center) / self.state_half_span
        goal = (graph.goal - self.state_center) / self.state_half_span
        ctx = self.context(torch.cat([start, goal, graph.active_tree.to(h.dtype).reshape(-1, 1)], -1))
        pooled = torch.cat([global_mean_pool(h, batch, size=B), global_max_pool(h, batch, size=B), ctx], -1)
        embed = self.readout(pooled).reshape(*batch_shape, self.out_channels)
        return h, embed, batch


class MeanEdges:
    """An edge set and what a PyG ``SAGEConv`` (mean aggregation) computes from it at every layer.

    ``SAGEConv(h, edge_index)`` is ``lin_l(mean_{j -> i} h_j) + lin_r(h_i)``; PyG evaluates the mean
    through its ``propagate`` machinery (argument inspection, hooks, the aggregation module), which
    costs several times the arithmetic on the small trees of an RL view. :meth:`conv` runs the same
    tensor operations in the same order (``index_select`` of the senders, ``scatter_add_`` into the
    receivers, division by the clamped in-degree computed once per edge set), so its output equals
    the layer's bit for bit (``tests/test_policy_interface.py``); other convolutions, or a SAGEConv
    configured otherwise, are called as they are.
    """

    def __init__(self, edge_index: torch.Tensor, like: torch.Tensor) -> None:
        self.edge_index = edge_index
        self.src, self.dst = edge_index[0], edge_index[1]
        n = like.shape[0]
        count = like.new_zeros(n).scatter_add_(0, self.dst, like.new_ones(self.dst.numel()))
        self.count = count.clamp(min=1).view(-1, 1)
        self._scatter_index: torch.Tensor | None = None

    def conv(self, conv: nn.Module, h: torch.Tensor) -> torch.Tensor:
        if not plain_mean_sage(conv):
            return conv(h, self.edge_index)
        x_j = h.index_select(0, self.src)
        if self._scatter_index is None or self._scatter_index.shape != x_j.shape:
            self._scatter_index = self.dst.view(-1, 1).expand_as(x_j)
        mean = h.new_zeros(h.shape).scatter_add_(0, self._scatter_index, x_j) / self.count.expand(h.shape)
        return conv.lin_l(mean) + conv.lin_r(h)


def plain_mean_sage(conv: nn.Module) -> bool:
    """A ``SAGEConv`` as :data:`CONVS` builds it: mean aggregation, no projection, no
    normalisation, root weight on."""
    return (type(conv) is SAGEConv and isinstance(conv.aggr, str) and conv.aggr == "mean" and not conv.project
            and not conv.normalize and conv.root_weight and not conv._forward_hooks and not conv._forward_pre_hooks)


#: The checkpoint kind of a :class:`CandidateEncoder`'s prior model (the supervised GNN sample scorer).
PRIOR_KIND = "tree/gnn-scorer"


class CandidateEncoder(nn.Module):
    """Candidate-selection observation -> per-candidate embeddings and a summary.

    Reads ``candidate_features`` ``(*S, K, F)`` (the features of
    :class:`gnn_mp_envs.envs.candidates.CandidateSet`, each relative to the tree) through one
    MLP shared by the candidates (``F -> hidden -> embed``); with ``tree`` (the keyword
    arguments of a :class:`TreeEncoder`), the tree view's graph embedding is appended to every
    candidate's input. ``forward(obs)`` returns ``(per_candidate (*S, K, embed), summary (*S,
    2 * embed))``: the mean and max over the candidates. :meth:`flat` is what a library head
    reads: ``[per_candidate.flatten(), summary]``, :attr:`out_channels` wide.

    With ``prior`` (``{"scorer": TreeGNNScorer constructor arguments, "temperature": T}``) the
    features' last column is a candidate prior's logit (the supervised GNN sample scorer over the
    whole tree, a :data:`PRIOR_KIND` model, computed incrementally by the env and the sampler: its
    candidate prior, :func:`agents.nn.priors.candidate_prior`), and
    :meth:`flat` ends with those ``K`` logits as they are, so that a linear head can start as
    exactly the prior (:func:`prior_head_init`) and training learns what to add. The scorer's
    weights are a frozen submodule (:attr:`prior_model`): they travel with the policy's, and the
    sampler rebuilds the same prior from them.
    """

    def __init__(self, feature_dim: int, count: int, hidden: int = 64, embed: int = 32, act: str = "tanh",
                 tree: Mapping | None = None, prior: Mapping | None = None) -> None:
        super().__init__()
        if act not in ACTIVATIONS:
            raise ValueError(f"unknown act {act!r}; known: {', '.join(sorted(ACTIVATIONS))}")
        self.feature_dim, self.count, self.hidden, self.embed, self.act_name = (int(feature_dim), int(count),
                                                                                 int(hidden), int(embed), act)
        self.tree_config = None if tree is None else dict(tree)
        self.tree = None if tree is None else TreeEncoder(**self.tree_config)
        self.prior_config = None if prior is None else {"scorer": dict(prior["scorer"]),
                                                        "temperature": float(prior.get("temperature", 1.0))}
        #: The candidate prior's model (frozen; None without a prior).
        self.prior_model = None
        self.prior_source: str | None = None
        if self.prior_config is not None:
            from agents.nn.priors import prior_model
            self.prior_model = prior_model(PRIOR_KIND, self.prior_config["scorer"]).eval().requires_grad_(False)
        extra = 0 if self.tree is None else self.tree.out_channels
        self.net = nn.Sequential(nn.Linear(self.feature_dim + extra, self.hidden), ACTIVATIONS[act](),
                                 nn.Linear(self.hidden, self.embed), ACTIVATIONS[act]())
        self.out_channels = self.count * self.embed + 2 * self.embed + (self.count if self.prior_model is not None
                                                                        else 0)

    @classmethod
    def from_space(cls, observation_space: spaces.Dict, tree_context: bool = False,
                   prior_checkpoint: str | None = None, prior_temperature: float = 1.0,
                   **kwargs) -> "CandidateEncoder":
        """Sized for a candidate env's observation space; ``tree_context=True`` adds a
        :class:`TreeEncoder` (``tree_kwargs``: its keyword arguments) over the tree view;
        ``prior_checkpoint``: the ``tree/gnn-scorer`` checkpoint whose logits (over
        ``prior_temperature``) the env appends as the features' last column."""
        feats = observation_space["candidate_features"]
        if prior_checkpoint is not None:
            from agents.checkpoints import read_checkpoint
            record = read_checkpoint(prior_checkpoint)
            kwargs["prior"] = {"scorer": record["ctor_args"], "temperature": float(prior_temperature)}
        tree_kwargs = dict(kwargs.pop("tree_kwargs", None) or {})
        if tree_context:
            enc = TreeEncoder.from_space(observation_space, **tree_kwargs)
            kwargs["tree"] = {"in_channels": enc.in_channels, "hidden_channels": enc.hidden_channels,
                              "num_layers": enc.num_layers, "out_channels": enc.out_channels,
                              "state_dim": enc.state_dim, "conv": enc.conv, "knn": enc.knn,
                              "feature_scale": enc.feature_scale.tolist(),
                              "state_low": (enc.state_center - enc.state_half_span).tolist(),
                              "state_high": (enc.state_center + enc.state_half_span).tolist()}
        encoder = cls(int(feats.shape[-1]), int(feats.shape[-2]), **kwargs)
        if prior_checkpoint is not None:
            encoder.load_prior(prior_checkpoint)
        return encoder

    def load_prior(self, path: str) -> None:
        """The prior's weights from its ``tree/gnn-scorer`` checkpoint (again after a library re-initialised
        every linear layer under its features extractor: SB3's orthogonal init does)."""
        from agents.checkpoints import load_checkpoint
        scorer, _ = load_checkpoint(path, expected_kind="tree/gnn-scorer")
        self.prior_model.load_state_dict(scorer.state_dict())
        #: Where the prior's weights came from (None: from a policy's own state dict).
        self.prior_source = str(path)

    def config(self) -> dict:
        """Constructor arguments that rebuild this encoder (plain values)."""
        return {"feature_dim": self.feature_dim, "count": self.count, "hidden": self.hidden, "embed": self.embed,
                "act": self.act_name, "tree": self.tree_config, "prior": self.prior_config}

    def forward(self, obs: Mapping) -> tuple[torch.Tensor, torch.Tensor]:
        x = obs["candidate_features"]
        x = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
        x = x.float()
        if self.tree is not None:
            ctx = self.tree(obs)[1]
            x = torch.cat([x, ctx.unsqueeze(-2).expand(*x.shape[:-1], ctx.shape[-1])], -1)
        per = self.net(x)
        return per, torch.cat([per.mean(-2), per.amax(-2)], -1)

    def flat(self, obs: Mapping) -> torch.Tensor:
        """``[per_candidate.flatten(-2), mean, max]`` ``(*S, out_channels)`` (with a prior: then its ``K`` logits)."""
        per, summary = self(obs)
        parts = [per.flatten(-2), summary]
        if self.prior_model is not None:
            x = obs["candidate_features"]
            parts.append((x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))).float()[..., -1])
        return torch.cat(parts, -1)


def prior_head_init(linear: nn.Linear, count: int) -> None:
    """Make a linear head over :meth:`CandidateEncoder.flat` (with a prior) start as the prior: the
    weights of the last ``count`` inputs (the prior's logits) the identity, the rest as initialised
    (SB3's orthogonal init of gain 0.01 gives a policy within a few hundredths of the prior), bias zero."""
    with torch.no_grad():
        linear.weight[:, -count:] = torch.eye(count, dtype=linear.weight.dtype)
        linear.bias.zero_()


#: Backbone name -> encoder class (``backbone=`` of the SB3 extractor, the TorchRL modules and RL
#: policies; ``"class"`` of a stored encoder configuration), or ``"module:attribute"`` of one that a
#: method provides, imported when first asked for (the floor names it, never imports it).
ENCODERS: dict[str, type[nn.Module] | str] = {"tree": TreeEncoder, "tree-gnn": "agents.tree.backbone:TreeGNNEncoder"}


def register_encoder(name: str, encoder: type[nn.Module] | str) -> None:
    """Add an encoder (a class with ``from_space``, or its ``"module:attribute"``) under a new name."""
    if name in ENCODERS:
        raise ValueError(f"encoder {name!r} is already registered")
    ENCODERS[name] = encoder


def encoder_class(name: str) -> type[nn.Module]:
    """The encoder class registered as ``name`` (ValueError: an unknown name)."""
    if name not in ENCODERS:
        raise ValueError(f"unknown backbone {name!r}; known: {', '.join(ENCODERS)}")
    return resolved(ENCODERS, name)


def encoder_from_space(observation_space: spaces.Dict, backbone: str = "tree", **kwargs) -> nn.Module:
    """The encoder ``backbone`` (a key of :data:`ENCODERS`) sized for an observation space."""
    return encoder_class(backbone).from_space(observation_space, **kwargs)


__all__ = ["ACTIVATIONS", "CONVS", "ENCODERS", "PRIOR_KIND", "CandidateEncoder", "TreeEncoder", "encoder_class",
           "encoder_from_space", "plain_mean_sage", "prior_head_init", "register_encoder"]
