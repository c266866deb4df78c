"""The planner's nearest-neighbour index: an incremental, bucketed k-d tree per search tree, compiled (numba),
that answers exactly what a scan of the tree's nodes answers: the first node (the smallest index) at the
least distance under the problem's weighted metric (:func:`~gnn_mp_envs.core.problem._nearest_row_loop`).

A node joins its search tree's k-d tree once (no rebuilds) in a leaf of up to :data:`BUCKET` nodes, whose
states the leaf keeps by coordinate (a block: ``points[block, coordinate, slot]``) so that a query
compares a leaf's nodes in SIMD lanes from contiguous memory. A full leaf splits at the median of its
nodes on the coordinate of their widest weighted spread (periodic coordinates never: the gap to a plane
across a wrapped coordinate is not a bound); nodes that no such coordinate spreads chain another block
instead. A query descends to the query's leaf, then backs up into the far side of each plane only where
the plane is not farther than the best distance so far (with a margin far above rounding). It compares
squared distances and takes the square root, as the scan does, only of those within that margin of the
best, so every distance it compares is the scan's; ties go to the smallest node index. So the answer is
the scan's, bit for bit, at a cost that grows with the depth of the tree rather than its size: the
Fetch's trees reach 30,000 nodes in 8 dimensions. Compared with one node per k-d node (the tree this
replaced), a leaf's nodes are compared from one block rather than reached one by one through the tree,
and the median splits keep the tree balanced. The tree GNN's causal k-nearest queries walk the same
trees (:func:`kd_pop_cell`, :func:`kd_stack_far_side`) with their own metric
(``agents/tree/compiled.py``).

:class:`IndexArrays` (``n``: node capacity, ``t`` search trees; a k-d node is an internal node or a
leaf): ``links`` (int32, a k-d node's left and right child and its splitting coordinate, -1 for none: a
leaf), ``cut`` (its splitting value: a node's state below it goes left), ``leaf`` (a leaf's first block);
per block its ``fill``, the next block of its leaf (``chain``, -1: none), its ``points`` and their node
numbers (``ids``); per search tree its ``root``, -1 while empty; ``used``
(k-d nodes and blocks handed out); scratch: ``stack``, ``bounds``, ``cell``, ``squares`` (a block's squared
distances; a splitting leaf's values).
"""
from __future__ import annotations

import math

import numpy as np

from gnn_mp_envs.utils.array_groups import array_group
from gnn_mp_envs.utils.compiled import jit

#: A cell is skipped, and a node's square root not taken, when its squared distance exceeds the best
#: squared distance by this factor plus :data:`PRUNE_FLOOR`: far above the rounding of either, so no node
#: that could tie or win is passed over.
PRUNE_MARGIN = 1.0 + 1e-9
#: The margin's absolute part, for distances so small that their squares lose precision (subnormal).
PRUNE_FLOOR = 2.0 ** -1000
#: ``links`` columns.
LEFT, RIGHT, SPLIT = 0, 1, 2
#: Nodes per block of a leaf: their distances are computed in SIMD lanes (16 measured best on the Fetch's
#: trees against 32 and 64).
BUCKET = 16
#: The index's arrays (see the module), as the compiled planning loop's table holds them.
IndexArrays = array_group("IndexArrays", (
    ("weights", np.float64, 1), ("periodic", np.bool_, 1), ("links", np.int32, 2), ("cut", np.float64, 1),
    ("leaf", np.int64, 1), ("fill", np.int64, 1), ("chain", np.int64, 1), ("points", np.float64, 3),
    ("ids", np.int64, 2), ("root", np.int64, 1), ("used", np.int64, 1),
    ("stack", np.int64, 2), ("bounds", np.float64, 2), ("cell", np.float64, 1), ("squares", np.float64, 1)))


@jit(inline=True)
def kd_pop_cell(stack, bounds, cell, top, limit):
    """The next stacked cell of a query: ``(node, its squared distance, new top)``; node -1 when the top row
    was a mark (the cell ``cell`` is restored) or a cell farther than ``limit`` (dropped). An entered
    cell's row stays as a mark holding its coordinate's former gap (see :func:`index_nearest`)."""
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


