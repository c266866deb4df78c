"""The planner's nearest-neighbour index: an incremental k-d tree per search tree, compiled (numba), that
answers exactly what a scan of the tree's nodes answers: the first node (in insertion order) at the least
distance under the problem's weighted metric (:func:`~gnn_mp_envs.core.problem._nearest_row_loop`).

Every node is a point of the k-d tree, inserted once when it joins its search tree (no rebuilds), split
on the coordinates in turn (periodic ones never: the gap to a plane across a wrapped coordinate is not a
bound). A query descends to the query's cell, then backs up into the far side of each plane only where
the plane is not farther than the best distance so far (with a relative margin far above rounding), and
computes every distance it looks at as the scan does; ties go to the smallest node index. So the answer
is the scan's, bit for bit, at a cost that grows with the depth of the tree rather than its size: the
Fetch's trees reach 30,000 nodes in 8 dimensions.

Arrays (``n``: node capacity): ``left``, ``right`` (child node or -1), ``split`` (the coordinate a node
splits on); ``root`` (per search tree, -1 while empty); ``stack``, ``bounds``, ``offsets`` (scratch). States are
the planner's node store (global rows), so the index holds no copy of them.
"""

from __future__ import annotations

import math

import numpy as np

from gnn_mp_envs.utils.compiled import jit

#: A cell is skipped when its squared distance exceeds the best squared distance by this factor: far above
#: the rounding of either, so no node that could tie or win is skipped.
PRUNE_MARGIN = 1.0 + 1e-9


@jit(inline=True)
def _distance(states, i, x, weights, periodic):
    """The scan's distance from row ``i`` of ``states`` to ``x`` (the same operations, in order)."""
    acc = 0.0
    for c in range(x.shape[0]):
        v = states[i, c] - x[c]
        if periodic[c]:
            a = v + math.pi
            v = (a if 0.0 < a < 2 * math.pi else a % (2 * math.pi)) - math.pi
        v = v * weights[c]
        acc += v * v
    return math.sqrt(acc)


@jit(inline=True)
def _next_split(dim, periodic):
    """The coordinate after ``dim`` that is not periodic (-1: none is)."""
    d = periodic.shape[0]
    for k in range(1, d + 1):
        c = (dim + k) % d
        if not periodic[c]:
            return c
    return -1


@jit
def kd_insert(i, tree, states, periodic, left, right, split, root):
    """Add node ``i`` (a row of ``states``) to search tree ``tree``'s k-d tree."""
    left[i], right[i] = -1, -1
    node = root[tree]
    if node < 0:
        root[tree] = i
        split[i] = _next_split(-1, periodic)
        return
    while True:
        c = split[node]
        if c < 0 or states[i, c] >= states[node, c]:        # no splitting coordinate: a chain on the right
            if right[node] < 0:
                right[node] = i
                break
            node = right[node]
        else:
            if left[node] < 0:
                left[node] = i
                break
            node = left[node]
    split[i] = _next_split(split[node], periodic) if split[node] >= 0 else -1


@jit
def kd_nearest(x, tree, states, weights, periodic, left, right, split, root, stack, bounds, offsets):
    """``(node, distance)``: the node of search tree ``tree`` nearest ``x``, the first of equals (the
    smallest index), as the scan finds it; ``(-1, inf)`` for an empty tree; a NaN in ``x``: the root
    and NaN (a scan's first NaN distance). Scratch: ``stack``, ``bounds`` (one entry per node, plus
    one) and ``offsets`` (one row per node, plus two, of the state's size).

    A subtree is visited only when its cell may hold a node as near as the best so far: the cell's
    squared distance from ``x`` (the sum over coordinates of the squared weighted gap to the cell's slab,
    kept per stacked cell and updated one coordinate per plane crossed) is not beyond the best's square."""
    node = root[tree]
    if node < 0:
        return -1, math.inf
    d = x.shape[0]
    for c in range(d):
        if x[c] != x[c]:
            return node, math.nan
    cur = offsets.shape[0] - 1                       # the row of the cell being walked
    best, best_d, best_sq = -1, math.inf, math.inf
    stack[0], bounds[0] = node, 0.0
    for c in range(d):
        offsets[0, c] = 0.0
    top = 1
    while top > 0:
        top -= 1
        bound = bounds[top]
        if bound > best_sq:                          # the cell already farther than the best
            continue
        node = stack[top]
        for c in range(d):
            offsets[cur, c] = offsets[top, c]
        while node >= 0:                             # down toward x, keeping the far sides
            dist = _distance(states, node, x, weights, periodic)
            if dist < best_d or (dist == best_d and node < best):
                best, best_d = node, dist
                best_sq = dist * dist * PRUNE_MARGIN
            c = split[node]
            if c < 0:
                node = right[node]
                continue
            gap = (x[c] - states[node, c]) * weights[c]
            if gap < 0.0:
                near, far, gap = left[node], right[node], -gap
            else:
                near, far = right[node], left[node]
            if far >= 0:
                old = offsets[cur, c]
                far_bound = bound - old * old + gap * gap
                if far_bound <= best_sq:
                    for k in range(d):
                        offsets[top, k] = offsets[cur, k]
                    offsets[top, c] = gap
                    stack[top], bounds[top] = far, far_bound
                    top += 1
            node = near
    return best, best_d


class NearestIndex:
    """The k-d trees of a planner's search trees over its node store (see the module)."""

    def __init__(self, capacity: int, num_trees: int, weights: np.ndarray, periodic: np.ndarray) -> None:
        self.left = np.full(capacity, -1, dtype=np.int64)
        self.right = np.full(capacity, -1, dtype=np.int64)
        self.split = np.full(capacity, -1, dtype=np.int64)
        self.root = np.full(num_trees, -1, dtype=np.int64)
        self.stack = np.zeros(capacity + 1, dtype=np.int64)
        self.bounds = np.zeros(capacity + 1)
        self.offsets = np.zeros((capacity + 2, len(weights)))
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        self.periodic = np.ascontiguousarray(periodic, dtype=np.bool_)

    def insert(self, i: int, tree: int, states: np.ndarray) -> None:
        kd_insert(i, tree, states, self.periodic, self.left, self.right, self.split, self.root)

    def nearest(self, x: np.ndarray, tree: int, states: np.ndarray) -> tuple[int, float]:
        return kd_nearest(x, tree, states, self.weights, self.periodic, self.left, self.right, self.split,
                          self.root, self.stack, self.bounds, self.offsets)
