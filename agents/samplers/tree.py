"""Samplers over the growing tree: the GNN, CVAE and GNN-CVAE of :mod:`agents.models.tree_samplers`
(the GNN sample scorer, the pendulum's GNN head, is :mod:`agents.samplers.tree_scorer`).

Every sampler mixes its model with uniform samples at a fixed rate (``uniform_mix``, which
keeps the planner probabilistically complete) and may add goal samples (``goal_bias``):

    with probability uniform_mix       -> uniform over the bounds
    with probability goal_bias         -> the active tree's target (goal; start for BiRRT's goal tree)
    otherwise                          -> the model's sample (wrapped, clipped to the bounds)

**Inference cost.** The GNN is causal (a node's embedding is fixed when it is inserted), so
:meth:`TreeGNNSampler.act` keeps per-episode caches: each new observation row is embedded
once (its causal k-NN found against the cached states of its tree, the message MLPs' sender
terms cached per node and layer), the per-tree embedding sums are running sums, and a sample
costs one small query MLP, one ``(n, H) @ (H,)`` product and a draw. No graph is rebuilt and
no earlier node is re-run; ``gnn-mp bench-sampler`` reports the cost at 1,000 nodes. The
CVAE does not read the tree: it decodes a batch of ``proposals`` per forward pass and spends
them over the next steps. The batched TensorDict path (:meth:`propose`) recomputes from the
padded observation, with the same distribution.

Randomness: ``reset(seed)`` seeds both the torch generator (batched path) and a numpy
generator (``act``), so a benchmark run is reproducible.
"""

from __future__ import annotations

import importlib
import math
from typing import Mapping

import numpy as np
import torch
from scipy.special import erf

from agents.models.tree_samplers import TreeCVAE, TreeGNN, TreeGNNCVAE, causal_knn
from agents.samplers.base import SAMPLER_IN_KEYS, Sampler


def _gelu(x: np.ndarray) -> np.ndarray:
    return 0.5 * x * (1.0 + erf(x / math.sqrt(2.0)))


def _linears(seq: torch.nn.Sequential) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(m.weight.detach().numpy().T.astype(np.float64).copy(), m.bias.detach().numpy().astype(np.float64).copy())
            for m in seq if isinstance(m, torch.nn.Linear)]


def _layer_norm(norms: list[tuple[np.ndarray, np.ndarray, float]], x: np.ndarray, layer: int) -> np.ndarray:
    """``torch.nn.LayerNorm`` of layer ``layer`` in numpy (``norms``: its weight, bias, eps)."""
    g, b, eps = norms[layer]
    mu = x.mean(-1, keepdims=True)
    var = ((x - mu) ** 2).mean(-1, keepdims=True)
    return (x - mu) / np.sqrt(var + eps) * g + b


