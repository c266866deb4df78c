"""Incremental numpy inference of the causal tree models, one new tree node at a time.

A causal GNN embeds a node from older nodes only, so a node's embedding is fixed the moment it
is inserted. The engines keep per-episode caches: each new observation row is embedded once
(its causal k-NN found against the cached states of its tree, the message-passing layers run
from the cached terms of earlier nodes), and what a sample needs is kept up to date in place
(the GNN's per-tree embedding sums; the scorer's frontier sums). No graph is rebuilt and no
earlier node is re-run. The math is the torch model's, in float64
(``tests/test_tree_engine.py`` compares offsets, log-sigmas, mixture weights, contexts and
scores with the torch model's to 1e-5 on trees of a few hundred nodes).

* :class:`IncrementalTreeGNN` mirrors :class:`agents.tree.models.TreeGNN` (the ``gnn``
  node mixture and the GNN-CVAE's tree context);
* :class:`IncrementalTreeScorer` mirrors :class:`agents.tree.scorer.TreeGNNScorer`.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from agents.tree.kernels import (gelu, layer_norm, linears, mlp, nearest_k, norms_of, scaled_sq_dist, vector,
                                wrap_periodic)
from agents.tree.models import TreeGNN
from agents.tree.scorer import EDGE_TYPES, TreeGNNScorer

_add_reduce = np.add.reduce
#: ``a @ b`` for 1-D and 2-D operands: the same BLAS call (bit for bit) with less overhead; 3-D products stay ``@``
_dot = np.dot


class _Engine:
    """Per-episode node caches: capacity that grows by doubling, and a new episode recognised
    by a smaller tree or another start/goal (the caches are then cleared)."""

    #: Names of the per-node arrays: node axis first, or (``layered``) second to last.
    node_arrays: tuple[str, ...] = ()
    layered_arrays: tuple[str, ...] = ()

    def __init__(self, state_dim: int, capacity: int) -> None:
        self.d = int(state_dim)
        self._allocate(capacity)
        self.clear()

    def _allocate(self, capacity: int) -> None:
        raise NotImplementedError

    def _grow(self, n: int) -> None:
        if n <= self.capacity:
            return
        old = {name: getattr(self, name) for name in (*self.node_arrays, *self.layered_arrays)}
        cap = self.capacity
        self._allocate(max(n, 2 * cap))
        for name in self.node_arrays:
            getattr(self, name)[:cap] = old[name]
        for name in self.layered_arrays:
            getattr(self, name)[..., :cap, :] = old[name]

    def clear(self) -> None:
        self.n = 0
        self.problem = None
        self._problem_key = b""
        #: Counts the clears: ``(generation, n)`` names the ingested tree (what a cached result is of).
        self.generation = getattr(self, "generation", -1) + 1

    def same_tree(self, obs: Mapping[str, np.ndarray]) -> bool:
        """Is the observation's tree the cached one grown further? Rows are append-only, so the
        last cached node must still be there: another tree of the same problem and size (a second
        env fed to the same sampler) differs in it."""
        if self.n == 0:
            return True
        return obs["nodes"][self.n - 1].tolist() == self.states[self.n - 1].tolist()

    def new_rows(self, obs: Mapping[str, np.ndarray]) -> tuple[int, int]:
        """``(i0, n)``: the observation's rows ``i0..n-1`` are new (a new episode clears the caches first)."""
        n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
        start, goal = np.asarray(obs["start"]), np.asarray(obs["goal"])
        key = start.tobytes() + goal.tobytes()          # the episode's start and goal, cheaply compared
        if n < self.n or self.problem is None or key != self._problem_key or not self.same_tree(obs):
            self.clear()
            self.problem = np.concatenate([start.astype(np.float64), goal.astype(np.float64)])
            self._problem_key = key
        if n > self.n:
            self._grow(n)
        return self.n, n


