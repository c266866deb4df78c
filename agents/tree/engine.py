"""Incremental inference of the causal tree models (numpy, and compiled functions), one new tree
node at a time.

A causal GNN embeds a node from older nodes only, so a node's embedding is fixed the moment it
is inserted. The engines keep per-episode caches: each new observation row is embedded once
(its causal k-NN found against the cached states of its tree, the message-passing layers run
from the cached terms of earlier nodes), and what a sample needs is kept up to date in place
(the GNN's per-tree embedding sums; the scorer's frontier sums). No graph is rebuilt and no
earlier node is re-run. The math is the torch model's, in float64
(``tests/test_tree_engine.py`` compares offsets, log-sigmas, mixture weights, contexts and
scores with the torch model's to 1e-5 on trees of a few hundred nodes).

* :class:`IncrementalTreeGNN` mirrors :class:`agents.tree.models.TreeGNN` (the ``gnn``
  node mixture and the GNN-CVAE's tree context); the new nodes' embeddings, the context and the
  mixture are compiled functions of :mod:`agents.tree.compiled` (numba);
* :class:`IncrementalTreeScorer` mirrors :class:`agents.tree.scorer.TreeGNNScorer`; its
  per-node work (depth, input MLP, causal k-NN, message passing, frontier sums) is one compiled
  call too (:func:`agents.tree.compiled.scorer_embed_rows`), and so is its candidate head
  (:meth:`~IncrementalTreeScorer.candidate_logits`; :meth:`~IncrementalTreeScorer.logits` and
  :meth:`~IncrementalTreeScorer.nearest` are its numpy oracle).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from agents.tree.compiled import (
    _UNTRAINED_TREE,
    PACKED_WEIGHTS,
    announce_compilation,
    context_after_rows,
    embed_rows,
    mixture_after_rows,
    mixtures_after_rows,
    node_mixture,
    pack_weights,
    scorer_candidate_logits,
    scorer_embed_rows,
    tree_context,
)
from agents.nn.twins import linears, mlp, norms_of, vector, wrap_periodic
from gnn_mp_envs.core.nearest import IndexArrays, NearestIndex
from agents.tree.models import TreeGNN
from agents.tree.scorer import EDGE_TYPES, TreeGNNScorer


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


#: What :func:`announce_compilation` names for the GNN's compiled forwards.
GNN_LOOP = "the tree GNN's per-node loop"


class IncrementalTreeGNN(_Engine):
    """Numpy inference of a :class:`TreeGNN` that embeds each new tree node once."""

    node_arrays = ("states", "tree_id", "keys", "offsets", "log_sigma")
    layered_arrays = ("sender",)

    def __init__(self, model: TreeGNN, capacity: int = 1024, *, heads: bool = True) -> None:
        """``heads`` false: the node keys, offsets and log-sigmas are not computed (a sampler that
        reads only :meth:`context`, the GNN-CVAE), and :meth:`mixture` is unavailable."""
        m = model.eval()
        self.model = m
        self.heads = bool(heads)
        self.H, self.L, self.k, self.trees = m.hidden_channels, m.num_layers, m.knn, m.num_trees
        self.center, self.scale = vector(m.state_center), vector(m.state_scale)
        self.feature_scale, self.step = vector(m.feature_scale), vector(m.step_scale)
        self.periodic = m.periodic.numpy().copy()
        (iw1, ib1), (iw2, ib2) = linears(m.input)
        H = self.H
        # Per layer, stacked for the compiled embedding: each message MLP's first layer split into its
        # sender part W_h (cached per node: W_h h_j) and its relative-position part W_x / step; its second
        # layer enters the update MLP only through the update's first layer, so the two are fused per
        # message (U_p = uw1[H:2H], U_k = uw1[2H:]: m U = h' (W_2 U) + b_2 U); the update MLP's h block
        # and second layer; the LayerNorm.
        first = [[linears(conv.net) for conv in (conv_p, conv_k)] for conv_p, conv_k in zip(m.parent_convs, m.knn_convs)]
        updates = [linears(u) for u in m.updates]
        stack = lambda pick: np.ascontiguousarray(np.stack([pick(layer) for layer in range(self.L)]))   # noqa: E731
        self.w_sender = stack(lambda l: np.stack([first[l][0][0][0][:H], first[l][1][0][0][:H]]))
        self.wpx, self.bp1 = stack(lambda l: first[l][0][0][0][H:] / self.step[:, None]), stack(lambda l: first[l][0][0][1])
        self.wkx, self.bk1 = stack(lambda l: first[l][1][0][0][H:] / self.step[:, None]), stack(lambda l: first[l][1][0][1])
        block = lambda l, e: updates[l][0][0][(1 + e) * H:(2 + e) * H]      # noqa: E731  (e: 0 parent, 1 k-NN)
        self.wpu = stack(lambda l: first[l][0][1][0] @ block(l, 0))
        self.bpu = stack(lambda l: first[l][0][1][1] @ block(l, 0))
        self.wku = stack(lambda l: first[l][1][1][0] @ block(l, 1))
        self.bku = stack(lambda l: first[l][1][1][1] @ block(l, 1))
        self.uw1, self.ub1 = stack(lambda l: updates[l][0][0][:H]), stack(lambda l: updates[l][0][1])
        self.uw2, self.ub2 = stack(lambda l: updates[l][1][0]), stack(lambda l: updates[l][1][1])
        norms = norms_of(m.norms)
        self.norm_g, self.norm_b = stack(lambda l: norms[l][0]), stack(lambda l: norms[l][1])
        self.norm_eps = np.array([norms[l][2] for l in range(self.L)], dtype=np.float64)
        self.query = linears(m.query)
        self.key = linears(m.key)[0]
        self.node_head = linears(m.node_head)[0]
        self.query_shift = linears(m.query_shift)[0]
        self.use_parent, self.use_knn, self.use_context = m.use_parent, m.use_knn, m.use_context
        self.relative_inputs = m.relative_inputs
        #: What the compiled per-node loop reads besides the caches, in its argument order (built once).
        self.weights = (self.periodic, self.step, self.center, self.scale, self.feature_scale, bool(self.relative_inputs),
                        int(self.k) if self.use_knn else 0, bool(self.use_parent), self.heads, iw1, ib1, iw2, ib2,
                        self.w_sender, self.wpx, self.bp1, self.wpu, self.bpu, self.wkx, self.bk1, self.wku, self.bku,
                        self.uw1, self.ub1, self.uw2, self.ub2, self.norm_g, self.norm_b, self.norm_eps, *self.key,
                        *self.node_head)
        #: The same weights packed for :meth:`grown_mixture`'s one compiled call (a short dispatch): the
        #: embedding's arrays in their argument order (without its flags), then the heads', the
        #: query's and the shift's (``PACKED_WEIGHTS``).
        embedding = self.weights[1:5] + self.weights[9:29]
        (qw1, qb1), (qw2, qb2) = self.query
        packed = dict(zip(PACKED_WEIGHTS, (*embedding, *self.key, *self.node_head, qw1, qb1, qw2, qb2,
                                           *self.query_shift), strict=True))
        self._flat, self._layout = pack_weights(packed)
        self._flags = np.array([bool(self.relative_inputs), int(self.k) if self.use_knn else 0, bool(self.use_parent),
                                self.heads, bool(self.use_context)], dtype=np.int64)
        super().__init__(m.state_dim, capacity)

    def _allocate(self, capacity: int) -> None:
        d, H, L, T = self.d, self.H, self.L, self.trees
        self.capacity = capacity
        self.states = np.zeros((capacity, d))
        self.tree_id = np.zeros(capacity, dtype=np.int64)
        self.sender = np.zeros((L, 2, capacity, H))        # cached W_h h_j per layer and edge type (parent, k-NN)
        self.keys = np.zeros((capacity, H))
        self.offsets = np.zeros((capacity, T, d))
        self.log_sigma = np.zeros((capacity, T, d))
        # the causal k-NN's k-d trees, one per GNN tree (the planner's bucketed index; its weights, 1 / step,
        # only choose the splits); growing keeps the nodes indexed so far
        index = NearestIndex(capacity, T, 1.0 / self.step, self.periodic)
        if hasattr(self, "kd_index"):
            index.take(self.kd_index)
        self.kd_index = index

    @property
    def kd(self) -> IndexArrays:
        """The k-d trees' arrays as the compiled k-NN takes them (``_kd_causal_knn``)."""
        return self.kd_index.arrays

    def clear(self) -> None:
        super().clear()
        self.sums = np.zeros((self.trees, self.H))
        self.counts = np.zeros(self.trees)
        self.kd_index.clear()
        self._ends_key = None

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
        # everything per new node, one node after the other (compiled): input MLP, causal k-NN,
        # message-passing layers, node heads, the per-tree embedding sums
        embed_rows(i0, x, feats, tid, parent, self.states, self.tree_id, self.sender, self.keys, self.offsets,
                   self.log_sigma, self.sums, self.counts, self.kd, *self.weights)
        self.n = n
        return n

    def _check_trees(self, actives) -> None:
        """Refuse a tree this model has no slot for before a compiled forward embeds anything (the forward
        would embed the new rows, then stop at the context: the rows would be embedded twice by a retry)."""
        for active in actives:
            if not 0 <= int(active) < self.trees:
                raise ValueError(_UNTRAINED_TREE)

    def _ends_of(self, start: np.ndarray, goal: np.ndarray, key: bytes) -> np.ndarray:
        """The context's start-and-goal inputs, kept per problem (``key``: its start and goal bytes)."""
        if key != self._ends_key:
            start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
            ends = ([wrap_periodic(goal - start, self.periodic) / self.scale] if self.relative_inputs
                    else [(start - self.center) / self.scale, (goal - self.center) / self.scale])
            self._ends, self._ends_key = np.concatenate(ends).astype(np.float64), key
        return self._ends

    def context(self, start: np.ndarray, goal: np.ndarray, active: int) -> np.ndarray:
        """The tree context ``q`` ``(H,)`` of the ingested tree (``TreeGNN.context``; compiled, its
        start-and-goal inputs kept per problem)."""
        ends = self._ends_of(start, goal, start.tobytes() + goal.tobytes())
        (w1, b1), (w2, b2) = self.query
        return tree_context(ends, int(active), self.sums, self.counts, bool(self.use_context), w1, b1, w2, b2)

    def grown_context(self, obs: Mapping[str, np.ndarray], rows: tuple[int, int], active: int) -> np.ndarray:
        """:meth:`ingest` and :meth:`context` in one compiled call (the GNN-CVAE's forward up to its
        decoder; the same floats). ``rows`` is what :meth:`new_rows` just returned for ``obs``."""
        i0, n = rows
        self._check_trees((active,))
        ends = self._ends_of(obs["start"], obs["goal"], self._problem_key)
        announce_compilation(context_after_rows, GNN_LOOP)
        q = context_after_rows(i0, n, obs["nodes"], obs["node_features"], obs["parent"], self.states, self.tree_id,
                               self.sender, self.keys, self.offsets, self.log_sigma, self.sums, self.counts, self.kd,
                               self.periodic, self._flags, self._flat, self._layout, ends, int(active))
        self.n = n
        return q

    def grown_mixture(self, obs: Mapping[str, np.ndarray], rows: tuple[int, int], active: int,
                      temperature: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`ingest`, :meth:`context` and :meth:`node_mixture` in one compiled call (the GNN
        sampler's forward; the same floats): probabilities, their running sums and the shift.
        ``rows`` is what :meth:`new_rows` just returned for ``obs``."""
        if not self.heads:
            raise RuntimeError("this engine was built with heads=False (no node keys): it gives the context only")
        i0, n = rows
        self._check_trees((active,))
        start, goal = obs["start"], obs["goal"]
        ends = self._ends_of(start, goal, self._problem_key)
        announce_compilation(mixture_after_rows, GNN_LOOP)
        out = mixture_after_rows(i0, n, obs["nodes"], obs["node_features"], obs["parent"], self.states, self.tree_id,
                                 self.sender, self.keys, self.offsets, self.log_sigma, self.sums, self.counts, self.kd,
                                 self.periodic, self._flags, self._flat, self._layout, ends, int(active),
                                 1.0 / float(temperature))
        self.n = n
        return out

    def grown_mixtures(self, obs: Mapping[str, np.ndarray], rows: tuple[int, int], actives: np.ndarray,
                       temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`grown_mixture` of several trees from one embedding of the new rows, in one compiled call (a
        batch's forward): running sums ``(len(actives), n)`` and shifts ``(len(actives), d)``, row ``a`` the
        floats :meth:`grown_mixture` gives for tree ``actives[a]``."""
        if not self.heads:
            raise RuntimeError("this engine was built with heads=False (no node keys): it gives the context only")
        i0, n = rows
        actives = np.asarray(actives, dtype=np.int64)
        self._check_trees(actives.tolist())
        ends = self._ends_of(obs["start"], obs["goal"], self._problem_key)
        announce_compilation(mixtures_after_rows, GNN_LOOP)
        out = mixtures_after_rows(i0, n, obs["nodes"], obs["node_features"], obs["parent"], self.states, self.tree_id,
                                  self.sender, self.keys, self.offsets, self.log_sigma, self.sums, self.counts, self.kd,
                                  self.periodic, self._flags, self._flat, self._layout, ends,
                                  actives, 1.0 / float(temperature))
        self.n = n
        return out

    def mixture(self, q: np.ndarray, active: int, temperature: float) -> tuple[np.ndarray, np.ndarray]:
        """Node probabilities ``(n,)`` and the component shift ``(d,)`` at the current tree."""
        p, _, shift = self.node_mixture(q, active, temperature)
        return p, shift

    def node_mixture(self, q: np.ndarray, active: int, temperature: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`mixture`'s probabilities, their running sums (what a draw searches) and the shift."""
        if not self.heads:
            raise RuntimeError("this engine was built with heads=False (no node keys): it gives the context only")
        w, b = self.query_shift
        q = np.ascontiguousarray(q, dtype=np.float64)     # the compiled product takes float64 rows only
        return node_mixture(self.keys[:self.n], q, int(active), 1.0 / float(temperature), w, b, self.step)


class IncrementalTreeScorer(_Engine):
    """Inference of a :class:`TreeGNNScorer` that embeds each new tree node once (compiled) and keeps
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
        stack = lambda layers, i, j: np.ascontiguousarray(np.stack([mlp_[i][j] for mlp_ in layers]))   # noqa: E731
        (iw1, ib1), (iw2, ib2) = self.input
        (fw1, fb1), (fw2, fb2) = self.frontier_net
        #: What the compiled per-node call reads besides the caches, in its argument order (built once).
        self._periodic_mask, self._angle_cols = self.periodic.astype(bool), self.angle_cols.astype(np.int64)
        self._compiled_weights = (
            self._periodic_mask, self.weights, self._angle_cols, self.center, self.scale,
            self.feature_scale, self.step, float(self.depth_scale), int(self.k), iw1, ib1, iw2, ib2,
            *(stack(convs, i, j) for convs in (self.parent_convs, self.knn_convs, self.updates)
              for i, j in ((0, 0), (0, 1), (1, 0), (1, 1))),
            np.stack([g for g, _, _ in self.norms]), np.stack([b for _, b, _ in self.norms]),
            np.array([eps for _, _, eps in self.norms], dtype=np.float64), fw1, fb1, fw2, fb2)
        super().__init__(m.state_dim, capacity)
        announce_compilation(scorer_embed_rows, "the tree scorer's per-node loop")

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
        # everything per new node in one compiled call: depth, input MLP, causal k-NN, message passing,
        # the frontier sums of the new edges
        scorer_embed_rows(i0, x, feats, tid, parent, self.goal, self.states, self.tree_id, self.depth, self.h, self.front,
                          *self._compiled_weights)
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

    def candidate_logits(self, samples: np.ndarray, active: int = 0) -> np.ndarray:
        """:meth:`logits` of ``samples`` at their :meth:`nearest` nodes of tree ``active``, in one
        compiled call (:func:`~agents.tree.compiled.scorer_candidate_logits`; a head of another depth
        than the trained scorers' three layers takes the numpy path)."""
        if len(self.head) != 3:
            return self.logits(samples, self.nearest(samples, active))
        (w1, b1), (w2, b2), (w3, b3) = self.head
        return scorer_candidate_logits(np.ascontiguousarray(samples, dtype=np.float64), self.n, int(active),
                                       self.multi_tree, self.states, self.tree_id, self.h[self.L], self.front,
                                       self.goal, self._periodic_mask, self.weights, self.unit, self.scale,
                                       self.center, self._angle_cols, w1, b1, w2, b2, w3, b3)

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
