"""The tree as a padded graph observation, updated in place as nodes are added.

Layout (``N = max_nodes``, ``d`` = state dimension), all padded rows zero:

=================  ==================  =========================================================
key                shape / dtype       meaning
=================  ==================  =========================================================
``nodes``          (N, d) float32      node states
``node_features``  (N, 2d+1) float32   ``[x_init - x_n, x_goal - x_n, tree_id]`` (the paper's
                                       features; differences wrap angles; tree id is 0 for the
                                       start tree, 1 for BiRRT's goal tree)
``parent``         (N,) int64          parent index of each node (tree edges), -1 for roots
                                       and padding
``mask``           (N,) int8           1 for real nodes
``num_nodes``      (1,) int64          number of real nodes (they are rows ``0..num_nodes-1``)
``start``          (d,) float32        start state
``goal``           (d,) float32        goal state
``active_tree``    (1,) int64          the tree the next action extends (always 0 for RRT)
``obstacles``      (M, 1+w) float32    the problem's obstacles, one row each: ``[1, features]``
                                       (task-specific ``w`` features; padding rows are zero;
                                       ``(1, 1)`` zeros for tasks without obstacles). What
                                       conditional samplers (CVAE) condition on.
=================  ==================  =========================================================

``spaces.Dict`` rather than ``spaces.Graph``: SB3 and TorchRL accept padded boxes, and
``agents.nn.graph.to_pyg`` turns this layout into a PyG ``Data``/``Batch``.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from gnn_mp_envs.core.problem import Problem
from gnn_mp_envs.core.tree import TreeStore
from gnn_mp_envs.utils.compiled import lazy_njit

#: glibc ``mallopt`` parameters (see ``man mallopt``).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_heap_tuned = False


def keep_freed_heap(trim_threshold: int = 64 << 20, mmap_threshold: int = 32 << 20) -> bool:
    """Stop glibc from handing freed heap back to the OS after every step (once per process).

    Each step returns fresh copies of the padded arrays (0.7 MB for the 20,000-node
    pendulum observation). By default glibc returns the freed copies to the OS (``brk``
    trimming), so the next copies page-fault in anew: measured 185 us per step against
    22 us once freed memory stays in the heap. Raising the trim threshold to 64 MiB (and
    pinning the mmap threshold at 32 MiB, which setting the former would otherwise freeze
    at 128 KiB) keeps it; the process then holds at most that much idle heap. A no-op
    returning False where glibc is not the allocator.
    """
    global _heap_tuned
    if _heap_tuned:
        return True
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        ok = bool(libc.mallopt(_M_MMAP_THRESHOLD, mmap_threshold)) and bool(
            libc.mallopt(_M_TRIM_THRESHOLD, trim_threshold))
    except (OSError, AttributeError):
        return False
    _heap_tuned = ok
    return ok


OBSERVATION_KEYS = ("nodes", "node_features", "parent", "mask", "num_nodes", "start", "goal",
                    "active_tree", "obstacles")


def obstacle_shape(max_obstacles: int, obstacle_width: int) -> tuple[int, int]:
    """Shape of the ``obstacles`` entry: one row per obstacle, a presence flag + features."""
    return (max(1, int(max_obstacles)), 1 + int(obstacle_width) if max_obstacles else 1)


def observation_space(low: np.ndarray, high: np.ndarray, max_nodes: int,
                      obstacles: tuple[int, int] = (1, 1)) -> spaces.Dict:
    """The padded-graph observation space for a state box ``[low, high]`` (``obstacles``: the
    shape of the obstacle rows, see :func:`obstacle_shape`)."""
    low = np.asarray(low, dtype=np.float32)
    high = np.asarray(high, dtype=np.float32)
    span = high - low
    feat_high = np.concatenate([span, span, [1.0]]).astype(np.float32)
    feat_low = np.concatenate([-span, -span, [0.0]]).astype(np.float32)
    state_low = np.minimum(low, 0.0)  # padding rows are zero
    state_high = np.maximum(high, 0.0)
    return spaces.Dict({
        "nodes": spaces.Box(np.tile(state_low, (max_nodes, 1)), np.tile(state_high, (max_nodes, 1)),
                            dtype=np.float32),
        "node_features": spaces.Box(np.tile(feat_low, (max_nodes, 1)), np.tile(feat_high, (max_nodes, 1)),
                                    dtype=np.float32),
        "parent": spaces.Box(-1, max_nodes - 1, shape=(max_nodes,), dtype=np.int64),
        "mask": spaces.MultiBinary(max_nodes),
        "num_nodes": spaces.Box(0, max_nodes, shape=(1,), dtype=np.int64),
        "start": spaces.Box(low, high, dtype=np.float32),
        "goal": spaces.Box(low, high, dtype=np.float32),
        "active_tree": spaces.Box(0, 1, shape=(1,), dtype=np.int64),
        "obstacles": spaces.Box(-np.inf, np.inf, shape=tuple(obstacles), dtype=np.float32),
    })


def _write_row(i: int, states: np.ndarray, tree_id: np.ndarray, parents: np.ndarray, endpoints: np.ndarray,
               nodes: np.ndarray, node_features: np.ndarray, parent: np.ndarray, mask: np.ndarray,
               num_nodes: np.ndarray) -> None:
    """:meth:`GraphObservation.add` for a problem whose ``difference`` is the plain ``a - b``, in one
    pass: the same float64 differences, rounded to float32 on the store as numpy's assignment does."""
    d = states.shape[1]
    for c in range(d):
        nodes[i, c] = states[i, c]
        node_features[i, c] = endpoints[0, c] - states[i, c]
        node_features[i, d + c] = endpoints[1, c] - states[i, c]
    node_features[i, 2 * d] = tree_id[i]
    parent[i] = parents[i]
    mask[i] = 1
    num_nodes[0] = i + 1


