"""Candidate selection: the RL action as a choice among ``K`` candidate samples (numpy only).

Zhang, Huh & Lee (2018) let an RL policy accept or reject uniform samples; here each planner
iteration offers ``K`` candidate states and the policy picks one (``spaces.Discrete(K)``). The
candidates and their features come from :class:`CandidateSet`, the one implementation behind
the training env (:class:`CandidatePickWrapper`, the ``GNNMP/*-RLPick-v0`` ids) and the
sampler that runs a trained picker in the benchmark (``agents.rl.sampler.PickSampler``), so a
policy sees the same inputs in both.

**Candidates** (rows in this order; the kind of row ``k`` is fixed, see :data:`CANDIDATE_KINDS`):

* row 0, ``target``: the active tree's target (the goal; BiRRT's goal tree: the start);
* row 1, ``near-target``: the target plus a Gaussian of ``target_scale`` times the box's span;
* row 2, ``newest``: the active tree's newest node plus a Gaussian step (continue growing);
* row 3, ``greedy``: the active tree's node nearest its target plus a Gaussian step;
* rows 4..K-1, ``uniform``: uniform states over the bounds.

The Gaussian's standard deviation is ``local_scale`` extensions per coordinate
(``step_scale / metric_weight``); periodic coordinates are wrapped, every row clipped to the bounds.

**Features** (``(K, F)`` float32, ``F = 13 + 4 d``), all relative to the tree: for candidate
``c`` with nearest active-tree node ``n`` (the node the planner extends, under the planner's
metric ``|| w * wrap(a - b) ||``), target ``g``, ``D = dist(start, goal)`` and the tree's best
node ``b`` (nearest ``g``):

=====  ==========================================================================
cols   meaning
=====  ==========================================================================
0-4    one-hot kind (target, near-target, newest, greedy, uniform)
5      ``log1p(dist(c, n) / step)``: how far the extension reaches
6      ``dist(c, g) / D``
7      ``dist(n, g) / D``
8      ``(dist(n, g) - dist(b, g)) / D``: how much worse ``n`` is than the tree's best node
9      ``log1p(age of n)`` in nodes added since it (0: the newest)
10     ``log1p(children of n)``: extensions that succeeded from ``n``
11     ``log1p(failures of n)``: extensions from ``n`` that were blocked (the planner's history)
12     BiRRT: ``dist(c, nearest node of the other tree) / D``; RRT: 0
13..   ``c`` in ``[-1, 1]`` (d), ``n`` in ``[-1, 1]`` (d), ``wrap(c - n) / step`` clipped to
       ``[-4, 4]`` (d), ``wrap(g - n) / span`` (d)
last   with a ``prior``: its logit of ``c`` (one more column, ``F = 14 + 4 d``)
=====  ==========================================================================

**A prior** (``CandidateSet(..., prior=...)``, :class:`CandidatePrior`): any object that scores the
step's candidates from the full observation, e.g. ``agents.tree.prior.ScorerPrior``, the supervised
GNN sample scorer read incrementally over the whole tree (a policy whose logits start as the
prior's is a warm start that PPO refines; ``docs/rl.md``). This module only calls it, so the
environments stay free of torch.

The tree statistics (children, failures, best node) are kept incrementally per episode; a
failure is counted when the sample actually sent (:meth:`CandidateSet.record`, the mixture's
uniform draws included) did not grow the tree. A new episode (another start or goal, or a tree
that shrank) clears them.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Protocol, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gnn_mp_envs.utils.compiled import jit

#: The kind of each candidate row: row 0 target, 1 near the target, 2 newest, 3 greedy, the rest uniform.
CANDIDATE_KINDS = ("target", "near-target", "newest", "greedy", "uniform")
#: Default number of candidates per step.
DEFAULT_CANDIDATES = 8
#: Default standard deviation of the local candidates, in extensions.
DEFAULT_LOCAL_SCALE = 1.0
#: Default standard deviation of the near-target candidate, as a fraction of the box's span.
DEFAULT_TARGET_SCALE = 0.1
#: Scalar feature columns before the per-dimension blocks.
SCALAR_FEATURES = len(CANDIDATE_KINDS) + 8


@jit
def _nearest_node(p, states, m, periodic, span, weights):
    """Row of ``states[:m]`` nearest ``p`` under the planner's metric and the distance, in the order
    of :meth:`CandidateSet._nearest`'s numpy operations (coordinate by coordinate), so bit for bit
    the same; the first of equal minima, as ``argmin``."""
    best, j = np.inf, 0
    for r in range(m):
        sq = 0.0
        for i in range(p.shape[0]):
            diff = p[i] - states[r, i]
            if periodic[i]:
                diff = abs(diff)
                diff = min(diff, span[i] - diff)
            if weights[i] != 1.0:
                diff *= weights[i]
            sq += diff * diff
        if sq < best:
            best, j = sq, r
    return j, np.sqrt(best)


@jit
def _difference(a, b, i, periodic, half, span):
    """``wrap(a - b)`` of coordinate ``i``: numpy's floored modulo, as :meth:`CandidateSet._difference`."""
    diff = a - b
    if periodic[i]:
        diff = (diff + half[i]) % span[i] - half[i]
    return diff