def _run_mlp(layers: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
    for i, (w, b) in enumerate(layers):
        x = x @ w + b
        if i < len(layers) - 1:
            x = _gelu(x)
    return x


def _wrap(delta: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    if not periodic.any():
        return delta
    return np.where(periodic, (delta + np.pi) % (2 * np.pi) - np.pi, delta)


class IncrementalTreeGNN:
    """Numpy inference of a :class:`TreeGNN` that embeds each new tree node once (exactly the
    model's math: the same causal k-NN, messages, updates and heads)."""

    def __init__(self, model: TreeGNN, capacity: int = 1024) -> None:
        m = model.eval()
        self.model = m
        self.d, self.H, self.L, self.k, self.trees = m.state_dim, m.hidden_channels, m.num_layers, m.knn, m.num_trees
        buf = lambda t: t.detach().numpy().astype(np.float64).copy()  # noqa: E731
        self.center, self.scale = buf(m.state_center), buf(m.state_scale)
        self.feature_scale, self.step = buf(m.feature_scale), buf(m.step_scale)
        self.periodic = m.periodic.numpy().copy()
        self.input = _linears(m.input)
        H = self.H
        # First message layer split into sender / receiver parts: W [h_j, (x_j - x_i)/s] + b.
        self.messages = []
        for conv_p, conv_k in zip(m.parent_convs, m.knn_convs):
            split = []
            for conv in (conv_p, conv_k):
                (w1, b1), (w2, b2) = _linears(conv.net)
                split.append((w1[:H], w1[H:] / self.step[:, None], b1, w2, b2))
            self.messages.append(split)
        self.updates = [_linears(u) for u in m.updates]
        self.norms = [(buf(n.weight), buf(n.bias), n.eps) for n in m.norms]
        self.query = _linears(m.query)
        self.key = _linears(torch.nn.Sequential(m.key))[0]
        self.node_head = _linears(torch.nn.Sequential(m.node_head))[0]
        self.query_shift = _linears(torch.nn.Sequential(m.query_shift))[0]
        self.use_parent, self.use_knn, self.use_context = m.use_parent, m.use_knn, m.use_context
        self._allocate(capacity)
        self.clear()

    def _allocate(self, capacity: int) -> None:
        d, H, L, T = self.d, self.H, self.L, self.trees
        self.capacity = capacity
        self.states = np.zeros((capacity, d))
        self.tree_id = np.zeros(capacity, dtype=np.int64)
        self.sender = np.zeros((L, 2, capacity, H))        # cached W_h h_j + W_x x_j / s per layer, edge type
        self.keys = np.zeros((capacity, H))
        self.offsets = np.zeros((capacity, T, d))
        self.log_sigma = np.zeros((capacity, T, d))

    def _grow(self, n: int) -> None:
        if n <= self.capacity:
            return
        old = (self.states, self.tree_id, self.sender, self.keys, self.offsets, self.log_sigma, self.capacity)
        self._allocate(max(n, 2 * self.capacity))
        cap = old[-1]
        self.states[:cap], self.tree_id[:cap], self.keys[:cap] = old[0], old[1], old[3]
        self.sender[:, :, :cap] = old[2]
        self.offsets[:cap], self.log_sigma[:cap] = old[4], old[5]

    def clear(self) -> None:
        self.n = 0
        self.sums = np.zeros((self.trees, self.H))
        self.counts = np.zeros(self.trees)
        self.start = None

    def ingest(self, obs: Mapping[str, np.ndarray]) -> int:
        """Embed the observation's rows not seen yet (a new episode restarts the cache)."""
        n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
        problem = np.concatenate([np.asarray(obs["start"], np.float64), np.asarray(obs["goal"], np.float64)])
        if n < self.n or self.start is None or not np.array_equal(problem, self.start):
            self.clear()   # a new episode
            self.start = problem
        i0 = self.n
        if n == i0:
            return n
        self._grow(n)
        d, H = self.d, self.H
        x = np.asarray(obs["nodes"][i0:n], dtype=np.float64)
        feats = np.asarray(obs["node_features"][i0:n], dtype=np.float64)
        tid = feats[:, 2 * d].astype(np.int64)
        parent = np.asarray(obs["parent"][i0:n]).astype(np.int64)
        self.states[i0:n], self.tree_id[i0:n] = x, tid
        h = _run_mlp(self.input, np.concatenate([feats / self.feature_scale, (x - self.center) / self.scale], -1))
        B = n - i0
        # causal k-NN: earlier nodes of the same tree, distances in step units, angles wrapped
        if self.k:
            diff = _wrap(self.states[None, :n] - x[:, None], self.periodic) / self.step
            dist = (diff * diff).sum(-1)
            later = np.arange(n)[None, :] >= np.arange(i0, n)[:, None]
            dist[later | (self.tree_id[None, :n] != tid[:, None])] = np.inf
            k = min(self.k, n)
            near = np.argsort(dist, axis=1, kind="stable")[:, :k]   # ties to the earlier node, as the model
            near_ok = np.isfinite(np.take_along_axis(dist, near, 1))
        has_parent = parent >= 0
        par = np.where(has_parent, parent, 0)
        for layer in range(self.L):
            (wph, wpx, bp1, wp2, bp2), (wkh, wkx, bk1, wk2, bk2) = self.messages[layer]
            self.sender[layer, 0, i0:n] = h @ wph + x @ wpx
            self.sender[layer, 1, i0:n] = h @ wkh + x @ wkx
            mp = np.zeros((B, H))
            if self.use_parent and has_parent.any():
                rel_p = _wrap(self.states[par] - x, self.periodic) @ wpx - (self.states[par] @ wpx - x @ wpx)
                pre = self.sender[layer, 0, par] - x @ wpx + rel_p + bp1
                mp = np.where(has_parent[:, None], _gelu(pre) @ wp2 + bp2, 0.0)
            mk = np.zeros((B, H))
            if self.use_knn and self.k:
                sj = self.states[near]                                               # (B, k, d)
                rel_k = (_wrap(sj - x[:, None], self.periodic) - (sj - x[:, None])) @ wkx
                pre = self.sender[layer, 1][near] - (x @ wkx)[:, None] + rel_k + bk1
                g = _gelu(pre) * near_ok[..., None]
                count = near_ok.sum(1, keepdims=True)
                mk = np.where(count > 0, (g.sum(1) / np.maximum(count, 1)) @ wk2 + bk2, 0.0)
            h = _layer_norm(self.norms, h + _run_mlp(self.updates[layer], np.concatenate([h, mp, mk], -1)), layer)
        w, b = self.key
        self.keys[i0:n] = h @ w + b
        w, b = self.node_head
        o = (h @ w + b).reshape(B, self.trees, 2 * d)
        self.offsets[i0:n] = o[..., :d] * self.step
        self.log_sigma[i0:n] = np.clip(o[..., d:], -4.0, 1.0)
        np.add.at(self.sums, tid, h)
        np.add.at(self.counts, tid, 1.0)
        self.n = n
        return n

    def context(self, start: np.ndarray, goal: np.ndarray, active: int) -> np.ndarray:
        means = self.sums / np.maximum(self.counts, 1.0)[:, None]
        if not self.use_context:
            means = means * 0.0
        parts = [(start - self.center) / self.scale, (goal - self.center) / self.scale, np.eye(self.trees)[active],
                 means.reshape(-1), np.log1p(self.counts) / 5.0]
        return _run_mlp(self.query, np.concatenate(parts))

    def mixture(self, q: np.ndarray, active: int, temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """Node probabilities ``(n,)`` and the component shift ``(d,)`` at the current tree."""
        logits = self.keys[:self.n] @ q / math.sqrt(self.H) / temperature
        p = np.exp(logits - logits.max())
        w, b = self.query_shift
        shift = (q @ w + b).reshape(self.trees, self.d)[active] * self.step
        return p / p.sum(), shift


class _MixedSampler(Sampler):
    """Uniform / goal / model mixture shared by the tree samplers (see the module docstring)."""

    reads = SAMPLER_IN_KEYS

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, uniform_mix: float = 0.25,
                 goal_bias: float = 0.0, periodic: np.ndarray | None = None) -> None:
        if not (0.0 <= uniform_mix <= 1.0 and 0.0 <= goal_bias <= 1.0 and uniform_mix + goal_bias <= 1.0):
            raise ValueError(f"uniform_mix and goal_bias must be in [0, 1] with a sum <= 1, got {uniform_mix}, "
                             f"{goal_bias}")
        self.uniform_mix, self.goal_bias = float(uniform_mix), float(goal_bias)
        self._periodic = np.zeros(len(low), dtype=bool) if periodic is None else np.asarray(periodic, dtype=bool)
        super().__init__(low, high, seed)
        self._low64, self._high64 = np.asarray(low, np.float64), np.asarray(high, np.float64)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.rng = np.random.default_rng(None if seed is None else int(seed))

    def _finish(self, x: np.ndarray) -> np.ndarray:
        return np.clip(_wrap(x, self._periodic), self._low64, self._high64).astype(np.float32)

    def act(self, obs: Mapping) -> np.ndarray:
        u = self.rng.random()
        if u < self.uniform_mix:
            return self.rng.uniform(self._low64, self._high64).astype(np.float32)
        if u < self.uniform_mix + self.goal_bias:
            target = obs["start"] if int(np.asarray(obs["active_tree"]).reshape(-1)[0]) == 1 else obs["goal"]
            return np.asarray(target, dtype=np.float32).copy()
        return self._finish(self.model_sample(obs))

    def model_sample(self, obs: Mapping) -> np.ndarray:
        raise NotImplementedError

    def propose(self, obs: Mapping) -> torch.Tensor:
        """Batched path (TensorDict / TorchRL): one ``act`` per observation, in batch order, with
        the random stream of ``self.rng`` (the per-episode caches are not used)."""
        arrays = {k: np.asarray(v.detach().cpu() if isinstance(v, torch.Tensor) else v) for k, v in obs.items()
                  if k in SAMPLER_IN_KEYS}
        shape = arrays["start"].shape[:-1]
        flat = {k: v.reshape(-1, *v.shape[len(shape):]) for k, v in arrays.items()}
        out = np.stack([self._stateless_act({k: v[i] for k, v in flat.items()}) for i in range(int(np.prod(shape)))])
        return torch.as_tensor(out.reshape(*shape, -1))

    def _stateless_act(self, obs: Mapping) -> np.ndarray:
        return self.act(obs)


class _TreeContextSampler(_MixedSampler):
    """A sampler that reads the tree through an :class:`IncrementalTreeGNN` (per-episode caches)."""

    def _attach(self, gnn: TreeGNN) -> None:
        self.engine = IncrementalTreeGNN(gnn)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        if hasattr(self, "engine"):
            self.engine.clear()

    def tree_context(self, obs: Mapping) -> tuple[np.ndarray, int]:
        """Ingest the observation's new nodes; the tree context ``q`` and the active tree."""
        self.engine.ingest(obs)
        active = int(np.asarray(obs["active_tree"]).reshape(-1)[0])
        q = self.engine.context(np.asarray(obs["start"], np.float64), np.asarray(obs["goal"], np.float64), active)
        return q, active

    def _stateless_act(self, obs: Mapping) -> np.ndarray:
        self.engine.clear()
        return self.act(obs)


class TreeGNNSampler(_TreeContextSampler):
    """The GNN sampler (Algorithm 1): a node of the tree ~ softmax(key . q / temperature), then
    a Gaussian around its learned offset (scale times ``sigma_scale``)."""

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeGNN,
                 uniform_mix: float = 0.25, goal_bias: float = 0.0, temperature: float = 1.0,
                 sigma_scale: float = 1.0) -> None:
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.periodic.numpy())
        self.model = model.eval()
        self._attach(model)
        self.temperature, self.sigma_scale = float(temperature), float(sigma_scale)

    def model_sample(self, obs: Mapping) -> np.ndarray:
        q, active = self.tree_context(obs)
        e = self.engine
        p, shift = e.mixture(q, active, self.temperature)
        m = min(int(np.searchsorted(np.cumsum(p), self.rng.random() * (1 - 1e-12), side="right")), e.n - 1)
        sigma = self.sigma_scale * np.exp(e.log_sigma[m, active])
        return e.states[m] + e.offsets[m, active] + shift + sigma * self.rng.standard_normal(e.d)