def _write_rows(first: int, stop: int, states: np.ndarray, tree_id: np.ndarray, parents: np.ndarray,
                endpoints: np.ndarray, nodes: np.ndarray, node_features: np.ndarray, parent: np.ndarray,
                mask: np.ndarray, num_nodes: np.ndarray) -> None:
    """:func:`_write_row` for rows ``first..stop-1`` (a batch's new nodes: one call, not one per node)."""
    for i in range(first, stop):
        _write_row(i, states, tree_id, parents, endpoints, nodes, node_features, parent, mask, num_nodes)


#: :func:`_write_row` compiled (numba), or None without numba.
compiled_write_row = lazy_njit(_write_row)
#: :func:`_write_rows` compiled (numba), or None without numba.
compiled_write_rows = lazy_njit(_write_rows, calls={"_write_row": compiled_write_row})


def _row_writers(problem: Problem | None) -> tuple:
    """The compiled writes of one row and of a run of rows for ``problem`` where its features are plain
    differences; ``(None, None)`` (numpy's path, e.g. the pendulum's wrapped angles) otherwise."""
    if problem is None or type(problem).difference is not Problem.difference:
        return None, None
    return compiled_write_row(), compiled_write_rows()


class GraphObservation:
    """Preallocated observation arrays; :meth:`add` writes one row per new node."""

    def __init__(self, state_dim: int, max_nodes: int, obstacles: tuple[int, int] = (1, 1)) -> None:
        self.max_nodes = int(max_nodes)
        self.state_dim = int(state_dim)
        self.nodes = np.zeros((max_nodes, state_dim), dtype=np.float32)
        self.node_features = np.zeros((max_nodes, 2 * state_dim + 1), dtype=np.float32)
        self.parent = np.full(max_nodes, -1, dtype=np.int64)
        self.mask = np.zeros(max_nodes, dtype=np.int8)
        self.num_nodes = np.zeros(1, dtype=np.int64)
        self.start = np.zeros(state_dim, dtype=np.float32)
        self.goal = np.zeros(state_dim, dtype=np.float32)
        self.active_tree = np.zeros(1, dtype=np.int64)
        self.obstacles = np.zeros(obstacles, dtype=np.float32)
        self._problem: Problem | None = None
        self._write = self._write_run = None
        #: The feature columns ``[x_init - x_n, x_goal - x_n]`` as a (N, 2, d) view: both differences
        #: of a new node are computed and written in one operation each.
        self._differences = self.node_features[:, :2 * state_dim].reshape(max_nodes, 2, state_dim)
        self._tree_column = 2 * state_dim
        #: The arrays themselves, in observation order (what ``as_dict(copy=False)`` hands out).
        self._views = {"nodes": self.nodes, "node_features": self.node_features, "parent": self.parent,
                       "mask": self.mask, "num_nodes": self.num_nodes, "start": self.start, "goal": self.goal,
                       "active_tree": self.active_tree, "obstacles": self.obstacles}

    def __getstate__(self) -> dict:
        # the difference view is rebuilt on the copy's own arrays (a copied view would be detached)
        return {k: v for k, v in self.__dict__.items() if k not in ("_differences", "_write", "_write_run")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._differences = self.node_features[:, :2 * self.state_dim].reshape(self.max_nodes, 2, self.state_dim)
        self._write, self._write_run = _row_writers(self._problem)

    def reset(self, problem: Problem, tree: TreeStore, obstacle_rows: np.ndarray | None = None) -> None:
        """Clear the rows used by the previous episode and write the roots of ``tree`` and the
        problem's ``obstacle_rows`` (k, w)."""
        n = int(self.num_nodes[0])
        self.nodes[:n] = 0.0
        self.node_features[:n] = 0.0
        self.parent[:n] = -1
        self.mask[:n] = 0
        self.num_nodes[0] = 0
        self.start[:] = problem.start
        self.goal[:] = problem.goal
        self.active_tree[0] = 0
        self.obstacles[:] = 0.0
        if obstacle_rows is not None and len(obstacle_rows):
            k, w = obstacle_rows.shape
            if k > self.obstacles.shape[0] or w + 1 != self.obstacles.shape[1]:
                raise ValueError(f"{k} obstacle rows of width {w} do not fit the observation's "
                                 f"{self.obstacles.shape} (presence flag + features)")
            self.obstacles[:k, 0] = 1.0
            self.obstacles[:k, 1:] = obstacle_rows
        self._problem = problem
        self._endpoints = np.stack([problem.start, problem.goal])
        self._write, self._write_run = _row_writers(problem)
        for i in range(len(tree)):
            self.add(tree, i)

    def add(self, tree: TreeStore, i: int) -> None:
        """Write node ``i`` of ``tree`` (nodes arrive in index order)."""
        if self._write is not None:
            self._write(i, tree.states, tree.tree_id, tree.parent, self._endpoints, self.nodes, self.node_features,
                        self.parent, self.mask, self.num_nodes)
            return
        x = tree.states[i]
        self.nodes[i] = x
        self._differences[i] = self._problem.difference(self._endpoints, x)    # [x_init - x, x_goal - x]
        self.node_features[i, self._tree_column] = tree.tree_id[i]
        self.parent[i] = tree.parent[i]
        self.mask[i] = 1
        self.num_nodes[0] = i + 1

    def add_rows(self, tree: TreeStore, first: int, stop: int) -> None:
        """Write nodes ``first..stop-1`` of ``tree`` (what a step added), in one compiled call where
        :meth:`add` compiles."""
        if self._write_run is not None:
            self._write_run(first, stop, tree.states, tree.tree_id, tree.parent, self._endpoints, self.nodes,
                            self.node_features, self.parent, self.mask, self.num_nodes)
            return
        for i in range(first, stop):
            self.add(tree, i)

    def as_dict(self, copy: bool = True) -> dict:
        """The observation; ``copy=False`` returns live views that later steps overwrite."""
        if not copy:
            return dict(self._views)
        c = np.copy
        return {
            "nodes": c(self.nodes),
            "node_features": c(self.node_features),
            "parent": c(self.parent),
            "mask": c(self.mask),
            "num_nodes": c(self.num_nodes),
            "start": c(self.start),
            "goal": c(self.goal),
            "active_tree": c(self.active_tree),
            "obstacles": c(self.obstacles),
        }
