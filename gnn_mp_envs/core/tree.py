"""Search trees in preallocated arrays.

All trees of a planner share one node store (global indices are what the observation
shows), and each tree keeps a contiguous copy of its own states.

Nearest-neighbour queries: where the problem names its metric (``nearest_metric``: weights and
periodic coordinates, every built-in task), a compiled incremental k-d tree per search tree
(:class:`~gnn_mp_envs.core.nearest.NearestIndex`) answers exactly what a scan would (the first node at
the least distance), at any size; the compiled planning loop (:mod:`gnn_mp_envs.core.loop`) queries
and grows the same index. Otherwise (a user's own metric) small trees are scanned in one pass (the
problem's ``nearest_row``); once a tree has ``KD_MIN_NODES`` nodes, a scipy ``cKDTree`` indexes its
older nodes and only the nodes added since the last rebuild are scanned. That k-d tree is rebuilt
when the recent buffer outgrows ``max(KD_MIN_BUFFER, indexed / 8)``, so the rebuild cost is
amortised, and works in the problem's ``nn_embed`` coordinates, where Euclidean distance (with
``nn_boxsize`` periodic axes) equals ``problem.distance``.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from scipy.spatial import cKDTree

from gnn_mp_envs.core.nearest import NearestIndex
from gnn_mp_envs.core.problem import compiled_nearest_node
from gnn_mp_envs.utils.compiled import jit

KD_MIN_NODES = 1024
KD_MIN_BUFFER = 512


@jit
def path_nodes(parent, head, tail):
    """The nodes from the root of ``head``'s tree down to ``head``, then, where ``tail >= 0``, from ``tail``'s
    parent up to its root (BiRRT's path: ``tail`` meets ``head`` at the same state, so it is left out): a
    solution's nodes in one compiled call, inside the planning time of every solved problem (a walk in Python
    converts every parent index it reads)."""
    up = 0
    i = head
    while i >= 0:
        up += 1
        i = parent[i]
    down = 0
    i = parent[tail] if tail >= 0 else -1
    while i >= 0:
        down += 1
        i = parent[i]
    out = np.empty(up + down, dtype=np.int64)
    k, i = up, head
    while i >= 0:
        k -= 1
        out[k] = i
        i = parent[i]
    k = up
    i = parent[tail] if tail >= 0 else -1
    while i >= 0:
        out[k] = i
        k += 1
        i = parent[i]
    return out


@jit
def solution_rows(parent, states, controls, cost, head, tail):
    """A solution in one compiled call: :func:`path_nodes` of ``head`` and ``tail``, their states and controls
    (copies of those rows), and its length (the two nodes' costs-to-come, ``tail``'s only where ``tail >= 0``).
    Inside the planning time of every solved problem: one call instead of a fancy index per array."""
    nodes = path_nodes(parent, head, tail)
    k = nodes.shape[0]
    out_states = np.empty((k, states.shape[1]))
    out_controls = np.empty((k, controls.shape[1]))
    for r in range(k):
        i = nodes[r]
        for c in range(states.shape[1]):
            out_states[r, c] = states[i, c]
        for c in range(controls.shape[1]):
            out_controls[r, c] = controls[i, c]
    length = cost[head] + cost[tail] if tail >= 0 else cost[head]
    return nodes, out_states, out_controls, length


class Metric(Protocol):
    """What a nearest query needs from a problem."""

    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray: ...
    def nearest_row(self, states: np.ndarray, x: np.ndarray) -> tuple[int, float]: ...
    def nn_embed(self, states: np.ndarray) -> np.ndarray: ...
    nn_boxsize: np.ndarray | None


class TreeStore:
    """Nodes of one or two trees: state, parent, cost-to-come, tree id and edge control."""

    def __init__(self, capacity: int, state_dim: int, control_dim: int = 0, num_trees: int = 1,
                 nearest_metric: tuple[np.ndarray, np.ndarray] | None = None):
        if capacity < num_trees:
            raise ValueError(f"capacity must hold at least the {num_trees} root(s), got {capacity}")
        self.capacity = int(capacity)
        self.state_dim = int(state_dim)
        self.num_trees = int(num_trees)
        self.states = np.zeros((capacity, state_dim))
        self.parent = np.full(capacity, -1, dtype=np.int64)
        self.cost = np.zeros(capacity)
        self.tree_id = np.zeros(capacity, dtype=np.int64)
        self.controls = np.zeros((capacity, control_dim))
        # Per-tree contiguous copies for nearest-neighbour queries.
        self._tree_states = [np.zeros((capacity, state_dim)) for _ in range(num_trees)]
        self._tree_index = [np.zeros(capacity, dtype=np.int64) for _ in range(num_trees)]
        self._tree_size = np.zeros(num_trees, dtype=np.int64)   # an array: the compiled loop updates it
        self._kd: list[cKDTree | None] = [None] * num_trees
        self._kd_count = [0] * num_trees
        self._scan = compiled_nearest_node()
        #: The exact k-d trees of a named metric (None: the generic scan and cKDTree).
        self.index = NearestIndex(capacity, num_trees, *nearest_metric) if nearest_metric is not None else None
        #: The node count as a one-element array, which the compiled loop updates in place.
        self._size = np.zeros(1, dtype=np.int64)

    @property
    def size(self) -> int:
        return int(self._size[0])

    def __len__(self) -> int:
        return self.size

    @property
    def full(self) -> bool:
        return self.size >= self.capacity

    def tree_size(self, tree: int) -> int:
        return int(self._tree_size[tree])

    def add(self, state: np.ndarray, parent: int, tree: int, cost: float = 0.0,
            control: np.ndarray | None = None) -> int:
        """Append a node and return its global index."""
        if self.size >= self.capacity:
            raise IndexError(f"tree store is full ({self.capacity} nodes)")
        i = self.size
        self.states[i] = state
        self.parent[i] = parent
        self.cost[i] = (self.cost[parent] if parent >= 0 else 0.0) + cost
        self.tree_id[i] = tree
        if control is not None and control.size:
            self.controls[i] = control
        self._size[0] = i + 1
        if self.index is not None:
            self._tree_size[tree] += 1
            self.index.insert(i, tree, self.states)
            return i
        k = self._tree_size[tree]
        self._tree_states[tree][k] = state
        self._tree_index[tree][k] = i
        self._tree_size[tree] = k + 1
        return i

    def nearest(self, x: np.ndarray, tree: int, metric: Metric) -> int:
        """Global index of the node of ``tree`` closest to ``x`` under ``metric.distance``."""
        if self.index is not None:
            return int(self.index.nearest(x, tree, self.states)[0])
        k = self._tree_size[tree]
        states = self._tree_states[tree]
        if k < KD_MIN_NODES:            # a small tree: one scan (one compiled call where the problem names its metric)
            named = getattr(metric, "nearest_metric", None)
            if named is not None and self._scan is not None:
                return self._scan(states, k, x, *named, self._tree_index[tree])
            return int(self._tree_index[tree][metric.nearest_row(states[:k], x)[0]])
        indexed = self._kd_count[tree]
        if k - indexed > max(KD_MIN_BUFFER, indexed // 8):
            self._kd[tree] = cKDTree(metric.nn_embed(states[:k]), boxsize=metric.nn_boxsize)
            self._kd_count[tree] = indexed = k
        kd_dist, kd_idx = self._kd[tree].query(metric.nn_embed(x[None])[0])
        if indexed == k:
            return int(self._tree_index[tree][kd_idx])
        j, d_j = metric.nearest_row(states[indexed:k], x)     # the nodes added since the last rebuild
        if kd_dist <= d_j:
            return int(self._tree_index[tree][kd_idx])
        return int(self._tree_index[tree][indexed + j])

    def path_to_root(self, i: int) -> list[int]:
        """Node indices from the root of ``i``'s tree down to ``i``."""
        return path_nodes(self.parent, int(i), -1).tolist()