class TreeCVAESampler(_MixedSampler):
    """Ichter et al.'s CVAE: decodes ``proposals`` states per forward pass for the problem
    (start, goal, obstacles) and spends them over the next steps; it does not read the tree."""

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeCVAE,
                 uniform_mix: float = 0.25, goal_bias: float = 0.0, proposals: int = 32) -> None:
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.periodic.numpy())
        self.model = model.eval()
        self.proposals = int(proposals)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._queue: list[np.ndarray] = []
        self._key = None

    def model_sample(self, obs: Mapping) -> np.ndarray:
        key = b"".join(np.asarray(obs[k]).tobytes() for k in ("start", "goal", "obstacles"))
        if key != self._key:
            self._queue, self._key = [], key
        if not self._queue:
            condition = cvae_condition(self.model, obs)
            z = torch.as_tensor(self.rng.standard_normal((self.proposals, self.model.latent_channels)), dtype=torch.float32)
            with torch.no_grad():
                self._queue = list(self.model.decode(z, condition.expand(self.proposals, -1)).double().numpy())
        return self._queue.pop()


class TreeGNNCVAESampler(_TreeContextSampler):
    """The GNN-CVAE: the causal GNN summarises the tree (incrementally, as the GNN sampler),
    the decoder turns a latent draw and that context into the next sample."""

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeGNNCVAE,
                 uniform_mix: float = 0.25, goal_bias: float = 0.0) -> None:
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.gnn.periodic.numpy())
        self.model = model.eval()
        self._attach(model.gnn)

    def model_sample(self, obs: Mapping) -> np.ndarray:
        q, _ = self.tree_context(obs)
        z = torch.as_tensor(self.rng.standard_normal(self.model.latent_channels), dtype=torch.float32)
        with torch.no_grad():
            return self.model.decode(z[None], torch.as_tensor(q, dtype=torch.float32)[None])[0].double().numpy()


