"""Learned samplers over the growing tree (the paper's Algorithm 1): GNN, CVAE and GNN-CVAE.

**GNN** (:class:`TreeGNN`). A *causal* graph network over the planner's tree: node ``n``
receives messages only from its parent and from its ``knn`` nearest *earlier* nodes of the
same tree (PyG :class:`~agents.nn.causal.RelativeConv` layers, messages built from the sender's embedding and
the relative position ``(x_j - x_n) / step_scale``). A node's embedding is therefore fixed the
moment it is inserted: training scores every snapshot of a run with one forward pass over
its final tree, and online inference embeds each new node once and caches it
(:class:`agents.tree.samplers.TreeGNNSampler`). The sampling distribution at a snapshot is a
mixture over the tree's nodes::

    q          = MLP(start, goal, one_hot(active_tree), mean embedding of each tree, log sizes)
    weight_m   = softmax_m(key(h_m) . q / sqrt(H) / temperature)
    component  = N(x_m + offset_a(h_m) + shift_a(q), diag(exp(log_sigma_a(h_m)))^2)

with separate offset / scale heads per active tree ``a`` (BiRRT grows two). The loss is the
mixture's negative log-likelihood of the label: the next solution-path node the active tree
does not hold yet. Node inputs are the environment's features plus the node's state (the
paper's ``[x_init - x_n, x_goal - x_n]``, its text allows the own position too).

**CVAE** (:class:`TreeCVAE`, Ichter et al. 2018): fully connected, conditioned on start,
goal and the problem's obstacle rows; it learns the distribution of solution-path states and
ignores the tree. **GNN-CVAE** (:class:`TreeGNNCVAE`): the same latent-variable model whose
condition is the causal GNN's tree context ``q`` (graph encoder) and whose decoder also
reads it: a CVAE over the next sample given the tree.

Every model is registered as a checkpoint kind (``tree/gnn``, ``tree/cvae``, ``tree/gnn-cvae``).
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from agents.checkpoints import register_model_kind
from agents.nn.causal import CausalTreeTrunk, mlp, wrap_periodic

#: Clamp of the mixture components' log standard deviations.
LOG_SIGMA_RANGE = (-4.0, 1.0)
#: Clamp of the CVAEs' latent log standard deviations (as PyG's VGAE).
MAX_LOGSTD = 10.0


class TreeGNN(CausalTreeTrunk):
    """The causal tree GNN (:class:`~agents.nn.causal.CausalTreeTrunk`) and its node-mixture head
    (see the module docstring).

    Args:
        state_dim: ``d``.
        hidden_channels / num_layers: node embedding width ``H`` and message-passing layers.
        knn: causal nearest neighbours per node (0: tree edges only).
        state_center / state_scale: ``(d,)``; node states enter as ``(x - center) / scale``.
        feature_scale: ``(2d + 1,)`` divisor of the environment's node features.
        step_scale: ``(d,)`` unit of relative positions and of the offset heads (~ one extension).
        periodic: indices of angle coordinates (wrapped to ``[-pi, pi)``).
        num_trees: 1 for RRT, 2 for BiRRT (offset heads per active tree).
        use_parent / use_knn / use_context: ablations (message sources, global tree context).
        relative_inputs: read no absolute position: a node's inputs are the environment's features
            (its offsets to start and goal) only, the context's start and goal their difference. The
            model is then unchanged by moving a whole problem (features that generalise).
    """

    def __init__(self, state_dim: int, hidden_channels: int = 64, num_layers: int = 2, knn: int = 6, *,
                 state_center: Sequence[float] | None = None, state_scale: Sequence[float] | None = None,
                 feature_scale: Sequence[float] | None = None, step_scale: Sequence[float] | None = None,
                 periodic: Sequence[int] = (), num_trees: int = 2, use_parent: bool = True,
                 use_knn: bool = True, use_context: bool = True, relative_inputs: bool = False) -> None:
        super().__init__()
        d = int(state_dim)
        self.state_dim, self.hidden_channels, self.num_layers, self.knn = d, int(hidden_channels), int(num_layers), int(knn)
        self.num_trees, self.use_parent, self.use_knn, self.use_context = int(num_trees), use_parent, use_knn, use_context
        self.relative_inputs = bool(relative_inputs)

        self.build_trunk((2 if self.relative_inputs else 3) * d + 1, state_center=state_center,
                         state_scale=state_scale, feature_scale=feature_scale, step_scale=step_scale,
                         periodic=periodic)
        H = self.hidden_channels
        self.query = mlp((1 if self.relative_inputs else 2) * d + num_trees + num_trees * H + num_trees, H, H)
        self.key = nn.Linear(H, H)
        self.node_head = nn.Linear(H, num_trees * 2 * d)     # per active tree: offset (d) + log sigma (d)
        self.query_shift = nn.Linear(H, num_trees * d)       # per active tree: shift of every component

    # ------------------------------------------------------------------ embeddings
    def node_inputs(self, nodes: Tensor, features: Tensor) -> Tensor:
        if self.relative_inputs:
            return features / self.feature_scale
        return torch.cat([features / self.feature_scale, (nodes - self.state_center) / self.state_scale], -1)

    def embed(self, nodes: Tensor, features: Tensor, parent: Tensor, knn: Tensor) -> Tensor:
        """Node embeddings ``(N, H)`` of one or more trees (indices global to ``nodes``)."""
        h = self.input(self.node_inputs(nodes, features))
        return self.layers(h, nodes, parent, knn, self.use_parent, self.use_knn)

    # ------------------------------------------------------------------ mixture
    def context(self, start: Tensor, goal: Tensor, active: Tensor, means: Tensor, counts: Tensor) -> Tensor:
        """Tree context ``q`` ``(T, H)`` from start/goal ``(T, d)``, active tree ``(T,)``, each
        tree's mean embedding ``(T, num_trees, H)`` and size ``(T, num_trees)``."""
        if not self.use_context:
            means = torch.zeros_like(means)
        scale = self.state_scale
        ends = ([wrap_periodic(goal - start, self.periodic) / scale] if self.relative_inputs
                else [(start - self.state_center) / scale, (goal - self.state_center) / scale])
        parts = [*ends, F.one_hot(active.long(), self.num_trees).to(means.dtype), means.flatten(1),
                 torch.log1p(counts) / 5]
        return self.query(torch.cat(parts, -1))

    def snapshot_context(self, h: Tensor, tree_id: Tensor, start: Tensor, goal: Tensor, sizes: Tensor,
                         active: Tensor) -> Tensor:
        """``q`` of every snapshot (the first ``sizes[t]`` nodes): running means and counts of
        each tree's embeddings, read off cumulative sums in insertion order."""
        onehot = F.one_hot(tree_id.long(), self.num_trees).float()                     # (N, trees)
        csum = torch.cat([h.new_zeros(1, self.num_trees, h.shape[1]),
                          torch.cumsum(onehot[:, :, None] * h[:, None, :], 0)])          # (N+1, trees, H)
        ccount = torch.cat([h.new_zeros(1, self.num_trees), torch.cumsum(onehot, 0)])  # (N+1, trees)
        counts = ccount[sizes]
        T = len(sizes)
        return self.context(start.expand(T, -1), goal.expand(T, -1), active,
                            csum[sizes] / counts.clamp(min=1)[..., None], counts)

    def node_heads(self, h: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Per node: key ``(N, H)``, offset and log sigma ``(N, num_trees, d)``."""
        d = self.state_dim
        o = self.node_head(h).view(*h.shape[:-1], self.num_trees, 2 * d)
        return self.key(h), o[..., :d] * self.step_scale, o[..., d:].clamp(*LOG_SIGMA_RANGE)

    def shift(self, q: Tensor, active: Tensor) -> Tensor:
        """Per-snapshot shift of every component ``(T, d)``."""
        s = self.query_shift(q).view(-1, self.num_trees, self.state_dim)
        return s[torch.arange(len(q)), active.long()] * self.step_scale

    def logits(self, q: Tensor, key: Tensor, temperature: float = 1.0) -> Tensor:
        return q @ key.T / math.sqrt(self.hidden_channels) / temperature

    # ------------------------------------------------------------------ training
    def run_nll(self, nodes: Tensor, features: Tensor, parent: Tensor, tree_id: Tensor, knn: Tensor,
                start: Tensor, goal: Tensor, sizes: Tensor, active: Tensor, labels: Tensor) -> Tensor:
        """Per-snapshot mixture NLL ``(T,)`` of one run: the snapshot ``t`` is the tree's first
        ``sizes[t]`` nodes (insertion order), its label the next sample ``labels[t]``."""
        h = self.embed(nodes, features, parent, knn)
        key, offset, log_sigma = self.node_heads(h)
        q = self.snapshot_context(h, tree_id, start, goal, sizes, active)
        logits = self.logits(q, key)
        valid = torch.arange(len(nodes))[None, :] < sizes[:, None]
        log_w = torch.log_softmax(logits.masked_fill(~valid, -1e9), -1)                 # (T, N)
        a = active.long()
        mu = nodes[None] + offset[:, :, :].permute(1, 0, 2)[a] + self.shift(q, active)[:, None]   # (T, N, d)
        ls = log_sigma.permute(1, 0, 2)[a]                                               # (T, N, d)
        z = wrap_periodic(labels[:, None] - mu, self.periodic) / ls.exp()
        log_n = (-0.5 * z * z - ls - 0.5 * math.log(2 * math.pi)).sum(-1)
        return -torch.logsumexp(log_w + log_n, -1)


class _Gaussian(nn.Module):
    """VGAE-style latent helpers shared by the two CVAEs."""

    latent_channels: int

    @staticmethod
    def reparametrize(mu: Tensor, logstd: Tensor, generator: torch.Generator | None = None) -> Tensor:
        eps = torch.randn(mu.shape, generator=generator)
        return mu + eps * logstd.clamp(max=MAX_LOGSTD).exp()

    @staticmethod
    def kl_loss(mu: Tensor, logstd: Tensor) -> Tensor:
        logstd = logstd.clamp(max=MAX_LOGSTD)
        return -0.5 * torch.mean(torch.sum(1 + 2 * logstd - mu ** 2 - logstd.exp() ** 2, dim=-1))

    def to_state(self, out: Tensor) -> Tensor:
        """The decoder's output in state units."""
        raise NotImplementedError

    def decode_for_one(self, z: Tensor, condition: Tensor) -> Tensor:
        """``decode(z, condition.expand(len(z), -1))`` for one condition ``(C,)`` (a problem, a tree
        context), its share of the decoder's first layer computed once instead of once per latent
        row: a sampler decodes hundreds of proposals per condition, and the CVAE's 516 condition
        columns were 99% of its first layer (equal to ``decode`` up to float32 rounding)."""
        layers = iter(self.decoder)              # its layers in turn (``decoder[1:]`` would build a new Sequential)
        first, L = next(layers), self.latent_channels
        h = F.linear(z, first.weight[:, :L]) + F.linear(condition, first.weight[:, L:], first.bias)
        for layer in layers:
            h = layer(h)
        return self.to_state(h)


class TreeCVAE(_Gaussian):
    """Ichter et al.'s CVAE: ``p(x | start, goal, obstacles)`` over solution-path states.

    ``condition`` is ``[start, goal, obstacle rows (flattened)]`` scaled like the states;
    encoder ``(x, c) -> (mu, logstd)``, decoder ``(z, c) -> x`` (a Gaussian with learned
    per-dimension scale). It does not read the tree.
    """

    def __init__(self, state_dim: int, condition_dim: int, hidden_channels: int = 128, latent_channels: int = 4,
                 *, state_center: Sequence[float] | None = None, state_scale: Sequence[float] | None = None,
                 periodic: Sequence[int] = ()) -> None:
        super().__init__()
        d = int(state_dim)
        self.state_dim, self.condition_dim, self.latent_channels = d, int(condition_dim), int(latent_channels)
        self.register_buffer("state_center", torch.zeros(d) if state_center is None else torch.tensor(state_center).float())
        self.register_buffer("state_scale", torch.ones(d) if state_scale is None else torch.tensor(state_scale).float())
        mask = torch.zeros(d, dtype=torch.bool)
        mask[list(periodic)] = True
        self.register_buffer("periodic", mask)
        self.encoder = mlp(d + condition_dim, hidden_channels, 2 * latent_channels, layers=3)
        self.decoder = mlp(latent_channels + condition_dim, hidden_channels, d, layers=3)
        self.log_scale = nn.Parameter(torch.full((d,), -2.0))

    def scaled(self, x: Tensor) -> Tensor:
        return (x - self.state_center) / self.state_scale

    def encode(self, x: Tensor, condition: Tensor) -> tuple[Tensor, Tensor]:
        out = self.encoder(torch.cat([self.scaled(x), condition], -1))
        return out[..., :self.latent_channels], out[..., self.latent_channels:]

    def to_state(self, out: Tensor) -> Tensor:
        return out * self.state_scale + self.state_center

    def decode(self, z: Tensor, condition: Tensor) -> Tensor:
        """The state (mean of the decoder's Gaussian)."""
        return self.to_state(self.decoder(torch.cat([z, condition], -1)))

    def loss(self, x: Tensor, condition: Tensor, kl_weight: float = 1.0,
             generator: torch.Generator | None = None) -> tuple[Tensor, dict[str, float]]:
        mu, logstd = self.encode(x, condition)
        z = self.reparametrize(mu, logstd, generator)
        err = wrap_periodic(x - self.decode(z, condition), self.periodic) / self.state_scale
        ls = self.log_scale.clamp(*LOG_SIGMA_RANGE)
        recon = (0.5 * (err / ls.exp()) ** 2 + ls).sum(-1).mean()
        kl = self.kl_loss(mu, logstd)
        return recon + kl_weight * kl, {"recon": float(recon.detach()), "kl": float(kl.detach())}

    def sample(self, condition: Tensor, num_samples: int, generator: torch.Generator | None = None) -> Tensor:
        """``(num_samples, d)`` states for one condition ``(C,)``."""
        z = torch.randn((num_samples, self.latent_channels), generator=generator)
        return self.decode_for_one(z, condition)


class TreeGNNCVAE(_Gaussian):
    """A CVAE over the next sample whose condition is the causal GNN's tree context.

    The graph encoder is a :class:`TreeGNN` (its ``context`` ``q`` summarises the tree, start,
    goal and active tree); ``encoder (x, q) -> (mu, logstd)``, ``decoder (z, q) -> x``.
    """

    def __init__(self, state_dim: int, hidden_channels: int = 64, num_layers: int = 2, knn: int = 6,
                 latent_channels: int = 4, **gnn_kwargs) -> None:
        super().__init__()
        self.gnn = TreeGNN(state_dim, hidden_channels, num_layers, knn, **gnn_kwargs)
        d, H = int(state_dim), int(hidden_channels)
        self.state_dim, self.latent_channels = d, int(latent_channels)
        self.encoder = mlp(d + H, H, 2 * latent_channels, layers=3)
        self.decoder = mlp(latent_channels + H, H, d, layers=3)
        self.log_scale = nn.Parameter(torch.full((d,), -2.0))

    def encode(self, x: Tensor, q: Tensor) -> tuple[Tensor, Tensor]:
        g = self.gnn
        out = self.encoder(torch.cat([(x - g.state_center) / g.state_scale, q], -1))
        return out[..., :self.latent_channels], out[..., self.latent_channels:]

    def to_state(self, out: Tensor) -> Tensor:
        return out * self.gnn.state_scale + self.gnn.state_center

    def decode(self, z: Tensor, q: Tensor) -> Tensor:
        return self.to_state(self.decoder(torch.cat([z, q], -1)))

    def run_loss(self, nodes: Tensor, features: Tensor, parent: Tensor, tree_id: Tensor, knn: Tensor,
                 start: Tensor, goal: Tensor, sizes: Tensor, active: Tensor, labels: Tensor,
                 kl_weight: float = 1.0, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor]:
        """(summed reconstruction + KL terms, number of snapshots) of one run."""
        g = self.gnn
        q = g.snapshot_context(g.embed(nodes, features, parent, knn), tree_id, start, goal, sizes, active)
        T = len(sizes)
        mu, logstd = self.encode(labels, q)
        z = self.reparametrize(mu, logstd, generator)
        err = wrap_periodic(labels - self.decode(z, q), g.periodic) / g.state_scale
        ls = self.log_scale.clamp(*LOG_SIGMA_RANGE)
        recon = (0.5 * (err / ls.exp()) ** 2 + ls).sum(-1)
        kl = -0.5 * torch.sum(1 + 2 * logstd.clamp(max=MAX_LOGSTD) - mu ** 2 - logstd.clamp(max=MAX_LOGSTD).exp() ** 2, -1)
        return (recon + kl_weight * kl).sum(), torch.tensor(float(T))


#: Checkpoint kinds of the tree samplers (sampler name -> model kind is ``"tree/" + name``).
KINDS = {"tree/gnn": TreeGNN, "tree/cvae": TreeCVAE, "tree/gnn-cvae": TreeGNNCVAE}
for _kind, _cls in KINDS.items():
    register_model_kind(_kind, _cls)