@jit(inline=True)
def _block_squares(x, block, fill, weights, periodic, points, out):
    """``out[j]``: the scan's sum of squares (:func:`~gnn_mp_envs.core.problem._nearest_row_loop`) from
    slot ``j`` of ``block`` to ``x``, ``j < fill``: the same operations in the same order per point, one
    coordinate at a time over the block's column, so the loop over points runs in SIMD lanes (a periodic
    coordinate takes the scan's wrap)."""
    for j in range(fill):
        out[j] = 0.0
    for c in range(x.shape[0]):
        xc, wc = x[c], weights[c]
        column = points[block, c]
        if periodic[c]:
            for j in range(fill):
                v = column[j] - xc
                a = v + math.pi
                v = ((a if 0.0 < a < 2 * math.pi else a % (2 * math.pi)) - math.pi) * wc
                out[j] += v * v
        else:
            for j in range(fill):
                v = (column[j] - xc) * wc
                out[j] += v * v


@jit(inline=True)
def _split_leaf(node, block, i, states, ix):
    """Split the full leaf ``node`` (its one block ``block``) with node ``i`` joining it: on the
    coordinate (not periodic) of the widest weighted spread of its points, at their median, the points
    below it to a new leaf on ``block``, the rest to a new leaf on a new block. False where no such
    coordinate spreads them (it does not split: the caller chains a block)."""
    links, cut, leaf, fill, points, ids, used = ix.links, ix.cut, ix.leaf, ix.fill, ix.points, ix.ids, ix.used
    weights, periodic = ix.weights, ix.periodic
    k = fill[block]
    best_c, best_spread = -1, 0.0
    for c in range(states.shape[1]):
        if periodic[c]:
            continue
        lo, hi = states[i, c], states[i, c]
        for j in range(k):
            v = points[block, c, j]
            lo = v if v < lo else lo
            hi = v if v > hi else hi
        spread = (hi - lo) * weights[c]
        if spread > best_spread:
            best_c, best_spread = c, spread
    if best_c < 0:
        return False
    values = ix.squares                       # scratch: the k + 1 values, sorted by insertion
    values[0] = states[i, best_c]
    for j in range(k):
        v = points[block, best_c, j]
        m = j + 1
        while m > 0 and values[m - 1] > v:
            values[m] = values[m - 1]
            m -= 1
        values[m] = v
    at = values[(k + 1) // 2]
    if at == values[0]:                       # below the median, nothing: the next value up (one exists)
        for j in range(k + 1):
            if values[j] > at:
                at = values[j]
                break
    left, right = used[0], used[0] + 1        # two new leaves; ``node`` becomes their parent
    new_block = used[1]
    used[0] += 2
    used[1] += 1
    for m, b in ((left, block), (right, new_block)):
        links[m, LEFT], links[m, RIGHT], links[m, SPLIT] = -1, -1, -1
        leaf[m] = b
    links[node, LEFT], links[node, RIGHT], links[node, SPLIT] = left, right, best_c
    cut[node] = at
    leaf[node] = -1
    kept = 0
    fill[new_block] = 0
    for j in range(k):                        # in place: the kept points move down, the others out
        g = ids[block, j]
        b = block if points[block, best_c, j] < at else new_block
        s = kept if b == block else fill[new_block]
        for c in range(states.shape[1]):
            points[b, c, s] = points[block, c, j]
        ids[b, s] = g
        if b == block:
            kept += 1
        else:
            fill[new_block] += 1
    fill[block] = kept
    ix.chain[block], ix.chain[new_block] = -1, -1
    return True


@jit
def index_insert(i, tree, states, ix):
    """Add node ``i`` (a row of ``states``) to search tree ``tree``'s index; nothing when it is there
    already (a leaf's ids are looked through), so a repeated insert cannot hold a node twice."""
    links, cut, leaf, fill, chain, points, ids, used = ix.links, ix.cut, ix.leaf, ix.fill, ix.chain, ix.points, \
        ix.ids, ix.used
    node = ix.root[tree]
    if node < 0:                              # the tree's first node: a leaf with an empty block
        node, block = used[0], used[1]
        used[0] += 1
        used[1] += 1
        links[node, LEFT], links[node, RIGHT], links[node, SPLIT] = -1, -1, -1
        leaf[node], fill[block], chain[block] = block, 0, -1
        ix.root[tree] = node
    while links[node, SPLIT] >= 0:
        c = links[node, SPLIT]
        node = links[node, RIGHT] if states[i, c] >= cut[node] else links[node, LEFT]
    block = leaf[node]
    last = block
    while last >= 0:                          # already there?
        for j in range(fill[last]):
            if ids[last, j] == i:
                return
        block = last
        last = chain[last]
    if fill[block] == BUCKET:
        if block == leaf[node] and chain[block] < 0 and _split_leaf(node, block, i, states, ix):
            c = links[node, SPLIT]
            node = links[node, RIGHT] if states[i, c] >= cut[node] else links[node, LEFT]
            block = leaf[node]
        else:                                 # no coordinate splits the points: a block chained on
            chain[block] = used[1]
            block = used[1]
            used[1] += 1
            fill[block], chain[block] = 0, -1
    j = fill[block]
    for c in range(states.shape[1]):
        points[block, c, j] = states[i, c]
    ids[block, j] = i
    fill[block] = j + 1


@jit
def _scan_every_leaf(x, root, ix):
    """:func:`index_nearest` for a query with a NaN or an infinite coordinate (the scan's distances may
    be NaN: it answers the first NaN, else the first least): every leaf under ``root``, no pruning."""
    links, leaf, fill, chain, ids, squares, stack = ix.links, ix.leaf, ix.fill, ix.chain, ix.ids, ix.squares, ix.stack
    best, best_d, first_nan = -1, math.inf, -1
    stack[0, 0] = root
    top = 1
    while top > 0:
        top -= 1
        node = stack[top, 0]
        if links[node, SPLIT] >= 0:
            stack[top, 0], stack[top + 1, 0] = links[node, LEFT], links[node, RIGHT]
            top += 2
            continue
        block = leaf[node]
        while block >= 0:
            _block_squares(x, block, fill[block], ix.weights, ix.periodic, ix.points, squares)
            for j in range(fill[block]):
                dist, g = math.sqrt(squares[j]), ids[block, j]
                if dist != dist:
                    first_nan = g if first_nan < 0 or g < first_nan else first_nan
                elif best < 0 or dist < best_d or (dist == best_d and g < best):
                    best, best_d = g, dist
            block = chain[block]
    return (first_nan, math.nan) if first_nan >= 0 else (best, best_d)


@jit
def index_nearest(x, tree, ix):
    """``(node, distance)``: the node of search tree ``tree`` nearest ``x``, the first of equals (the
    smallest index), as the scan finds it; ``(-1, inf)`` for an empty tree; for a query with a NaN or
    an infinite coordinate, the scan's answer from every leaf (:func:`_scan_every_leaf`).

    A subtree is visited only when its cell may hold a node as near as the best so far: the cell's
    squared distance from ``x`` (the sum over coordinates of the squared weighted gap to the cell's
    slab, ``cell``, updated one coordinate per plane crossed) is not beyond the best's square
    (:func:`kd_pop_cell`, :func:`kd_stack_far_side`). A leaf's points are compared block by block
    (:func:`_block_squares`); the square root is taken only of those within the margin of the best."""
    node = ix.root[tree]
    if node < 0:
        return -1, math.inf
    d = x.shape[0]
    for c in range(d):
        if not math.isfinite(x[c]):
            return _scan_every_leaf(x, node, ix)
    links, cut, leaf, fill, chain, ids, squares = ix.links, ix.cut, ix.leaf, ix.fill, ix.chain, ix.ids, ix.squares
    stack, bounds, cell, weights = ix.stack, ix.bounds, ix.cell, ix.weights
    for c in range(d):
        cell[c] = 0.0
    best, best_d, limit = -1, math.inf, math.inf
    stack[0, 0], stack[0, 1], bounds[0, 0], bounds[0, 1] = node, 0, 0.0, 0.0
    top = 1
    while top > 0:
        node, bound, top = kd_pop_cell(stack, bounds, cell, top, limit)
        if node < 0:
            continue
        while links[node, SPLIT] >= 0:            # down toward x, stacking the far sides
            c = links[node, SPLIT]
            node, top = kd_stack_far_side(node, c, (x[c] - cut[node]) * weights[c], bound, limit, links, stack,
                                          bounds, cell, top)
        block = leaf[node]
        while block >= 0:
            k = fill[block]
            _block_squares(x, block, k, weights, ix.periodic, ix.points, squares)
            for j in range(k):
                acc = squares[j]
                if acc <= limit:
                    dist = math.sqrt(acc)
                    g = ids[block, j]
                    if best < 0 or dist < best_d or (dist == best_d and g < best):
                        best, best_d = g, dist
                        limit = dist * dist * PRUNE_MARGIN + PRUNE_FLOOR
            block = chain[block]
    return best, best_d


class NearestIndex:
    """The bucketed k-d trees of a planner's search trees (see the module); ``arrays``: the
    :class:`IndexArrays` the compiled calls read."""

    def __init__(self, capacity: int, num_trees: int, weights: np.ndarray, periodic: np.ndarray) -> None:
        if capacity >= 2 ** 31:
            raise ValueError(f"a node capacity of {capacity}: the index holds its k-d nodes as int32")
        weights = np.ascontiguousarray(weights, dtype=np.float64)
        dim = len(weights)
        blocks = capacity + num_trees         # a block holds at least one node
        nodes = 2 * blocks
        # empty, not zeros: every entry is written before it is read (a k-d node's and a block's when they are
        # handed out, a slot's when a node joins it), and zeroing megabytes would cost more than a reset's rest
        empty = np.empty
        self.arrays = IndexArrays(
            weights=weights, periodic=np.ascontiguousarray(periodic, dtype=np.bool_),
            links=empty((nodes, 3), dtype=np.int32), cut=empty(nodes), leaf=empty(nodes, dtype=np.int64),
            fill=empty(blocks, dtype=np.int64), chain=empty(blocks, dtype=np.int64),
            points=empty((blocks, dim, BUCKET)), ids=empty((blocks, BUCKET), dtype=np.int64),
            root=np.full(num_trees, -1, dtype=np.int64), used=np.zeros(2, dtype=np.int64),
            stack=empty((nodes + 1, 2), dtype=np.int64), bounds=empty((nodes + 1, 2)), cell=empty(dim),
            squares=empty(BUCKET + 1))

    def clear(self) -> None:
        """Empty every search tree (the arrays are kept)."""
        self.arrays.root[:] = -1
        self.arrays.used[:] = 0

    def take(self, other: "NearestIndex") -> None:
        """Hold what ``other`` (of at most this capacity, the same trees and metric) holds: a grown index."""
        a, b = self.arrays, other.arrays
        nodes, blocks = int(b.used[0]), int(b.used[1])
        if len(b.root) != len(a.root) or len(b.fill) > len(a.fill) or b.points.shape[1] != a.points.shape[1]:
            raise ValueError("an index takes one of at most its capacity, with as many trees and dimensions")
        for name in ("links", "cut", "leaf"):
            getattr(a, name)[:nodes] = getattr(b, name)[:nodes]
        for name in ("fill", "chain", "points", "ids"):
            getattr(a, name)[:blocks] = getattr(b, name)[:blocks]
        a.root[:], a.used[:] = b.root, b.used

    def insert(self, i: int, tree: int, states: np.ndarray) -> None:
        index_insert(i, tree, states, self.arrays)

    def nearest(self, x: np.ndarray, tree: int, states: np.ndarray) -> tuple[int, float]:
        """The scan's answer for ``x`` in ``tree`` (``states``: the node store the indexed rows came from;
        the index answers from its own copies of them)."""
        return index_nearest(x, tree, self.arrays)