@jit
def _ingest_rows(first, parent, tree, states, targets, children, rows0, rows1, states0, states1, columns0,
                 columns1, to_target0, to_target1, size, best_dist, best_row, periodic, half, span, weights):
    """The tree statistics of new observation rows ``first..``: children counts, each node in its
    tree's lists (``*0``: tree 0, ``*1``: tree 1) with its distance to the tree's target (the metric
    of :meth:`CandidateSet._distance`, summed in its order), the node nearest the target (the first of
    equal distances)."""
    d = states.shape[1]
    for r in range(states.shape[0]):
        p = parent[r]
        if p >= 0:
            children[p] += 1
        t = tree[r]
        sq = 0.0
        for i in range(d):
            diff = _difference(states[r, i], targets[t, i], i, periodic, half, span)
            if weights[i] != 1.0:
                diff *= weights[i]
            sq += diff * diff
        dist = np.sqrt(sq)
        m = size[t]
        rows, tree_states, columns, to_target = (rows0, states0, columns0, to_target0) if t == 0 else \
            (rows1, states1, columns1, to_target1)
        rows[m] = first + r
        for i in range(d):
            tree_states[m, i] = states[r, i]
            columns[i, m] = states[r, i]
        to_target[m] = dist
        size[t] = m + 1
        if dist < best_dist[t]:
            best_dist[t], best_row[t] = dist, first + r


@jit
def _assemble(target, noise, uniform, newest, greedy, target_std, local_std, low, span, high, periodic, wraps):
    """The step's candidates from its draws, as :meth:`CandidateSet.propose` states them in numpy:
    rows target, near-target, newest + step, greedy + step, uniform; periodic coordinates wrapped
    (floored modulo), clipped to the box, rounded to float32."""
    K, d = uniform.shape[0] + 4, target.shape[0]
    cands = np.empty((K, d), np.float32)
    row = np.empty(d)
    for k in range(K):
        for i in range(d):
            if k == 0:
                x = target[i]
            elif k == 1:
                x = target[i] + noise[0, i] * target_std[i]
            elif k == 2:
                x = noise[1, i] * local_std[i] + newest[i]
            elif k == 3:
                x = noise[2, i] * local_std[i] + greedy[i]
            else:
                x = low[i] + span[i] * uniform[k - 4, i]
            if wraps and periodic[i]:
                x = (x - low[i]) % span[i] + low[i]
            row[i] = x
        for i in range(d):
            cands[k, i] = np.float32(min(max(row[i], low[i]), high[i]))
    return cands