def cvae_condition(model: TreeCVAE, obs: Mapping) -> torch.Tensor:
    """``[start, goal, obstacle rows]`` of one observation, states scaled as the model's."""
    center, scale = model.state_center.numpy(), model.state_scale.numpy()
    start = (np.asarray(obs["start"], np.float32) - center) / scale
    goal = (np.asarray(obs["goal"], np.float32) - center) / scale
    obstacles = np.asarray(obs["obstacles"], np.float32).reshape(-1)
    return torch.as_tensor(np.concatenate([start, goal, obstacles]), dtype=torch.float32)


def reference_embeddings(model: TreeGNN, obs: Mapping) -> torch.Tensor:
    """The torch model's node embeddings of one padded observation (tests compare the
    incremental engine against this)."""
    n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
    d = model.state_dim
    nodes = torch.as_tensor(np.asarray(obs["nodes"][:n]), dtype=torch.float32)
    feats = torch.as_tensor(np.asarray(obs["node_features"][:n]), dtype=torch.float32)
    tid = feats[:, 2 * d].long()
    parent = torch.as_tensor(np.asarray(obs["parent"][:n])).long()
    knn = causal_knn(nodes, tid, model.knn, model.step_scale, model.periodic)
    with torch.no_grad():
        return model.embed(nodes, feats, parent, knn)