class IncrementalTreeGNN(_Engine):
    """Numpy inference of a :class:`TreeGNN` that embeds each new tree node once."""

    node_arrays = ("states", "tree_id", "keys", "offsets", "log_sigma")
    layered_arrays = ("sender",)

    def __init__(self, model: TreeGNN, capacity: int = 1024) -> None:
        m = model.eval()
        self.model = m
        self.H, self.L, self.k, self.trees = m.hidden_channels, m.num_layers, m.knn, m.num_trees
        self.center, self.scale = vector(m.state_center), vector(m.state_scale)
        self.feature_scale, self.step = vector(m.feature_scale), vector(m.step_scale)
        self.periodic = m.periodic.numpy().copy()
        self.input = linears(m.input)
        H = self.H
        # First message layer split into sender / receiver parts: W [h_j, (x_j - x_i)/s] + b.
        self.messages = []
        for conv_p, conv_k in zip(m.parent_convs, m.knn_convs):
            split = []
            for conv in (conv_p, conv_k):
                (w1, b1), (w2, b2) = linears(conv.net)
                split.append((w1[:H], w1[H:] / self.step[:, None], b1, w2, b2))
            self.messages.append(split)
        # both edge types' sender weights side by side: one product per layer for the two
        self.sender_weights = [(np.concatenate([p[0], k[0]], 1), np.concatenate([p[1], k[1]], 1))
                               for p, k in self.messages]
        self.updates = [linears(u) for u in m.updates]
        self.norms = norms_of(m.norms)
        self.query = linears(m.query)
        self.key = linears(m.key)[0]
        self.node_head = linears(m.node_head)[0]
        self.query_shift = linears(m.query_shift)[0]
        self.use_parent, self.use_knn, self.use_context = m.use_parent, m.use_knn, m.use_context
        self.relative_inputs = m.relative_inputs
        super().__init__(m.state_dim, capacity)

    def _allocate(self, capacity: int) -> None:
        d, H, L, T = self.d, self.H, self.L, self.trees
        self.capacity = capacity
        self.states = np.zeros((capacity, d))
        self.tree_id = np.zeros(capacity, dtype=np.int64)
        self.sender = np.zeros((L, 2, capacity, H))        # cached W_h h_j + W_x x_j / s per layer, edge type
        self.keys = np.zeros((capacity, H))
        self.offsets = np.zeros((capacity, T, d))
        self.log_sigma = np.zeros((capacity, T, d))

    def clear(self) -> None:
        super().clear()
        self.sums = np.zeros((self.trees, self.H))
        self.counts = np.zeros(self.trees)

    def ingest(self, obs: Mapping[str, np.ndarray]) -> int:
        """Embed the observation's rows not seen yet (a new episode restarts the cache)."""
        i0, n = self.new_rows(obs)
        if n == i0:
            return n
        d, H = self.d, self.H
        x = np.asarray(obs["nodes"][i0:n], dtype=np.float64)
        feats = np.asarray(obs["node_features"][i0:n], dtype=np.float64)
        tid = feats[:, 2 * d].astype(np.int64)
        parent = np.asarray(obs["parent"][i0:n]).astype(np.int64)
        self.states[i0:n], self.tree_id[i0:n] = x, tid
        h = mlp(self.input, feats / self.feature_scale if self.relative_inputs else
                np.concatenate([feats / self.feature_scale, (x - self.center) / self.scale], -1))
        B = n - i0
        # causal k-NN: earlier nodes of the same tree, distances in step units, angles wrapped
        if self.k:
            dist = scaled_sq_dist(self.states[:n], x, self.periodic, self.step)
            later = np.arange(n)[None, :] >= np.arange(i0, n)[:, None]
            dist[later | (self.tree_id[None, :n] != tid[:, None])] = np.inf
            k = min(self.k, n)
            near = nearest_k(dist, k)                                   # ties to the earlier node, as the model
            near_ok = np.isfinite(dist[np.arange(B)[:, None], near])
        has_parent = parent >= 0
        all_parent = bool(has_parent.all())
        par = parent if all_parent else np.where(has_parent, parent, 0)
        any_parent = self.use_parent and (all_parent or bool(has_parent.any()))
        if any_parent:
            sp = self.states[par]                                                    # (B, d)
            wrapped_p = wrap_periodic(sp - x, self.periodic)
        if self.use_knn and self.k:
            sj = self.states[near]                                                   # (B, k, d)
            rel = sj - x[:, None]
            wrapped_k = wrap_periodic(rel, self.periodic) - rel
            count = _add_reduce(near_ok, 1, keepdims=True, dtype=np.int64)
            ok = near_ok[..., None]
            all_near = bool(near_ok.all())
        # (each product below is computed once and reused: the same values as before, fewer calls)
        for layer in range(self.L):
            (_, wpx, bp1, wp2, bp2), (_, wkx, bk1, wk2, bk2) = self.messages[layer]   # sender parts: below
            wh, wx = self.sender_weights[layer]
            xs = _dot(x, wx)
            xp, xk = xs[:, :H], xs[:, H:]
            self.sender[layer, :, i0:n] = (_dot(h, wh) + xs).reshape(B, 2, H).transpose(1, 0, 2)
            mp = np.zeros((B, H))
            if any_parent:
                rel_p = _dot(wrapped_p, wpx) - (_dot(sp, wpx) - xp)
                pre = self.sender[layer, 0, par] - xp + rel_p + bp1
                mp = _dot(gelu(pre), wp2) + bp2
                if not all_parent:
                    mp = np.where(has_parent[:, None], mp, 0.0)
            mk = np.zeros((B, H))
            if self.use_knn and self.k:
                rel_k = wrapped_k @ wkx
                pre = self.sender[layer, 1][near] - xk[:, None] + rel_k + bk1
                g = gelu(pre)
                if all_near:        # every neighbour real: the mask and the guards select everything
                    mk = _dot(_add_reduce(g, 1) / count, wk2) + bk2
                else:
                    mk = np.where(count > 0, _dot(_add_reduce(g * ok, 1) / np.maximum(count, 1), wk2) + bk2, 0.0)
            h = layer_norm(self.norms[layer], h + mlp(self.updates[layer], np.concatenate([h, mp, mk], -1)))
        w, b = self.key
        self.keys[i0:n] = _dot(h, w) + b
        w, b = self.node_head
        o = (_dot(h, w) + b).reshape(B, self.trees, 2 * d)
        self.offsets[i0:n] = o[..., :d] * self.step
        self.log_sigma[i0:n] = np.minimum(np.maximum(o[..., d:], -4.0), 1.0)     # np.clip, without its wrapper
        for t, row in zip(tid.tolist(), h):      # np.add.at(sums, tid, h), in the same order
            self.sums[t] += row
            self.counts[t] += 1.0
        self.n = n
        return n

    def context(self, start: np.ndarray, goal: np.ndarray, active: int) -> np.ndarray:
        """The tree context ``q`` ``(H,)`` of the ingested tree (``TreeGNN.context``)."""
        means = self.sums / np.maximum(self.counts, 1.0)[:, None]
        if not self.use_context:
            means = means * 0.0
        ends = ([wrap_periodic(goal - start, self.periodic) / self.scale] if self.relative_inputs
                else [(start - self.center) / self.scale, (goal - self.center) / self.scale])
        parts = [*ends, np.eye(self.trees)[active], means.reshape(-1), np.log1p(self.counts) / 5.0]
        return mlp(self.query, np.concatenate(parts))

    def mixture(self, q: np.ndarray, active: int, temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """Node probabilities ``(n,)`` and the component shift ``(d,)`` at the current tree."""
        logits = _dot(self.keys[:self.n], q) / math.sqrt(self.H) / temperature
        p = np.exp(logits - logits.max())
        w, b = self.query_shift
        shift = (_dot(q, w) + b).reshape(self.trees, self.d)[active] * self.step
        return p / p.sum(), shift


class IncrementalTreeScorer(_Engine):
    """Numpy inference of a :class:`TreeGNNScorer` that embeds each new tree node once and keeps
    every node's frontier sum and counts up to date (``O(knn)`` per insertion)."""

    node_arrays = ("states", "tree_id", "depth", "front")
    layered_arrays = ("h",)

    def __init__(self, model: TreeGNNScorer, capacity: int = 1024) -> None:
        m = model.eval()
        self.H, self.L, self.k = m.hidden_channels, m.num_layers, m.knn
        self.center, self.scale = vector(m.state_center), vector(m.state_scale)
        self.feature_scale, self.step = vector(m.feature_scale), vector(m.step_scale)
        self.weights = vector(m.metric_weights)
        self.periodic = m.periodic.numpy().copy()
        self.angle_cols = np.flatnonzero(self.periodic)
        self.depth_scale = m.depth_scale
        self.unit = float(np.linalg.norm(self.weights * self.step))
        self.input = linears(m.input)
        self.parent_convs = [linears(c.net) for c in m.parent_convs]
        self.knn_convs = [linears(c.net) for c in m.knn_convs]
        self.updates = [linears(u) for u in m.updates]
        self.norms = norms_of(m.norms)
        self.frontier_net = linears(m.frontier.net)
        self.head = linears(m.head)
        super().__init__(m.state_dim, capacity)

    def _allocate(self, capacity: int) -> None:
        self.capacity = capacity
        self.states = np.zeros((capacity, self.d))
        self.tree_id = np.zeros(capacity, dtype=np.int64)
        self.depth = np.zeros(capacity)
        self.h = np.zeros((self.L + 1, capacity, self.H))          # embeddings after each layer
        self.front = np.zeros((capacity, self.H + EDGE_TYPES))     # frontier sums and counts

    def clear(self) -> None:
        super().clear()
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
        i0, n = self.new_rows(obs)
        if self.goal is None:
            self.goal = self.problem[self.d:]
        if n == i0:
            return n
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
        h = mlp(self.input, inputs)
        self.h[0, i0:n] = h
        # causal k-NN under the planner's metric: earlier nodes of the same tree, ties to the earlier node
        rows = np.arange(i0, n)
        if self.k:
            dist = self._sq_dist(x, self.states[:n])
            dist[(np.arange(n)[None, :] >= rows[:, None]) | (self.tree_id[None, :n] != tid[:, None])] = np.inf
            near = nearest_k(dist, min(self.k, n))
            near_ok = np.isfinite(dist[np.arange(B)[:, None], near])
        else:
            near, near_ok = np.zeros((B, 0), np.int64), np.zeros((B, 0), bool)
        has_parent = parent >= 0
        par = np.where(has_parent, parent, 0)
        rel_p = wrap_periodic(self.states[par] - x, self.periodic) / self.step                   # (B, d)
        rel_k = wrap_periodic(self.states[near] - x[:, None], self.periodic) / self.step          # (B, k, d)
        count = near_ok.sum(1, keepdims=True)
        for layer in range(self.L):
            mp = mlp(self.parent_convs[layer], np.concatenate([self.h[layer, par], rel_p], -1))
            mp = np.where(has_parent[:, None], mp, 0.0)
            msg = mlp(self.knn_convs[layer], np.concatenate([self.h[layer][near], rel_k], -1))
            mk = np.where(count > 0, (msg * near_ok[..., None]).sum(1) / np.maximum(count, 1), 0.0)
            h = layer_norm(self.norms[layer], h + mlp(self.updates[layer], np.concatenate([h, mp, mk], -1)))
            self.h[layer + 1, i0:n] = h
        # frontier: every new row is a newer node pointing at its parent (type 0) and its nearest (type 1)
        receivers = np.concatenate([par[has_parent], near[near_ok]])
        senders = np.concatenate([np.flatnonzero(has_parent), np.nonzero(near_ok)[0]])
        etype = np.concatenate([np.zeros(int(has_parent.sum()), np.int64), np.ones(int(near_ok.sum()), np.int64)])
        if len(receivers):
            onehot = np.eye(EDGE_TYPES)[etype]
            rel = wrap_periodic(x[senders] - self.states[receivers], self.periodic) / self.step
            phi = mlp(self.frontier_net, np.concatenate([h[senders], rel, onehot], -1))
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
        rel = wrap_periodic(samples - xn, self.periodic)
        to_goal = wrap_periodic(self.goal - samples, self.periodic)
        dist = np.sqrt(((self.weights * rel) ** 2).sum(-1, keepdims=True)) / self.unit
        cand = np.concatenate([rel / self.scale, dist, to_goal / self.scale, (samples - self.center) / self.scale,
                               *self._angles(samples), *self._angles(to_goal)], -1)
        front = self.front[near]
        total, counts = front[:, :self.H], front[:, self.H:]
        z = np.concatenate([self.h[self.L, near], total / (1 + counts.sum(-1, keepdims=True)), np.log1p(counts), cand],
                           -1)
        return mlp(self.head, z)[:, 0]


__all__ = ["IncrementalTreeGNN", "IncrementalTreeScorer"]