@jit
def _features(cands, kinds, states, rows, to_target, m, other_states, other_m, target, n, best_dist, scale,
              step, children, failures, periodic, span, half, center, weights, out, near):
    """:meth:`CandidateSet.features` without the prior's column, compiled: ``out (K, F)`` float64 and
    each candidate's nearest active-tree row in ``near``."""
    K, d = cands.shape
    c = kinds.shape[1]
    s = c + 8
    for k in range(K):
        p = cands[k]
        j, reach = _nearest_node(p, states, m, periodic, span, weights)
        node = rows[j]
        near[k] = node
        for col in range(c):
            out[k, col] = kinds[k, col]
        out[k, c] = np.log1p(reach / step)
        sq = 0.0
        for i in range(d):
            diff = _difference(p[i], target[i], i, periodic, half, span)
            if weights[i] != 1.0:
                diff *= weights[i]
            sq += diff * diff
        out[k, c + 1] = np.sqrt(sq) / scale
        out[k, c + 2] = to_target[j] / scale
        out[k, c + 3] = (to_target[j] - best_dist) / scale
        out[k, c + 4] = np.log1p(float(n - 1 - node))
        out[k, c + 5] = np.log1p(float(children[node]))
        out[k, c + 6] = np.log1p(float(failures[node]))
        out[k, c + 7] = _nearest_node(p, other_states, other_m, periodic, span, weights)[1] / scale \
            if other_m > 0 else 0.0
        for i in range(d):
            out[k, s + i] = (p[i] - center[i]) / half[i]
            out[k, s + d + i] = (states[j, i] - center[i]) / half[i]
            out[k, s + 2 * d + i] = min(max(_difference(p[i], states[j, i], i, periodic, half, span) / step, -4.0),
                                        4.0)
            out[k, s + 3 * d + i] = _difference(target[i], states[j, i], i, periodic, half, span) / span[i]


