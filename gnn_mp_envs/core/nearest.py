"""The planner's nearest-neighbour index: an incremental k-d tree per search tree, compiled (numba), that
answers exactly what a scan of the tree's nodes answers: the first node (in insertion order) at the least
distance under the problem's weighted metric (:func:`~gnn_mp_envs.core.problem._nearest_row_loop`).

Every node is a point of the k-d tree, inserted once when it joins its search tree (no rebuilds), split
on the coordinates in turn (periodic ones never: the gap to a plane across a wrapped coordinate is not a
bound). A query descends to the query's cell, then backs up into the far side of each plane only where
the plane is not farther than the best distance so far (with a margin far above rounding). It compares
squared distances and takes the square root, as the scan does, only of those within that margin of the
best, so every distance it compares is the scan's; ties go to the smallest node index. So the answer
is the scan's, bit for bit, at a cost that grows with the depth of the tree rather than its size: the
Fetch's trees reach 30,000 nodes in 8 dimensions.

Arrays (``n``: node capacity): ``links`` (int32, ``(n, 3)``: a node's left and right child, -1 for none,
and the coordinate it splits on, -1 for none), ``cut`` (a node's state on that coordinate: the descent
picks its side from one small array, not from the state rows); ``root`` (per search tree, -1 while empty); ``stack``,
``bounds``, ``cell`` (scratch). States are the planner's node store (global rows), so the index holds
no other copy of them.
"""

from __future__ import annotations

import math

import numpy as np

from gnn_mp_envs.utils.compiled import jit

#: A cell is skipped, and a node's square root not taken, when its squared distance exceeds the best
#: squared distance by this factor plus :data:`PRUNE_FLOOR`: far above the rounding of either, so no node
#: that could tie or win is passed over.
PRUNE_MARGIN = 1.0 + 1e-9
#: The margin's absolute part, for distances so small that their squares lose precision (subnormal).
PRUNE_FLOOR = 2.0 ** -1000
#: ``links`` columns.
LEFT, RIGHT, SPLIT = 0, 1, 2


@jit(inline=True)
def _squared_distance(states, i, x, weights, periodic):
    """The scan's sum of squares from row ``i`` of ``states`` to ``x`` (the same operations, in order):
    its square root is the scan's distance."""
    acc = 0.0
    for c in range(x.shape[0]):
        v = states[i, c] - x[c]
        if periodic[c]:
            a = v + math.pi
            v = (a if 0.0 < a < 2 * math.pi else a % (2 * math.pi)) - math.pi
        v = v * weights[c]
        acc += v * v
    return acc


@jit(inline=True)
def _next_split(dim, periodic):
    """The coordinate after ``dim`` that is not periodic (-1: none is)."""
    d = periodic.shape[0]
    for k in range(1, d + 1):
        c = (dim + k) % d
        if not periodic[c]:
            return c
    return -1


@jit(inline=True)
def kd_pop_cell(stack, bounds, cell, top, limit):
    """The next stacked cell of a query: ``(node, its squared distance, new top)``; node -1 when the top row
    was a mark (the cell ``cell`` is restored) or a cell farther than ``limit`` (dropped). An entered
    cell's row stays as a mark holding its coordinate's former gap (see :func:`kd_nearest`)."""
    e = top - 1
    node, c = stack[e, 0], stack[e, 1]
    if node < 0:                                 # a mark: the cell's subtree is done
        cell[c] = bounds[e, 1]
        return -1, 0.0, e
    bound = bounds[e, 0]
    if bound > limit:                            # the cell already farther than the best
        return -1, 0.0, e
    stack[e, 0] = -1
    bounds[e, 1], cell[c] = cell[c], bounds[e, 1]
    return node, bound, top


@jit(inline=True)
def kd_stack_far_side(node, c, gap, bound, limit, links, stack, bounds, cell, top):
    """At ``node`` (splitting coordinate ``c``; ``gap``: the query's signed, scaled gap to its plane): stack
    the far side's cell (its squared distance ``bound`` with this coordinate's gap) and return ``(the
    near child, new top)``. The row is written always and kept by the count, not by a branch (which far
    sides are kept is too irregular for the branch predictor)."""
    near_side = RIGHT if gap >= 0.0 else LEFT
    far = links[node, RIGHT + LEFT - near_side]
    gap_sq = gap * gap
    far_bound = bound - cell[c] + gap_sq
    stack[top, 0], stack[top, 1] = far, c
    bounds[top, 0], bounds[top, 1] = far_bound, gap_sq
    top += (far >= 0) & (far_bound <= limit)
    return links[node, near_side], top


