"""Critical-sample models: GNN (TAGConv), GAT (GATv2Conv), GNN-CVAE, and CNN / CVAE baselines.

All share PyG's constructor habit ``(in_channels, hidden_channels, num_layers, out_channels)``.
Graph models read node features ``x`` (N, 5) = ``[x_init - x_n, x_goal - x_n, obstacle]``
(paper eq. featurestate), optionally with the node position ``x_n`` appended (N, 7; the
paper's text allows "its own xy position"), and stack graph filters. Two readouts:

* ``readout="max"`` (the paper's): global max pool over the graph -> FC head;
* ``readout="attention"``: a per-node score -> softmax over the graph's nodes -> the
  prediction is the softmax-weighted mean of the node positions ``pos`` plus a small FC
  offset from the attention-pooled embedding (zero at initialisation).

Node-level outputs are permutation equivariant and the pooled prediction invariant
(paper Theorem 1) for both readouts; tests check it.

The CVAEs follow PyG's ``VGAE`` layout: ``encode`` -> ``(mu, logstd)``, ``reparametrize``,
``decode``, ``recon_loss`` and ``kl_loss``; ``sample`` draws critical states from N(0, I).

The generic pieces (:class:`GraphPoolRegressor`, :class:`CNNTrunk`, the Gaussian latent)
know nothing of the 2-D unit square: the state dimension is ``out_channels`` (for the
attention readout, the width of ``pos``) and the offset added to the max-readout head is the
constructor argument ``centre`` (a number or one value per state dimension, e.g. the middle
of the joint limits). :data:`STATE_DIM` and :data:`CENTRE` are only the defaults of the
critical-sample task, so its checkpoints load unchanged.

Each model is registered with :mod:`agents.checkpoints` as kind ``critical/<name>``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn
from torch_geometric.nn import GATv2Conv, TAGConv, global_max_pool
from torch_geometric.nn.conv.gcn_conv import gcn_norm
from torch_geometric.utils import scatter, softmax, to_torch_csr_tensor

from agents.checkpoints import register_model_kind

#: Node feature width of eq. featurestate in 2-D: two relative vectors and an indicator.
NODE_FEATURES = 5
#: Node feature width with the node's own position ``x_n`` appended.
NODE_FEATURES_WITH_POSITION = 7
#: Graph readouts: the paper's global max pool + FC, or attention over node positions.
READOUTS = ("max", "attention")
#: Which edges the graph filters run on: the problem's collision-free edges only, or every
#: edge of the fixed r-disc graph (then the obstacle indicator reaches free nodes). The
#: models only record the choice; :mod:`agents.critical.data` builds the edges.
EDGE_MODES = ("valid", "all")
#: Attention readout: what each node's score sees besides its own embedding: nothing, or the
#: graph's max-pooled embedding (global context, like the paper's max-pool head).
CONTEXTS = ("none", "max")
#: Default predicted state dimension: (x, y) of the critical-sample task.
STATE_DIM = 2
#: Occupancy, start and goal channels of the CNN baselines.
IMAGE_CHANNELS = 3
#: VGAE's clamp on log standard deviations, for numerical safety.
MAX_LOGSTD = 10.0
#: Default output offset: the centre of the unit square, so a zero-initialised head is
#: sensible. A constructor argument (``centre``) of every model.
CENTRE = 0.5
#: Prefix of the checkpoint kinds of these models: ``critical/gnn``, ``critical/gat``, ...
KIND_PREFIX = "critical/"

Centre = float | Sequence[float]


def _centre_buffer(module: nn.Module, centre: Centre) -> None:
    """Keep ``centre`` as a non-persistent buffer: it follows ``.to(device)`` but is not in
    the state dict (it is a constructor argument, stored with the checkpoint's ctor_args)."""
    module.centre = centre if isinstance(centre, (int, float)) else tuple(float(c) for c in centre)
    module.register_buffer("_centre", torch.as_tensor(module.centre, dtype=torch.float32), persistent=False)


def _mlp(in_channels: int, hidden_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(in_channels, hidden_channels), nn.ReLU(),
                         nn.Linear(hidden_channels, out_channels))


class GraphPoolRegressor(nn.Module):
    """``num_layers`` graph convolutions -> readout (global max pool + FC, or attention).

    Any state dimension: ``out_channels`` is the predicted state's width (the attention
    readout predicts a mean of node positions, so there it must equal ``pos``'s width), and
    the max readout's head output is offset by ``centre``. Subclasses choose the convolution
    in :meth:`init_conv` and may pre-process the edges once per forward pass in
    :meth:`propagation`.
    """

    def __init__(self, in_channels: int, hidden_channels: int, num_layers: int,
                 out_channels: int, head_in_extra: int = 0, readout: str = "max",
                 edges: str = "valid", centre: Centre = CENTRE, context: str = "none") -> None:
        super().__init__()
        if edges not in EDGE_MODES:
            raise ValueError(f"edges must be one of {EDGE_MODES}, got {edges!r}")
        if context not in CONTEXTS:
            raise ValueError(f"context must be one of {CONTEXTS}, got {context!r}")
        self.edges, self.context = edges, context
        if readout not in READOUTS:
            raise ValueError(f"readout must be one of {READOUTS}, got {readout!r}")
        self.in_channels, self.hidden_channels = in_channels, hidden_channels
        self.num_layers, self.out_channels, self.readout = num_layers, out_channels, readout
        _centre_buffer(self, centre)
        self.convs = nn.ModuleList(
            self.init_conv(in_channels if i == 0 else hidden_channels, hidden_channels)
            for i in range(num_layers))
        self.head = _mlp(hidden_channels + head_in_extra, hidden_channels, out_channels)
        if readout == "attention":
            ctx = hidden_channels if context == "max" else 0
            self.score = _mlp(hidden_channels + head_in_extra + ctx, hidden_channels, 1)
            nn.init.zeros_(self.head[-1].weight)  # offset starts at 0: prediction = attention mean
            nn.init.zeros_(self.head[-1].bias)

    def init_conv(self, in_channels: int, out_channels: int) -> nn.Module:
        raise NotImplementedError

    def propagation(self, edge_index: Tensor, num_nodes: int):
        """What the convolutions take as graph argument (default: ``edge_index``)."""
        return edge_index

    def node_embeddings(self, x: Tensor, edge_index: Tensor) -> Tensor:
        """Per-node outputs of the graph filters (permutation equivariant)."""
        adj = self.propagation(edge_index, x.shape[0])
        for conv in self.convs:
            x = torch.relu(conv(x, adj))
        return x

    def pool(self, x: Tensor, edge_index: Tensor, batch: Tensor | None = None) -> Tensor:
        """Graph max pool of the node embeddings (B, hidden) (permutation invariant)."""
        return global_max_pool(self.node_embeddings(x, edge_index), batch)

    def attend(self, h: Tensor, pos: Tensor, batch: Tensor | None, extra: Tensor | None = None,
               return_log_attention: bool = False):
        """Attention readout of node embeddings ``h`` (N, H).

        ``extra`` (N, E) or (N, k, E) is concatenated to every node embedding before scoring
        (the GNN-CVAE's latent); the result is (B, 2) or (B, k, 2), and with
        ``return_log_attention`` also the per-node log attention (N,) or (N, k).
        """
        if pos.shape[-1] != self.out_channels:
            raise ValueError(f"the attention readout predicts a position: pos has {pos.shape[-1]} "
                             f"columns, out_channels is {self.out_channels}")
        if batch is None:
            batch = torch.zeros(h.shape[0], dtype=torch.long, device=h.device)
        num_graphs = int(batch.max()) + 1 if batch.numel() else 1
        ctx = global_max_pool(h, batch, num_graphs)[batch] if self.context == "max" else None
        if extra is not None:
            if extra.dim() == 3:
                h = h[:, None, :].expand(-1, extra.shape[1], -1)
            h = torch.cat([h, extra], -1)
        if ctx is not None:     # every node's score also sees the graph's max-pooled embedding
            ctx = ctx[:, None, :].expand(-1, h.shape[1], -1) if h.dim() == 3 else ctx
            s = self.score(torch.cat([h, ctx], -1)).squeeze(-1)
        else:
            s = self.score(h).squeeze(-1)
        a = softmax(s, batch, num_nodes=h.shape[0], dim=0)  # (N,) or (N, k)
        w = a.unsqueeze(-1)
        p = pos if a.dim() == 1 else pos[:, None, :]
        mean_pos = scatter(w * p, batch, dim=0, dim_size=num_graphs, reduce="sum")
        pooled = scatter(w * h, batch, dim=0, dim_size=num_graphs, reduce="sum")
        out = mean_pos + self.head(pooled)
        if return_log_attention:
            lse = torch.log(scatter(torch.exp(s - s.max()), batch, dim=0, dim_size=num_graphs,
                                    reduce="sum")) + s.max()
            return out, s - lse[batch]
        return out

    @property
    def has_node_scores(self) -> bool:
        """Whether the model scores the graph's nodes (the attention readout does)."""
        return self.readout == "attention"

    def node_log_scores(self, x: Tensor, edge_index: Tensor, batch: Tensor | None = None,
                        pos: Tensor | None = None) -> Tensor:
        """Node-level prediction: log-probabilities (N,) over each graph's nodes (the log attention).

        The critical node distribution the label-node loss trains; planning takes its top-k
        nodes (:mod:`gnn_mp_envs.critical.selection`). Needs ``readout="attention"``.
        """
        if not self.has_node_scores:
            raise ValueError("node scores need readout='attention' (the max readout only predicts a point)")
        return self.forward(x, edge_index, batch, pos, return_log_attention=True)[1]

    def forward(self, x: Tensor, edge_index: Tensor, batch: Tensor | None = None,
                pos: Tensor | None = None, return_log_attention: bool = False):
        if self.readout == "attention":
            if pos is None:
                raise ValueError("the attention readout needs the node positions pos")
            return self.attend(self.node_embeddings(x, edge_index), pos, batch,
                               return_log_attention=return_log_attention)
        return self.head(self.pool(x, edge_index, batch)) + self._centre


class CriticalGNN(GraphPoolRegressor):
    """The paper's GNN: K-tap graph filters (TAGConv is eq. 1-3) in L layers."""

    def __init__(self, in_channels: int = NODE_FEATURES, hidden_channels: int = 32,
                 num_layers: int = 3, out_channels: int = STATE_DIM, K: int = 3,
                 head_in_extra: int = 0, readout: str = "max", edges: str = "valid",
                 centre: Centre = CENTRE, context: str = "none") -> None:
        self.K = K
        super().__init__(in_channels, hidden_channels, num_layers, out_channels, head_in_extra, readout,
                         edges, centre, context)

    def init_conv(self, in_channels: int, out_channels: int) -> nn.Module:
        # Normalisation is done once per pass in propagation() (same result as normalize=True).
        return TAGConv(in_channels, out_channels, K=self.K, normalize=False)

    def propagation(self, edge_index: Tensor, num_nodes: int) -> Tensor:
        """Symmetric-normalised adjacency (TAGConv's gcn_norm, no self loops) as a CSR tensor.

        Computed once for all layers; sparse CSR matmul is ~4x faster on CPU than
        edge-wise message passing, with identical outputs.
        """
        ei, w = gcn_norm(edge_index, None, num_nodes, add_self_loops=False)
        return to_torch_csr_tensor(ei.flip(0), w, size=(num_nodes, num_nodes))


class CriticalGAT(GraphPoolRegressor):
    """The paper's GAT: the same stack with attention-weighted aggregation (GATv2Conv)."""

    def __init__(self, in_channels: int = NODE_FEATURES, hidden_channels: int = 32,
                 num_layers: int = 3, out_channels: int = STATE_DIM, heads: int = 1,
                 readout: str = "max", edges: str = "valid", centre: Centre = CENTRE,
                 context: str = "none") -> None:
        self.heads = heads
        super().__init__(in_channels, hidden_channels, num_layers, out_channels, readout=readout,
                         edges=edges, centre=centre, context=context)

    def init_conv(self, in_channels: int, out_channels: int) -> nn.Module:
        return GATv2Conv(in_channels, out_channels, heads=self.heads, concat=False)


class _GaussianLatent(nn.Module):
    """VGAE-style helpers shared by both CVAEs."""

    latent_channels: int

    def reparametrize(self, mu: Tensor, logstd: Tensor, generator: torch.Generator | None = None) -> Tensor:
        if not self.training:
            return mu
        eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype)
        return mu + eps * logstd.exp()

    @staticmethod
    def kl_loss(mu: Tensor, logstd: Tensor) -> Tensor:
        """Mean over the batch of KL(q(z | x, y) || N(0, I))."""
        logstd = logstd.clamp(max=MAX_LOGSTD)
        return -0.5 * torch.mean(torch.sum(1 + 2 * logstd - mu ** 2 - logstd.exp() ** 2, dim=1))

    @staticmethod
    def recon_loss(y_hat: Tensor, y: Tensor) -> Tensor:
        """Gaussian log-likelihood up to scale: mean over the batch of squared error."""
        return torch.mean(torch.sum((y_hat - y) ** 2, dim=-1))

    def prior(self, batch_size: int, num_samples: int, generator: torch.Generator | None = None) -> Tensor:
        return torch.randn((batch_size, num_samples, self.latent_channels), generator=generator)