# ---------------------------------------------------------------------------- registry
#: Checkpoint kind -> (sampler class or ``"module:Class"`` imported on first use, the sampling
#: settings a checkpoint's ``meta["sampler"]`` may carry).
KIND_SAMPLERS: dict[str, tuple[type | str, tuple[str, ...]]] = {
    "tree/gnn": (TreeGNNSampler, ("uniform_mix", "goal_bias", "temperature", "sigma_scale")),
    "tree/gnn-scorer": ("agents.samplers.tree_scorer:TreeScorerSampler",   # builds on _MixedSampler above
                        ("uniform_mix", "goal_bias", "candidates", "temperature")),
    "tree/cvae": (TreeCVAESampler, ("uniform_mix", "goal_bias", "proposals")),
    "tree/gnn-cvae": (TreeGNNCVAESampler, ("uniform_mix", "goal_bias")),
}
#: Sampler name -> the checkpoint kinds it accepts (a task ships the GNN head that works best for it:
#: the node mixture ``tree/gnn``, or the sample scorer ``tree/gnn-scorer`` on the pendulum).
NAME_KINDS: dict[str, tuple[str, ...]] = {"gnn": ("tree/gnn", "tree/gnn-scorer"), "cvae": ("tree/cvae",),
                                          "gnn-cvae": ("tree/gnn-cvae",)}


def shipped_checkpoint(name: str, task: str):
    """Where the package ships the ``name`` sampler's weights for ``task``."""
    from agents.checkpoints import SHIPPED_DIR
    return SHIPPED_DIR / f"tree_{name}_{task}.pt"


def load_tree_sampler(name: str, low: np.ndarray, high: np.ndarray, task: str | None = None,
                      seed: int | None = None, checkpoint: str | None = None, **settings) -> _MixedSampler:
    """A tree sampler with its weights (``checkpoint`` or the shipped file for ``task``) and the
    sampling settings stored with them (``meta["sampler"]``), which ``settings`` override."""
    from agents.checkpoints import load_checkpoint, resolve_checkpoint
    checkpoint = resolve_checkpoint(name, task, checkpoint, shipped_checkpoint(name, task) if task else None,
                                    f"gnn-mp train sampler --task {task} --model {name}")
    model, record = load_checkpoint(checkpoint, expected_kind=NAME_KINDS[name])
    cls, allowed = KIND_SAMPLERS[record["kind"]]
    if isinstance(cls, str):
        module, _, attr = cls.partition(":")
        cls = getattr(importlib.import_module(module), attr)
    meta = record.get("meta") or {}
    unknown = sorted(set(settings) - set(allowed))
    if unknown:
        raise ValueError(f"sampler {name!r} ({record['kind']}) takes {', '.join(allowed)}; "
                         f"unknown: {', '.join(unknown)}")
    trained_for = meta.get("task")
    if task is not None and trained_for is not None and trained_for != task:
        raise ValueError(f"{checkpoint}: weights trained for task {trained_for!r}, not {task!r}")
    chosen = {k: v for k, v in dict(meta.get("sampler") or {}).items() if k in allowed}
    chosen.update(settings)
    return cls(low, high, seed, model=model, **chosen)