@jit
def kd_insert(i, tree, states, periodic, links, cut, root):
    """Add node ``i`` (a row of ``states``) to search tree ``tree``'s k-d tree; nothing when it is there
    already (the descent meets it: its place is where its state leads), so a repeated insert cannot link a
    node under itself."""
    node = root[tree]
    if node < 0:
        root[tree] = i
        c = _next_split(-1, periodic)
    else:
        while True:
            if node == i:
                return
            c = links[node, SPLIT]
            side = RIGHT if c < 0 or states[i, c] >= cut[node] else LEFT   # no split: a chain on the right
            child = links[node, side]
            if child < 0:
                links[node, side] = i
                break
            node = child
        c = _next_split(c, periodic) if c >= 0 else -1
    links[i, LEFT], links[i, RIGHT] = -1, -1
    links[i, SPLIT] = c
    cut[i] = states[i, c] if c >= 0 else 0.0


@jit
def kd_nearest(x, tree, states, weights, periodic, links, cut, root, stack, bounds, cell):
    """``(node, distance)``: the node of search tree ``tree`` nearest ``x``, the first of equals (the
    smallest index), as the scan finds it; ``(-1, inf)`` for an empty tree; a NaN in ``x``: the root
    and NaN (a scan's first NaN distance). Scratch: ``stack`` (int64) and ``bounds`` (one row of two per
    node, plus one) and ``cell`` (the state's size).

    A subtree is visited only when its cell may hold a node as near as the best so far: the cell's
    squared distance from ``x`` (the sum over coordinates of the squared weighted gap to the cell's slab,
    ``cell``, updated one coordinate per plane crossed) is not beyond the best's square. A stacked cell is
    ``(node, plane) (squared distance, squared gap to the plane)``; once entered, its row stays on the
    stack as a mark, ``(-1, plane) (_, the coordinate's former gap)``, that restores ``cell`` when the
    cell's subtree is done.

    A far side is written to the stack always and kept by the count, not by a branch (which far sides
    are kept is too irregular for the branch predictor), and is tested against the limit from before
    the node's own distance, so that the push need not wait for that distance: a larger limit only
    keeps more cells, and a cell too far by then is dropped when it is popped."""
    node = root[tree]
    if node < 0:
        return -1, math.inf
    d = x.shape[0]
    for c in range(d):
        if x[c] != x[c]:
            return node, math.nan
    for c in range(d):
        cell[c] = 0.0
    best, best_d, limit = -1, math.inf, math.inf
    stack[0, 0], stack[0, 1], bounds[0, 0], bounds[0, 1] = node, 0, 0.0, 0.0
    top = 1
    while top > 0:
        node, bound, top = kd_pop_cell(stack, bounds, cell, top, limit)
        while node >= 0:                             # down toward x, stacking the far sides
            c = links[node, SPLIT]
            if c >= 0:
                near, top = kd_stack_far_side(node, c, (x[c] - cut[node]) * weights[c], bound, limit, links, stack,
                                              bounds, cell, top)
            else:                                    # no splitting coordinate: a chain on the right
                near = links[node, RIGHT]
            acc = _squared_distance(states, node, x, weights, periodic)
            if acc <= limit:
                dist = math.sqrt(acc)
                if dist < best_d or (dist == best_d and node < best):
                    best, best_d = node, dist
                    limit = dist * dist * PRUNE_MARGIN + PRUNE_FLOOR
            node = near
    return best, best_d


class NearestIndex:
    """The k-d trees of a planner's search trees over its node store (see the module)."""

    def __init__(self, capacity: int, num_trees: int, weights: np.ndarray, periodic: np.ndarray) -> None:
        if capacity >= 2 ** 31:
            raise ValueError(f"a node capacity of {capacity}: the index holds node numbers as int32")
        self.links = np.full((capacity, 3), -1, dtype=np.int32)
        self.cut = np.zeros(capacity)
        self.root = np.full(num_trees, -1, dtype=np.int64)
        self.stack = np.zeros((capacity + 1, 2), dtype=np.int64)
        self.bounds = np.zeros((capacity + 1, 2))
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        self.periodic = np.ascontiguousarray(periodic, dtype=np.bool_)
        self.cell = np.zeros(len(self.weights))

    def insert(self, i: int, tree: int, states: np.ndarray) -> None:
        kd_insert(i, tree, states, self.periodic, self.links, self.cut, self.root)

    def nearest(self, x: np.ndarray, tree: int, states: np.ndarray) -> tuple[int, float]:
        return kd_nearest(x, tree, states, self.weights, self.periodic, self.links, self.cut, self.root,
                          self.stack, self.bounds, self.cell)