def wrap_into_box(x: np.ndarray, low: np.ndarray, span: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """``x`` (rows of states, any float dtype) with its ``periodic`` coordinates wrapped into
    ``[low, low + span)``: ``low + (x - low) mod span`` (numpy's floored modulo), the others as they
    are. The one wrap of a drawn state: candidate sets, :func:`~gnn_mp_envs.envs.wrappers.policy_action_to_state`
    and the RL sampler's inlined copy of its target map."""
    wrapped = x - low
    np.remainder(wrapped, span, out=wrapped)
    wrapped += low
    return np.where(periodic, wrapped, x)


def feature_width(state_dim: int, prior: bool = False) -> int:
    """``F``: columns of the candidate features for ``state_dim``-D states (``prior``: with the prior's logit)."""
    return SCALAR_FEATURES + 4 * int(state_dim) + int(bool(prior))


class CandidatePrior(Protocol):
    """Scores a step's candidates from the full observation (per-episode caches allowed)."""

    def reset(self) -> None:
        """Forget the episode."""

    def __call__(self, obs: Mapping, candidates: np.ndarray, active: int) -> np.ndarray:
        """Logits ``(K,)`` of ``candidates`` ``(K, d)`` (float64) for tree ``active`` of ``obs``."""


class CandidateSet:
    """Draws the ``K`` candidates of a step and their features relative to the tree.

    Args:
        low, high: the state bounds ``(d,)``.
        count: ``K`` (at least 4: one of each kind).
        step_scale: about one extension in state units (the task's ``TaskSpec.step_scale``).
        periodic: ``(d,)`` bool, the coordinates that wrap (period ``high - low``).
        metric_weights: ``(d,)`` the planner's metric weights (None: Euclidean).
        local_scale: standard deviation of the local candidates, in extensions.
        prior: a :class:`CandidatePrior` whose logit of each candidate is the features' last column
            (None: no such column). Not part of :meth:`config`: its owner rebuilds it.

    ``propose(obs, rng)`` returns ``(candidates (K, d) float32, features (K, F) float32)``;
    ``record(obs, sample)`` is told the sample that was actually sent to the planner.
    """

    def __init__(self, low: np.ndarray, high: np.ndarray, *, count: int = DEFAULT_CANDIDATES,
                 step_scale: float = 1.0, periodic: Sequence[bool] | None = None,
                 metric_weights: Sequence[float] | None = None, local_scale: float = DEFAULT_LOCAL_SCALE,
                 target_scale: float = DEFAULT_TARGET_SCALE, prior: CandidatePrior | None = None) -> None:
        self.low = np.asarray(low, np.float64)
        self.high = np.asarray(high, np.float64)
        d = self.low.shape[0]
        if isinstance(count, bool) or int(count) != count or count < len(CANDIDATE_KINDS):
            raise ValueError(f"count must be an integer >= {len(CANDIDATE_KINDS)} (one candidate of each kind), "
                             f"got {count!r}")
        if not step_scale > 0 or not local_scale > 0 or not target_scale > 0:
            raise ValueError(f"step_scale, local_scale and target_scale must be > 0, got {step_scale}, {local_scale}, "
                             f"{target_scale}")
        self.count, self.state_dim = int(count), d
        if count < len(CANDIDATE_KINDS):
            raise ValueError(f"count must be >= {len(CANDIDATE_KINDS)} (one candidate of each kind), got {count}")
        self.span = self.high - self.low
        self.center, self.half = (self.high + self.low) / 2, self.span / 2
        self.periodic = np.zeros(d, bool) if periodic is None else np.asarray(periodic, bool)
        self.metric_weights = None if metric_weights is None else [float(w) for w in metric_weights]
        self.weights = np.ones(d) if metric_weights is None else np.asarray(metric_weights, np.float64)
        self.step = float(step_scale)
        self._wraps = bool(self.periodic.any())
        self._weighted = bool(np.any(self.weights != 1.0))
        self.local_scale, self.target_scale = float(local_scale), float(target_scale)
        self.local_std = self.local_scale * self.step / self.weights
        self.target_std = self.target_scale * self.span
        self.prior = prior
        self.width = feature_width(d, prior is not None)
        kinds = np.zeros((self.count, len(CANDIDATE_KINDS)), np.float64)
        fixed = len(CANDIDATE_KINDS) - 1
        kinds[np.arange(fixed), np.arange(fixed)] = 1
        kinds[fixed:, fixed] = 1
        self._kinds = kinds
        self.reset()

    def config(self) -> dict[str, Any]:
        """Constructor arguments that rebuild this candidate set (plain values, for a checkpoint)."""
        return {"count": self.count, "step_scale": self.step, "periodic": self.periodic.tolist(),
                "metric_weights": self.metric_weights, "local_scale": self.local_scale,
                "target_scale": self.target_scale}

    # ------------------------------------------------------------------ per episode
    def reset(self) -> None:
        """Forget the episode (tree statistics, the last sample)."""
        self._key: bytes | None = None
        self._seen = 0
        self._children = np.zeros(0, np.int64)
        self._failures = np.zeros(0, np.int64)
        self._tree_rows = [np.zeros(0, np.int64), np.zeros(0, np.int64)]     # row indices of each tree's nodes
        self._tree_states = [np.zeros((0, self.state_dim)), np.zeros((0, self.state_dim))]
        self._tree_columns = [np.zeros((self.state_dim, 0)), np.zeros((self.state_dim, 0))]   # the same, by coordinate
        self._tree_to_target = [np.zeros(0), np.zeros(0)]                  # each node's distance to its target
        self._tree_size = np.zeros(2, np.int64)
        self._near = np.zeros(0, np.int64)                                   # the last proposal's nearest nodes
        self._best_dist = np.full(2, np.inf)                # per tree: the distance of its node nearest its target
        self._best_row = np.full(2, -1, np.int64)           # ... and that node's row
        self._pending: tuple[int, int] | None = None       # (num_nodes when sent, nearest node)
        if self.prior is not None:
            self.prior.reset()

    def _difference(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        diff = a - b
        if self._wraps:
            diff = np.where(self.periodic, (diff + self.half) % self.span - self.half, diff)
        return diff

    def _distance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        diff = self._difference(a, b)
        if self._weighted:
            diff *= self.weights
        diff *= diff
        return np.sqrt(diff.sum(-1))

    def _ingest(self, obs: Mapping) -> int:
        """Update the tree statistics with the observation's new rows; the number of nodes."""
        self._obs = obs                      # what a prior scores the features' candidates against
        n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
        key = np.asarray(obs["start"]).tobytes() + np.asarray(obs["goal"]).tobytes()
        if key != self._key or n < self._seen:
            self.reset()
            self._key = key
            self._start = np.asarray(obs["start"], np.float64).copy()
            self._goal = np.asarray(obs["goal"], np.float64).copy()
            self._scale = max(float(self._distance(self._start, self._goal)), 1e-9)
            self._targets = np.stack([self._goal, self._start])     # tree 0 grows toward the goal, tree 1 the start
        if n > self._children.shape[0]:
            grow = max(n, 2 * self._children.shape[0], 64)
            self._children = np.concatenate([self._children, np.zeros(grow - self._children.shape[0], np.int64)])
            self._failures = np.concatenate([self._failures, np.zeros(grow - self._failures.shape[0], np.int64)])
        if n > self._seen:
            k = n - self._seen
            for t in (0, 1):
                self._reserve(t, int(self._tree_size[t]) + k)
            _ingest_rows(self._seen, np.asarray(obs["parent"][self._seen:n]).astype(np.int64),
                         np.asarray(obs["node_features"][self._seen:n, -1]).round().astype(np.int64),
                         np.asarray(obs["nodes"][self._seen:n], np.float64), self._targets, self._children,
                         *self._tree_rows, *self._tree_states, *self._tree_columns, *self._tree_to_target,
                         self._tree_size, self._best_dist, self._best_row, self.periodic, self.half, self.span,
                         self.weights)
        if self._pending is not None:
            sent_at, near = self._pending
            if n == sent_at:                        # the sample did not grow the tree: blocked
                self._failures[near] += 1
            self._pending = None
        self._seen = n
        return n

    def _reserve(self, tree: int, size: int) -> None:
        """Room for ``size`` nodes in ``tree``'s lists (doubling)."""
        m = int(self._tree_size[tree])
        if size <= len(self._tree_rows[tree]):
            return
        cap = max(2 * size, 64)
        self._tree_rows[tree] = np.resize(self._tree_rows[tree], cap)
        self._tree_to_target[tree] = np.resize(self._tree_to_target[tree], cap)
        grown = np.zeros((cap, self.state_dim))
        grown[:m] = self._tree_states[tree][:m]
        self._tree_states[tree] = grown
        columns = np.zeros((self.state_dim, cap))
        columns[:, :m] = self._tree_columns[tree][:, :m]
        self._tree_columns[tree] = columns

    def _nearest(self, points: np.ndarray, tree: int) -> tuple[np.ndarray, np.ndarray]:
        """Position in ``tree``'s node list of each point's nearest node under the planner's metric, and
        the distance; ``tree`` must hold a node. One coordinate at a time over contiguous columns
        (a wrapped coordinate as ``min(|a - b|, span - |a - b|)``): a fraction of the cost of a
        ``(P, m, d)`` difference with a wrap on every entry."""
        m = int(self._tree_size[tree])
        columns = self._tree_columns[tree]
        sq = None
        for i in range(self.state_dim):
            diff = np.subtract.outer(points[:, i], columns[i, :m])           # (P, m)
            if self.periodic[i]:
                np.abs(diff, out=diff)
                np.minimum(diff, self.span[i] - diff, out=diff)
            if self.weights[i] != 1.0:
                diff *= self.weights[i]
            diff *= diff
            sq = diff if sq is None else np.add(sq, diff, out=sq)
        j = sq.argmin(1)
        return j, np.sqrt(sq[np.arange(len(points)), j])

    # ------------------------------------------------------------------ per step
    def _step_context(self, obs: Mapping) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray]:
        """Ingest the observation: ``(num_nodes, active tree, its target, its newest node, its node
        nearest the target)`` (the target where the tree has none)."""
        n = self._ingest(obs)
        active = int(np.asarray(obs["active_tree"]).reshape(-1)[0])
        target = self._start if active == 1 else self._goal
        m, best = int(self._tree_size[active]), int(self._best_row[active])
        newest = self._tree_states[active][m - 1] if m else target
        greedy = np.asarray(obs["nodes"][best], np.float64) if best >= 0 else target
        return n, active, target, newest, greedy

    def propose(self, obs: Mapping, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The step's candidates ``(K, d)`` and features ``(K, F)`` (float32); draws from ``rng``."""
        n, active, target, newest, greedy = self._step_context(obs)
        noise = rng.standard_normal((3, self.state_dim))
        uniform = rng.random((self.count - 4, self.state_dim))
        cands32 = _assemble(target, noise, uniform, newest, greedy, self.target_std, self.local_std, self.low,
                            self.span, self.high, self.periodic, self._wraps)
        return cands32, self.features(cands32.astype(np.float64), n, active, target)

    def propose_reference(self, obs: Mapping, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`propose` in numpy operations (the same draws, candidates and features)."""
        n, active, target, newest, greedy = self._step_context(obs)
        d, K = self.state_dim, self.count
        cands = np.empty((K, d), np.float64)
        cands[0] = target
        noise = rng.standard_normal((3, d))
        cands[1] = target + noise[0] * self.target_std
        cands[2:4] = noise[1:] * self.local_std
        cands[2] += newest
        cands[3] += greedy
        cands[4:] = self.low + self.span * rng.random((K - 4, d))
        if self._wraps:
            cands = wrap_into_box(cands, self.low, self.span, self.periodic)
        cands32 = np.minimum(np.maximum(cands, self.low), self.high).astype(np.float32)
        return cands32, self.features_reference(cands32.astype(np.float64), n, active, target)

    def features(self, cands: np.ndarray, n: int, active: int, target: np.ndarray) -> np.ndarray:
        """Features ``(K, F)`` of candidate states ``cands`` for the active tree (see the module
        docstring) of the observation ingested last; remembers each candidate's
        nearest node for :meth:`record`. One compiled pass (:func:`_features`); the same values, bit
        for bit, as :meth:`features_reference`, the numpy statement of them."""
        K = cands.shape[0]
        out = np.empty((K, self.width), np.float64)
        near = np.empty(K, np.int64)
        other = 1 - active
        _features(np.ascontiguousarray(cands, np.float64), self._kinds[:K], self._tree_states[active],
                  self._tree_rows[active], self._tree_to_target[active], int(self._tree_size[active]),
                  self._tree_states[other], int(self._tree_size[other]), np.asarray(target, np.float64), int(n),
                  float(self._best_dist[active]), float(self._scale), self.step, self._children, self._failures,
                  self.periodic, self.span, self.half, self.center, self.weights, out, near)
        self._near = near
        if self.prior is not None:
            out[:, -1] = self.prior(self._obs, cands, active)
        return out.astype(np.float32)

    def features_reference(self, cands: np.ndarray, n: int, active: int, target: np.ndarray) -> np.ndarray:
        """:meth:`features` in numpy operations: what the columns are (tests hold the two equal)."""
        K, d = cands.shape
        D = self._scale
        j, reach = self._nearest(cands, active)
        near = self._tree_rows[active][j]
        self._near = near
        n_state = self._tree_states[active][j]
        n_goal = self._tree_to_target[active][j]
        out = np.empty((K, self.width), np.float64)
        c = len(CANDIDATE_KINDS)
        out[:, :c] = self._kinds[:K]
        out[:, c] = np.log1p(reach / self.step)
        out[:, c + 1] = self._distance(cands, target) / D
        out[:, c + 2] = n_goal / D
        out[:, c + 3] = (n_goal - self._best_dist[active]) / D
        out[:, c + 4] = np.log1p(n - 1 - near)
        out[:, c + 5] = np.log1p(self._children[near])
        out[:, c + 6] = np.log1p(self._failures[near])
        out[:, c + 7] = self._nearest(cands, 1 - active)[1] / D if self._tree_size[1 - active] else 0.0
        s = SCALAR_FEATURES
        out[:, s:s + d] = (cands - self.center) / self.half
        out[:, s + d:s + 2 * d] = (n_state - self.center) / self.half
        out[:, s + 2 * d:s + 3 * d] = np.clip(self._difference(cands, n_state) / self.step, -4.0, 4.0)
        out[:, s + 3 * d:s + 4 * d] = self._difference(target, n_state) / self.span
        if self.prior is not None:
            out[:, -1] = self.prior(self._obs, cands, active)
        return out.astype(np.float32)

    def record(self, obs: Mapping, sample: np.ndarray, candidate: int | None = None) -> None:
        """The sample actually sent to the planner for observation ``obs`` (call before stepping;
        ``candidate``: its row in the last proposal, when it is one): if the tree does not grow, its
        nearest node's failure count goes up at the next ingest."""
        n = self._ingest(obs)
        if candidate is not None:
            near = int(self._near[candidate])
        else:
            active = int(np.asarray(obs["active_tree"]).reshape(-1)[0])
            j, _ = self._nearest(np.asarray(sample, np.float64).reshape(1, -1), active)
            near = int(self._tree_rows[active][j[0]])
        self._pending = (n, near)


def candidate_space(state_dim: int, count: int, low: np.ndarray, high: np.ndarray,
                    prior: bool = False) -> dict[str, spaces.Box]:
    """The observation entries the candidate wrapper adds: ``candidates`` and ``candidate_features``
    (``prior``: with the prior's logit column)."""
    low32 = np.asarray(low, np.float32)
    high32 = np.asarray(high, np.float32)
    return {"candidates": spaces.Box(np.tile(low32, (count, 1)), np.tile(high32, (count, 1)), dtype=np.float32),
            "candidate_features": spaces.Box(-np.inf, np.inf, shape=(count, feature_width(state_dim, prior)),
                                             dtype=np.float32)}


def candidate_index(action: Any, count: int) -> int:
    """The candidate index ``action`` names: one integer in ``[0, count)`` (a Python or numpy integer, a
    0-d or one-element integer array, an integral float). Anything else is refused in one line: above
    all a vector (a one-hot action, ``count`` long, or an array of several indices), which an earlier
    reading turned silently into its first element, so a one-hot action always picked candidate 0."""
    if type(action) is int or isinstance(action, np.integer):          # SB3, TorchRL's index encoding, sample()
        k = int(action)
    else:
        try:
            a = np.asarray(action)
        except Exception:                                              # an object numpy cannot read
            a = None
        if a is None or a.dtype.kind not in "iuf" or a.size != 1:
            if a is not None and a.dtype.kind in "iufb" and a.size != 1:
                what = f"an array of shape {a.shape}"
            else:
                what = "a bool" if a is not None and a.dtype.kind == "b" else f"a {type(action).__name__}"
            hint = (" (a one-hot vector? send its index; a TorchRL actor acts in the env's encoding when built "
                    "with action_spec=env.action_spec)" if a is not None and a.shape[-1:] == (count,) and a.size > 1
                    else "")
            raise ValueError(f"action must be one candidate index, an integer in [0, {count}); got {what}{hint}")
        value = a.reshape(())[()]
        if a.dtype.kind == "f" and not (float(value).is_integer() and 0 <= value < count):   # NaN, inf fail too
            raise ValueError(f"action must be one candidate index, an integer in [0, {count}); got {float(value):g}")
        k = int(value)
    if not 0 <= k < count:
        raise ValueError(f"action must be one candidate index, an integer in [0, {count}); got {k}")
    return k


class CandidatePickWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Actions are ``Discrete(K)``: the index of one of the step's ``K`` candidates.

    ``candidates``: the keyword arguments of the :class:`CandidateSet` (``count``,
    ``step_scale``, ``periodic``, ``metric_weights``, ``local_scale``, ``target_scale``);
    ``prior``: a zero-argument factory of its :class:`CandidatePrior` (each env builds its own,
    with its own caches; None: no prior column).

    Adds ``candidates`` ``(K, d)`` and ``candidate_features`` ``(K, F)`` to the observation
    (:class:`CandidateSet`); ``step(k)`` sends candidate ``k`` to the planner, or, with
    probability ``uniform_mix``, a uniform state instead (the sampler's mixture). Wrap the
    planning env (with its full observation; apply the tree view after this wrapper). The
    draws come from the wrapper's own generator, seeded by ``reset(seed=...)``.
    """

    def __init__(self, env: gym.Env, uniform_mix: float = 0.0, prior: Callable[[], CandidatePrior] | None = None,
                 **candidates: Any) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, uniform_mix=uniform_mix, prior=prior, **candidates)
        gym.Wrapper.__init__(self, env)
        if not 0.0 <= uniform_mix <= 1.0:
            raise ValueError(f"uniform_mix must be in [0, 1], got {uniform_mix}")
        if prior is not None and not callable(prior):
            raise ValueError(f"prior must be a zero-argument factory of a candidate prior, got {prior!r}")
        box = env.action_space
        self.candidate_set = CandidateSet(box.low, box.high, prior=None if prior is None else prior(), **candidates)
        count = self.candidate_set.count
        self.uniform_mix = float(uniform_mix)
        self.action_space = spaces.Discrete(int(count))
        self.observation_space = spaces.Dict({**env.observation_space.spaces,
                                              **candidate_space(box.shape[0], count, box.low, box.high,
                                                                prior is not None)})
        self._rng = np.random.default_rng()
        self._obs: Mapping | None = None
        self._cands: np.ndarray | None = None

    def _with_candidates(self, obs: Mapping) -> dict:
        self._obs = obs
        self._cands, feats = self.candidate_set.propose(obs, self._rng)
        return {**obs, "candidates": self._cands, "candidate_features": feats}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), 0xCA9D])
        obs, info = self.env.reset(seed=seed, options=options)
        self.candidate_set.reset()
        return self._with_candidates(obs), info

    def step(self, action):
        if self._cands is None:
            raise RuntimeError("call reset() before step()")
        k = candidate_index(action, self.candidate_set.count)
        sample, candidate = self._cands[k], k
        if self.uniform_mix > 0.0 and self._rng.random() < self.uniform_mix:
            box = self.env.action_space
            sample = (box.low + (box.high - box.low) * self._rng.random(box.shape[0])).astype(np.float32)
            candidate = None
        self.candidate_set.record(self._obs, sample, candidate)
        obs, reward, terminated, truncated, info = self.env.step(sample)
        return self._with_candidates(obs), reward, terminated, truncated, info


__all__ = ["CANDIDATE_KINDS", "CandidatePickWrapper", "candidate_index", "CandidatePrior", "CandidateSet", "DEFAULT_CANDIDATES", "DEFAULT_LOCAL_SCALE",
           "DEFAULT_TARGET_SCALE",
           "candidate_space", "feature_width", "wrap_into_box"]
