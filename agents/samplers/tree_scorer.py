"""The GNN sample-scorer sampler: ``M`` uniform candidates, one picked by the learned scorer.

Each model step (probability ``1 - uniform_mix - goal_bias``; see :class:`_MixedSampler` for the
uniform and goal shares) draws ``candidates`` uniform states, finds each one's nearest node of
the active tree under the planner's metric (the node the planner would extend), scores them
with :class:`agents.models.tree_scorer.TreeGNNScorer` and returns one drawn with
``softmax(logit / temperature)``.

**Inference cost.** :class:`IncrementalTreeScorer` keeps per-episode caches in numpy: each new
observation row is embedded once (its causal k-NN found against the cached states, the
``L`` message-passing layers run from the cached embeddings of earlier nodes), and the
frontier sums of the nodes it points at (its parent and its nearest) are updated in place,
``O(knn)`` per insertion. A sample then costs the candidates' nearest-node search
(``M x n`` distances), ``M`` head MLPs and a draw; ``gnn-mp bench-sampler`` reports it at
1,000 nodes. The engine computes the torch model's math exactly (float64; tested against
:meth:`TreeGNNScorer.forward`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

from agents.models.tree_scorer import EDGE_TYPES, TreeGNNScorer
from agents.samplers.tree import _layer_norm, _linears, _MixedSampler, _run_mlp, _wrap


class IncrementalTreeScorer:
    """Numpy inference of a :class:`TreeGNNScorer` that embeds each new tree node once and keeps
    every node's frontier sum and counts up to date."""

    def __init__(self, model: TreeGNNScorer, capacity: int = 1024) -> None:
        m = model.eval()
        self.d, self.H, self.L, self.k = m.state_dim, m.hidden_channels, m.num_layers, m.knn
        buf = lambda t: t.detach().numpy().astype(np.float64).copy()  # noqa: E731
        self.center, self.scale = buf(m.state_center), buf(m.state_scale)
        self.feature_scale, self.step = buf(m.feature_scale), buf(m.step_scale)
        self.weights = buf(m.metric_weights)
        self.periodic = m.periodic.numpy().copy()
        self.angle_cols = np.flatnonzero(self.periodic)
        self.depth_scale = m.depth_scale
        self.unit = float(np.linalg.norm(self.weights * self.step))
        self.input = _linears(m.input)
        self.parent_convs = [_linears(c.net) for c in m.parent_convs]
        self.knn_convs = [_linears(c.net) for c in m.knn_convs]
        self.updates = [_linears(u) for u in m.updates]
        self.norms = [(buf(n.weight), buf(n.bias), n.eps) for n in m.norms]
        self.frontier_net = _linears(m.frontier.net)
        self.head = _linears(m.head)
        self._allocate(capacity)
        self.clear()

    def _allocate(self, capacity: int) -> None:
        self.capacity = capacity
        self.states = np.zeros((capacity, self.d))
        self.tree_id = np.zeros(capacity, dtype=np.int64)
        self.depth = np.zeros(capacity)
        self.h = np.zeros((self.L + 1, capacity, self.H))          # embeddings after each layer
        self.front = np.zeros((capacity, self.H + EDGE_TYPES))     # frontier sums and counts

    def _grow(self, n: int) -> None:
        if n <= self.capacity:
            return
        old = (self.states, self.tree_id, self.depth, self.h, self.front, self.capacity)
        self._allocate(max(n, 2 * self.capacity))
        c = old[-1]
        self.states[:c], self.tree_id[:c], self.depth[:c], self.front[:c] = old[0], old[1], old[2], old[4]
        self.h[:, :c] = old[3]

    def clear(self) -> None:
        self.n = 0
        self.problem = None
        self.goal = None
        self.multi_tree = False
        self.front[:] = 0.0

    def _sq_dist(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(A, B)`` squared planner distances between rows of ``a`` and ``b`` (states in their
        bounds, so a periodic difference is at most one period: ``min(|d|, 2 pi - |d|)``)."""
        out = np.zeros((len(a), len(b)))
        for c in range(self.d):
            diff = np.abs(a[:, c, None] - b[None, :, c])
            if self.periodic[c]:
                diff = np.minimum(diff, 2 * np.pi - diff)
            diff *= self.weights[c]
            out += diff * diff
        return out

    def _angles(self, x: np.ndarray) -> list[np.ndarray]:
        a = x[..., self.angle_cols]
        return [np.sin(a), np.cos(a)]

    def ingest(self, obs: Mapping[str, np.ndarray]) -> int:
        """Embed the observation's rows not seen yet (a new episode restarts the caches)."""
        n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
        problem = np.concatenate([np.asarray(obs["start"], np.float64), np.asarray(obs["goal"], np.float64)])
        if n < self.n or self.problem is None or not np.array_equal(problem, self.problem):
            self.clear()   # a new episode
            self.problem, self.goal = problem, problem[self.d:]
        i0 = self.n
        if n == i0:
            return n
        self._grow(n)
        d = self.d
        x = np.asarray(obs["nodes"][i0:n], dtype=np.float64)
        feats = np.asarray(obs["node_features"][i0:n], dtype=np.float64)
        tid = feats[:, 2 * d].astype(np.int64)
        parent = np.asarray(obs["parent"][i0:n]).astype(np.int64)
        self.states[i0:n], self.tree_id[i0:n] = x, tid
        self.multi_tree = self.multi_tree or bool((tid != 0).any())
        for r, p in enumerate(parent):      # a parent may be a row of this batch
            self.depth[i0 + r] = self.depth[p] + 1.0 if p >= 0 else 0.0
        B = n - i0
        goal = np.broadcast_to(self.goal, (B, d))
        inputs = np.concatenate([feats / self.feature_scale, (x - self.center) / self.scale,
                                 (goal - self.center) / self.scale, *self._angles(x), *self._angles(feats[:, d:2 * d]),
                                 *self._angles(goal), (self.depth[i0:n] / self.depth_scale)[:, None]], -1)
        h = _run_mlp(self.input, inputs)
        self.h[0, i0:n] = h
        # causal k-NN under the planner's metric: earlier nodes of the same tree, ties to the earlier node
        rows = np.arange(i0, n)
        if self.k:
            dist = self._sq_dist(x, self.states[:n])
            dist[(np.arange(n)[None, :] >= rows[:, None]) | (self.tree_id[None, :n] != tid[:, None])] = np.inf
            near = np.argsort(dist, axis=1, kind="stable")[:, :min(self.k, n)]
            near_ok = np.isfinite(np.take_along_axis(dist, near, 1))
        else:
            near, near_ok = np.zeros((B, 0), np.int64), np.zeros((B, 0), bool)
        has_parent = parent >= 0
        par = np.where(has_parent, parent, 0)
        rel_p = _wrap(self.states[par] - x, self.periodic) / self.step                   # (B, d)
        rel_k = _wrap(self.states[near] - x[:, None], self.periodic) / self.step          # (B, k, d)
        count = near_ok.sum(1, keepdims=True)
        for layer in range(self.L):
            mp = _run_mlp(self.parent_convs[layer], np.concatenate([self.h[layer, par], rel_p], -1))
            mp = np.where(has_parent[:, None], mp, 0.0)
            msg = _run_mlp(self.knn_convs[layer], np.concatenate([self.h[layer][near], rel_k], -1))
            mk = np.where(count > 0, (msg * near_ok[..., None]).sum(1) / np.maximum(count, 1), 0.0)
            h = _layer_norm(self.norms, h + _run_mlp(self.updates[layer], np.concatenate([h, mp, mk], -1)), layer)
            self.h[layer + 1, i0:n] = h
        # frontier: every new row is a newer node pointing at its parent (type 0) and its nearest (type 1)
        receivers = np.concatenate([par[has_parent], near[near_ok]])
        senders = np.concatenate([np.flatnonzero(has_parent), np.nonzero(near_ok)[0]])
        etype = np.concatenate([np.zeros(int(has_parent.sum()), np.int64), np.ones(int(near_ok.sum()), np.int64)])
        if len(receivers):
            onehot = np.eye(EDGE_TYPES)[etype]
            rel = _wrap(x[senders] - self.states[receivers], self.periodic) / self.step
            phi = _run_mlp(self.frontier_net, np.concatenate([h[senders], rel, onehot], -1))
            np.add.at(self.front, receivers, np.concatenate([phi, onehot], -1))
        self.n = n
        return n

    def nearest(self, samples: np.ndarray, active: int = 0) -> np.ndarray:
        """Each sample's nearest node of tree ``active`` (planner metric, first on ties)."""
        S = self.states[:self.n]
        idx = None
        if self.multi_tree:
            idx = np.flatnonzero(self.tree_id[:self.n] == active)
            S = S[idx]
        j = np.argmin(self._sq_dist(samples, S), axis=1)
        return j if idx is None else idx[j]

    def logits(self, samples: np.ndarray, near: np.ndarray) -> np.ndarray:
        """Scores ``(M,)`` of candidate ``samples`` ``(M, d)`` whose nearest nodes are ``near``."""
        xn = self.states[near]
        rel = _wrap(samples - xn, self.periodic)
        to_goal = _wrap(self.goal - samples, self.periodic)
        dist = np.sqrt(((self.weights * rel) ** 2).sum(-1, keepdims=True)) / self.unit
        cand = np.concatenate([rel / self.scale, dist, to_goal / self.scale, (samples - self.center) / self.scale,
                               *self._angles(samples), *self._angles(to_goal)], -1)
        front = self.front[near]
        total, counts = front[:, :self.H], front[:, self.H:]
        z = np.concatenate([self.h[self.L, near], total / (1 + counts.sum(-1, keepdims=True)), np.log1p(counts), cand],
                           -1)
        return _run_mlp(self.head, z)[:, 0]


class TreeScorerSampler(_MixedSampler):
    """``candidates`` uniform states, one drawn with ``softmax(score / temperature)`` (see the
    module docstring); mixed with uniform and goal samples."""

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeGNNScorer,
                 uniform_mix: float = 0.2, goal_bias: float = 0.05, candidates: int = 16,
                 temperature: float = 1.0) -> None:
        if int(candidates) < 1 or not temperature > 0:
            raise ValueError(f"candidates must be >= 1 and temperature > 0, got {candidates}, {temperature}")
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.periodic.numpy())
        self.model = model.eval()
        self.engine = IncrementalTreeScorer(model)
        self.candidates, self.temperature = int(candidates), float(temperature)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        if hasattr(self, "engine"):
            self.engine.clear()

    def model_sample(self, obs: Mapping) -> np.ndarray:
        e = self.engine
        e.ingest(obs)
        active = int(np.asarray(obs["active_tree"]).reshape(-1)[0])
        cands = self.rng.uniform(self._low64, self._high64, size=(self.candidates, e.d))
        logits = e.logits(cands, e.nearest(cands, active)) / self.temperature
        p = np.exp(logits - logits.max())
        c = np.cumsum(p)
        i = min(int(np.searchsorted(c, self.rng.random() * c[-1], side="right")), self.candidates - 1)
        return cands[i]

    def _stateless_act(self, obs: Mapping) -> np.ndarray:
        self.engine.clear()
        return self.act(obs)


def reference_logits(model: TreeGNNScorer, obs: Mapping, samples: np.ndarray) -> torch.Tensor:
    """The torch model's scores of candidate ``samples`` at one padded observation (tests compare
    the incremental engine against this)."""
    n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
    d = model.state_dim
    nodes = torch.as_tensor(np.asarray(obs["nodes"][:n]), dtype=torch.float32)
    feats = torch.as_tensor(np.asarray(obs["node_features"][:n]), dtype=torch.float32)
    parent = torch.as_tensor(np.asarray(obs["parent"][:n])).long()
    goal = torch.as_tensor(np.asarray(obs["goal"]), dtype=torch.float32)
    s = torch.as_tensor(np.asarray(samples), dtype=torch.float32)
    with torch.no_grad():
        knn = model.causal_knn(nodes, feats[:, 2 * d].long())
        near = model.nearest(s, nodes)
        return model(nodes, feats, parent, knn, goal, near, torch.full_like(near, n), s)


__all__ = ["IncrementalTreeScorer", "TreeScorerSampler", "reference_logits"]
