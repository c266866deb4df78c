"""Search trees in preallocated arrays.

All trees of a planner share one node store (global indices are what the observation
shows), and each tree keeps a contiguous copy of its own states so that a nearest
neighbour query is one vectorised pass over a slice, with no gathering or rebuilding.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

DistanceFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


class TreeStore:
    """Nodes of one or two trees: state, parent, cost-to-come, tree id and edge control."""

    def __init__(self, capacity: int, state_dim: int, control_dim: int = 0, num_trees: int = 1):
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
        self._tree_size = [0] * num_trees
        self.size = 0

    def __len__(self) -> int:
        return self.size

    @property
    def full(self) -> bool:
        return self.size >= self.capacity

    def tree_size(self, tree: int) -> int:
        return self._tree_size[tree]

    def add(self, state: np.ndarray, parent: int, tree: int, cost: float = 0.0,
            control: np.ndarray | None = None) -> int:
        """Append a node and return its global index."""
        if self.full:
            raise IndexError(f"tree store is full ({self.capacity} nodes)")
        i = self.size
        self.states[i] = state
        self.parent[i] = parent
        self.cost[i] = (self.cost[parent] if parent >= 0 else 0.0) + cost
        self.tree_id[i] = tree
        if control is not None and control.size:
            self.controls[i] = control
        k = self._tree_size[tree]
        self._tree_states[tree][k] = state
        self._tree_index[tree][k] = i
        self._tree_size[tree] = k + 1
        self.size = i + 1
        return i

    def nearest(self, x: np.ndarray, tree: int, distance: DistanceFn) -> int:
        """Global index of the node of ``tree`` closest to ``x`` under ``distance``."""
        k = self._tree_size[tree]
        d = distance(self._tree_states[tree][:k], x)
        return int(self._tree_index[tree][int(np.argmin(d))])

    def path_to_root(self, i: int) -> list[int]:
        """Node indices from the root of ``i``'s tree down to ``i``."""
        out = []
        while i >= 0:
            out.append(i)
            i = int(self.parent[i])
        return out[::-1]