class CriticalGNNCVAE(_GaussianLatent):
    """GNN-CVAE: a graph encoder q(z | y, x, G) and a graph decoder p(y | z, x, G).

    The encoder sees the label as a node feature ``y - x_n`` next to ``x`` (max pool -> FC
    -> (mu, log sigma)). The decoder runs the graph filters of ``x`` once; with
    ``readout="max"`` it maps ``[pool, z]`` through its FC head, with ``"attention"`` it
    scores ``[h_n, z]`` per node and returns the attention mean of node positions plus an FC
    offset. Either way k samples cost one graph pass.
    """

    def __init__(self, in_channels: int = NODE_FEATURES, hidden_channels: int = 32,
                 num_layers: int = 3, out_channels: int = STATE_DIM, latent_channels: int = 2,
                 K: int = 3, readout: str = "max", edges: str = "valid", centre: Centre = CENTRE,
                 context: str = "none") -> None:
        super().__init__()
        if edges not in EDGE_MODES:
            raise ValueError(f"edges must be one of {EDGE_MODES}, got {edges!r}")
        self.in_channels, self.latent_channels, self.readout = in_channels, latent_channels, readout
        self.edges = edges
        self.encoder = CriticalGNN(in_channels + out_channels, hidden_channels, num_layers,
                                   2 * latent_channels, K=K)
        self.decoder = CriticalGNN(in_channels, hidden_channels, num_layers, out_channels, K=K,
                                   head_in_extra=latent_channels, readout=readout, centre=centre,
                                   context=context)

    def encode(self, x: Tensor, edge_index: Tensor, y: Tensor, pos: Tensor,
               batch: Tensor | None = None) -> tuple[Tensor, Tensor]:
        rel = y[batch] - pos if batch is not None else y.reshape(1, -1) - pos
        out = self.encoder.head(self.encoder.pool(torch.cat([x, rel], 1), edge_index, batch))
        mu, logstd = out.chunk(2, dim=1)
        return mu, logstd.clamp(max=MAX_LOGSTD)

    def condition(self, x: Tensor, edge_index: Tensor, batch: Tensor | None = None,
                  pos: Tensor | None = None):
        """Decoder features of the problem; reuse them for many latent samples.

        Max readout: pooled features (B, hidden). Attention readout: ``(h, pos, batch)``.
        """
        if self.readout == "attention":
            if pos is None:
                raise ValueError("the attention readout needs the node positions pos")
            return (self.decoder.node_embeddings(x, edge_index), pos, batch)
        return self.decoder.pool(x, edge_index, batch)

    def decode_pooled(self, pooled, z: Tensor, return_log_attention: bool = False):
        """Decode z (B, P) or (B, k, P) given :meth:`condition`'s output."""
        if self.readout == "attention":
            h, pos, batch = pooled
            zn = z[batch] if batch is not None else z.expand(h.shape[0], *z.shape[1:])
            return self.decoder.attend(h, pos, batch, zn, return_log_attention)
        if z.dim() == 3:
            pooled = pooled[:, None, :].expand(-1, z.shape[1], -1)
        return self.decoder.head(torch.cat([pooled, z], -1)) + self.decoder._centre

    def decode(self, z: Tensor, x: Tensor, edge_index: Tensor, batch: Tensor | None = None,
               pos: Tensor | None = None, return_log_attention: bool = False):
        return self.decode_pooled(self.condition(x, edge_index, batch, pos), z, return_log_attention)

    def sample(self, x: Tensor, edge_index: Tensor, batch: Tensor | None, num_samples: int,
               generator: torch.Generator | None = None, pos: Tensor | None = None) -> Tensor:
        """``num_samples`` critical states per graph (B, k, out_channels) from z ~ N(0, I)."""
        cond = self.condition(x, edge_index, batch, pos)
        num_graphs = 1 if batch is None else int(batch.max()) + 1
        return self.decode_pooled(cond, self.prior(num_graphs, num_samples, generator))

    @property
    def has_node_scores(self) -> bool:
        """Whether the decoder scores the graph's nodes (the attention readout does)."""
        return self.readout == "attention"

    def sample_with_node_scores(self, x: Tensor, edge_index: Tensor, batch: Tensor | None, num_samples: int,
                                generator: torch.Generator | None = None,
                                pos: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Decoded samples (B, k, d) and the node distribution (N,) of the same k latents.

        The node distribution is the mixture over the latents z_1..z_k ~ N(0, I) of the
        decoder's attention, ``log(mean_j p(n | z_j))``: one graph pass for both.
        """
        if not self.has_node_scores:
            raise ValueError("node scores need readout='attention' (the max readout only decodes points)")
        cond = self.condition(x, edge_index, batch, pos)
        num_graphs = 1 if batch is None else int(batch.max()) + 1
        out, log_a = self.decode_pooled(cond, self.prior(num_graphs, num_samples, generator),
                                        return_log_attention=True)
        return out, torch.logsumexp(log_a, dim=-1) - math.log(num_samples)


class CNNTrunk(nn.Module):
    """Strided conv layers on (occupancy, start, goal) images -> flat features."""

    def __init__(self, in_channels: int, hidden_channels: int, num_layers: int,
                 image_size: int = 64) -> None:
        super().__init__()
        layers, c = [], in_channels
        for i in range(num_layers):
            out = hidden_channels * min(2 ** i, 4)
            layers += [nn.Conv2d(c, out, 3, stride=2, padding=1), nn.ReLU()]
            c = out
        self.net = nn.Sequential(*layers, nn.Flatten())
        side = image_size // 2 ** num_layers
        self.out_features = c * side * side

    def forward(self, image: Tensor) -> Tensor:
        return self.net(image)


class HeatmapUNet(nn.Module):
    """A small U-Net: the :class:`CNNTrunk`'s strided convs, a global FC bottleneck (what the
    point CNN's FC head sees), then upsampling with skip connections to one logit per pixel."""

    def __init__(self, in_channels: int, hidden_channels: int, num_layers: int, image_size: int = 64,
                 fc_channels: int = 64) -> None:
        super().__init__()
        widths = [hidden_channels * min(2 ** i, 4) for i in range(num_layers)]
        self.down = nn.ModuleList()
        c = in_channels
        for w in widths:
            self.down.append(nn.Sequential(nn.Conv2d(c, w, 3, stride=2, padding=1), nn.ReLU()))
            c = w
        side = image_size // 2 ** num_layers
        self._bottleneck = (c, side, side)
        self.fc = nn.Sequential(nn.Flatten(), nn.Linear(c * side * side, fc_channels), nn.ReLU(),
                                nn.Linear(fc_channels, c * side * side))
        self.up = nn.ModuleList()
        skips = [in_channels] + widths[:-1]               # what each upsampled level is joined with
        for i in reversed(range(num_layers)):
            out = skips[i] if i > 0 else hidden_channels
            self.up.append(nn.Sequential(nn.Conv2d(c + skips[i], out, 3, padding=1), nn.ReLU()))
            c = out
        self.logit = nn.Conv2d(c, 1, 1)

    def forward(self, image: Tensor) -> Tensor:
        """Logits (B, H, W), row 0 at y = 0 like the input."""
        feats, h = [image], image
        for layer in self.down:
            h = layer(h)
            feats.append(h)
        h = h + self.fc(h).view(-1, *self._bottleneck)
        for layer, skip in zip(self.up, reversed(feats[:-1])):
            h = nn.functional.interpolate(h, size=skip.shape[-2:], mode="nearest")
            h = layer(torch.cat([h, skip], 1))
        return self.logit(h).squeeze(1)


#: CNN readouts: the first round's FC regression to a point, or a heat map over the image.
CNN_READOUTS = ("point", "heatmap")


class CriticalCNN(nn.Module):
    """Baseline: the GNN layers replaced by CNN layers on an occupancy image.

    ``readout="point"`` (the paper's): strided convs -> FC -> a state. ``readout="heatmap"``:
    a U-Net heat map over the image, read at the fixed graph's nodes ``pos`` (bilinear), so
    it scores the same candidate nodes as the graph models and is trained with the same
    label-node loss; the point prediction is the softmax-weighted mean of the node positions.
    """

    def __init__(self, in_channels: int = IMAGE_CHANNELS, hidden_channels: int = 16,
                 num_layers: int = 4, out_channels: int = STATE_DIM, image_size: int = 64,
                 centre: Centre = CENTRE, readout: str = "point") -> None:
        super().__init__()
        if readout not in CNN_READOUTS:
            raise ValueError(f"readout must be one of {CNN_READOUTS}, got {readout!r}")
        self.readout, self.out_channels = readout, out_channels
        if readout == "point":
            self.trunk = CNNTrunk(in_channels, hidden_channels, num_layers, image_size)
            self.head = _mlp(self.trunk.out_features, 128, out_channels)
        else:
            self.unet = HeatmapUNet(in_channels, hidden_channels, num_layers, image_size)
        _centre_buffer(self, centre)

    @property
    def has_node_scores(self) -> bool:
        return self.readout == "heatmap"

    def heatmap(self, image: Tensor) -> Tensor:
        """Logits (B, H, W) over the image (``readout="heatmap"``)."""
        return self.unet(image)

    def node_log_scores(self, image: Tensor, pos: Tensor) -> Tensor:
        """Log-probabilities over the nodes ``pos`` (N, 2) of each image, flattened (B * N,)
        in the graph batches' layout (problem-major)."""
        if not self.has_node_scores:
            raise ValueError("node scores need readout='heatmap' (the point readout only predicts a point)")
        if pos.shape[-1] != 2:
            raise ValueError("the heat map is read at 2-D positions in the unit square")
        grid = (2 * pos - 1).to(image.dtype)[None, None].expand(image.shape[0], 1, -1, -1)
        logits = nn.functional.grid_sample(self.heatmap(image)[:, None], grid, mode="bilinear",
                                           padding_mode="border", align_corners=False)[:, 0, 0]   # (B, N)
        return torch.log_softmax(logits, dim=-1).reshape(-1)

    def forward(self, image: Tensor, pos: Tensor | None = None, return_log_attention: bool = False):
        if self.readout == "point":
            return self.head(self.trunk(image)) + self._centre
        if pos is None:
            raise ValueError("the heat-map readout needs the node positions pos")
        log_a = self.node_log_scores(image, pos)
        w = log_a.exp().view(image.shape[0], -1)
        out = w @ pos.to(w.dtype)
        return (out, log_a) if return_log_attention else out


class CriticalCVAE(_GaussianLatent):
    """Baseline CVAE: CNN condition embedding, FC encoder and decoder."""

    def __init__(self, in_channels: int = IMAGE_CHANNELS, hidden_channels: int = 16,
                 num_layers: int = 4, out_channels: int = STATE_DIM, latent_channels: int = 2,
                 image_size: int = 64, embed_channels: int = 128, centre: Centre = CENTRE) -> None:
        super().__init__()
        self.latent_channels = latent_channels
        _centre_buffer(self, centre)
        self.trunk = nn.Sequential(CNNTrunk(in_channels, hidden_channels, num_layers, image_size))
        self.embed = nn.Sequential(nn.Linear(self.trunk[0].out_features, embed_channels), nn.ReLU())
        self.encoder = _mlp(embed_channels + out_channels, embed_channels, 2 * latent_channels)
        self.decoder = _mlp(embed_channels + latent_channels, embed_channels, out_channels)

    def condition(self, image: Tensor) -> Tensor:
        return self.embed(self.trunk(image))

    def encode(self, image: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
        mu, logstd = self.encoder(torch.cat([self.condition(image), y], 1)).chunk(2, dim=1)
        return mu, logstd.clamp(max=MAX_LOGSTD)

    def decode_pooled(self, cond: Tensor, z: Tensor) -> Tensor:
        if z.dim() == 3:
            cond = cond[:, None, :].expand(-1, z.shape[1], -1)
        return self.decoder(torch.cat([cond, z], -1)) + self._centre

    def decode(self, z: Tensor, image: Tensor) -> Tensor:
        return self.decode_pooled(self.condition(image), z)

    def sample(self, image: Tensor, num_samples: int, generator: torch.Generator | None = None) -> Tensor:
        cond = self.condition(image)
        return self.decode_pooled(cond, self.prior(cond.shape[0], num_samples, generator))


#: Model name -> (class, family). Families: "graph"/"image" inputs, "det"/"cvae" outputs.
MODELS: dict[str, tuple[type[nn.Module], str, str]] = {
    "gnn": (CriticalGNN, "graph", "det"),
    "gat": (CriticalGAT, "graph", "det"),
    "gnn-cvae": (CriticalGNNCVAE, "graph", "cvae"),
    "cnn": (CriticalCNN, "image", "det"),
    "cvae": (CriticalCVAE, "image", "cvae"),
}


def build_model(name: str, **kwargs) -> nn.Module:
    """Instantiate a critical-sample model by name (see :data:`MODELS`)."""
    if name not in MODELS:
        raise ValueError(f"unknown critical model {name!r}; known: {sorted(MODELS)}")
    return MODELS[name][0](**kwargs)


def kind_of(name: str) -> str:
    """The checkpoint kind of a critical model name: ``"gnn"`` -> ``"critical/gnn"``."""
    if name not in MODELS:
        raise ValueError(f"unknown critical model {name!r}; known: {sorted(MODELS)}")
    return KIND_PREFIX + name


def name_of(kind: str) -> str:
    """The critical model name of a checkpoint kind: ``"critical/gnn"`` -> ``"gnn"``."""
    name = kind[len(KIND_PREFIX):] if kind.startswith(KIND_PREFIX) else None
    if name not in MODELS:
        raise ValueError(f"{kind!r} is not a critical-sample model kind")
    return name


for _name, (_cls, _, _) in MODELS.items():
    register_model_kind(kind_of(_name), _cls)
