"""The sphere checker's compiled kernel: sphere trees against obstacles and against each other, one
configuration (:func:`check_states`) or a whole edge (:func:`check_edge`, :func:`steer_edge`) per call.

A configuration collides when a leaf of a link's obstacle tree touches an obstacle, or a leaf of a
checked link pair's self-collision trees touches the other's (:mod:`gnn_mp_envs.robots.spheres.model`).
Trees are walked depth first from the root, so a link far from everything costs one test per obstacle.

Along an edge, the answer and the count are those of testing every state in the planner's order
(``b`` first, then by bisection; or from ``a`` to ``b``) up to the first invalid one, with less work.
``gaps[k, i]`` holds, for a state ``k`` known to be free, how many states away on either side (real
valued) link ``i``'s spheres stay clear of every obstacle (``i = link``), or a self pair's of each
other (``i = links + pair``). A walk that finds no touching leaves leaves a lower bound of the
distances (the least gap of the nodes it pruned); it becomes states through the motion bounds of
:mod:`gnn_mp_envs.robots.spheres.kinematics`. A self pair with a joint-space table
(:meth:`SphereChecker._joint_tables <gnn_mp_envs.robots.spheres.checker.SphereChecker._joint_tables>`)
is looked up instead of walked where its cell is free. So a link or pair that a checked neighbour
state vouches for is free without a test; an interval whose two checked ends vouch for every link
and pair across it is free as a whole, with the intervals under it (sequential order: the states
ahead are skipped the same way).

Edges start where earlier ones ended (a tree's nodes are the far ends of the edges that made them),
so the clearances the walks find at a free start or far end are remembered (the memo: the last
``MEMO_STATES`` such states, forgotten when the scene changes), and an edge whose start is one of
them takes them instead of walking again. They are lower bounds of distances, so only the work
depends on what the checker saw before, never an answer or a count. Everything is float64 and a pure
function of the configuration and the scene.

The kernel's arrays travel in six groups (:data:`GROUPS`, namedtuples); the compiled calls get one
table of their addresses and shapes (:func:`pack`) and view each group through it (``view_*``), as
arrays without a reference count (:mod:`gnn_mp_envs.utils.array_groups`).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.extending import intrinsic

from gnn_mp_envs.core.problem import ZERO_LENGTH
from gnn_mp_envs.robots.spheres.kinematics import (ROUND_DOWN, UNBOUNDED, forward_kinematics, motion_bounds, rate,
                                                   states_clear, velocities)
from gnn_mp_envs.utils.array_groups import GroupTable, array_group
from gnn_mp_envs.utils.compiled import jit

#: Obstacle kinds of the compiled tests.
BOX, CYLINDER, SPHERE = 0, 1, 2
KINDS = {"box": BOX, "cylinder": CYLINDER, "sphere": SPHERE}
#: Along an edge the tree walks refine distance bounds below this many states' motion (more work
#: per tested state, fewer tested states; chosen on the edges that planning checks on the val splits,
#: ``python -m tools.bench_planning_checks --refine R``).
REFINE = 1.0
#: Walks compare squared distances where they differ by more than this factor (far above rounding), so
#: that a node's pruning and the least clearance are those of comparing the distances themselves.
SQUARES_MARGIN = 1.0 + 1e-12


# ---------------------------------------------------------------------- the arrays, in groups
#: The robot's kinematic tree (:mod:`~gnn_mp_envs.robots.spheres.kinematics`), per link.
Kinematics = array_group("Kinematics", (("parent", np.int64, 1), ("origin_r", np.float64, 3),
                                        ("origin_t", np.float64, 2),
                                   ("kind", np.int64, 1), ("axis", np.float64, 2), ("q_index", np.int64, 1),
                                   ("q_fixed", np.float64, 1)))
#: The sphere trees (each link's obstacle tree's root, -1: none), the self pairs checked (two links, the roots of
#: their self-collision trees in those links' frames, and the link that moves in the other's frame, -1: neither)
#: and how far each joint can move a link's (a pair's) spheres. A pair's tree may cover several links rigidly
#: joined to its link
#: (:meth:`SphereChecker._body_pairs <gnn_mp_envs.robots.spheres.checker.SphereChecker._body_pairs>`).
Spheres = array_group("Spheres", (("link_root", np.int64, 1), ("nodes", np.float64, 2),
                             ("first_child", np.int64, 1), ("child_count", np.int64, 1), ("pairs", np.int64, 2),
                             ("pair_root", np.int64, 2), ("pair_moving", np.int64, 1), ("reach", np.float64, 2),
                             ("pair_reach", np.float64, 2)))
#: The self pairs' joint-space tables: per pair its offset in ``cells`` (-1: no table), joints, grid.
Tables = array_group("Tables", (("at", np.int64, 1), ("joint", np.int64, 2), ("low", np.float64, 2),
                                ("step", np.float64, 2),
                           ("dim", np.int64, 2), ("cells", np.int32, 1)))
#: The scene: per obstacle its kind (:data:`KINDS`), centre, rotation, size, and the links it may touch,
#: the obstacles in runs of one kind (boxes, cylinders, spheres: ``runs`` holds where each run ends); the same
#: numbers by coordinate (``columns``, rows :data:`COLUMNS`), and ``root_d2``, the working space of the
#: tests of a link's root sphere against every obstacle at once (:func:`_root_tests`).
Obstacles = array_group("Obstacles", (("kind", np.int64, 1), ("centre", np.float64, 2), ("rot", np.float64, 3),
                                 ("size", np.float64, 2), ("exempt", np.bool_, 2), ("runs", np.int64, 1),
                                 ("columns", np.float64, 2), ("root_d2", np.float64, 1)))
#: The rows of ``Obstacles.columns``: centre, rotation (row by row), size.
COLUMNS = 15
#: Working space: the configuration, link frames and velocities, walk stacks (the pair walk's with its points
#: in its first link's frame), an edge's bounds per state (``gaps``, ``known``), the bisection queue and the
#: edge's motion bounds per link and pair.
Scratch = array_group("Scratch", (("q", np.float64, 1), ("rot", np.float64, 3), ("trans", np.float64, 2),
                             ("omega", np.float64, 2), ("vel", np.float64, 2), ("stack", np.int64, 1),
                             ("pair_stack", np.int64, 2), ("pair_point", np.float64, 2), ("gaps", np.float64, 2),
                             ("known", np.bool_, 1), ("queue", np.int64, 2), ("delta", np.float64, 1),
                             ("pair_delta", np.float64, 1), ("curve", np.float64, 1), ("pair_curve", np.float64, 1),
                             ("pair_cell", np.float64, 1)))
#: The remembered edge ends: configurations (NaN: a row not valid), their walks' clearances per link and
#: pair (-1: not walked) and ``meta`` = (rows filled, next row to write).
Memo = array_group("Memo", (("q", np.float64, 2), ("clear", np.float64, 2), ("meta", np.int64, 1)))
#: The groups, in the table's order.
GROUPS = (Kinematics, Spheres, Tables, Obstacles, Scratch, Memo)
#: The kernel's table (:mod:`gnn_mp_envs.utils.array_groups`).
LAYOUT = GroupTable("spheres", GROUPS)
pack = LAYOUT.pack
view_kinematics = LAYOUT.viewer(Kinematics)
view_spheres = LAYOUT.viewer(Spheres)
view_tables = LAYOUT.viewer(Tables)
view_obstacles = LAYOUT.viewer(Obstacles)
view_scratch = LAYOUT.viewer(Scratch)
view_memo = LAYOUT.viewer(Memo)


# ---------------------------------------------------------------------- tests of one configuration
@jit(inline=True)
def _dist2(cx, cy, cz, kind, ox, oy, oz, r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz):
    """The squared distance from the point ``c`` to an obstacle's core (0 inside) and the radius the
    obstacle adds: a box of half extents ``s`` (adds 0), a cylinder of radius ``sx`` and half height
    ``sy`` along its z (adds 0), or a sphere of radius ``sx`` (its core is its centre, it adds ``sx``);
    centred at ``o``, rotated by ``R`` (rows ``r0*``, ``r1*``, ``r2*``). A sphere ``(c, r)`` is
    ``sqrt(d2) - r - adds`` from the obstacle (negative or zero: they touch; exact), so walks can compare
    squares and take the root only where the distance itself is needed. Scalars only: a compiled call
    with array arguments costs more than the test."""
    dx, dy, dz = cx - ox, cy - oy, cz - oz
    if kind == SPHERE:
        return dx * dx + dy * dy + dz * dz, sx
    lx = r00 * dx + r10 * dy + r20 * dz          # local = R^T d
    ly = r01 * dx + r11 * dy + r21 * dz
    lz = r02 * dx + r12 * dy + r22 * dz
    if kind == BOX:
        ex = abs(lx) - sx
        ey = abs(ly) - sy
        ez = abs(lz) - sz
        ex = ex if ex > 0.0 else 0.0
        ey = ey if ey > 0.0 else 0.0
        ez = ez if ez > 0.0 else 0.0
        return ex * ex + ey * ey + ez * ez, 0.0
    er = math.sqrt(lx * lx + ly * ly) - sx
    ez = abs(lz) - sy
    er = er if er > 0.0 else 0.0
    ez = ez if ez > 0.0 else 0.0
    return er * er + ez * ez, 0.0


@jit(inline=True)
def _root_tests(cx, cy, cz, obstacles):
    """``root_d2[o]``: :func:`_dist2` of the point ``c`` to every obstacle ``o`` (a link's root sphere's
    centre), in loops of one kind over the obstacles' columns that the compiler turns into SIMD lanes:
    the same operations on each obstacle as :func:`_dist2`, so the same floats."""
    col, out, runs = obstacles.columns, obstacles.root_d2, obstacles.runs
    for o in range(0, runs[0]):                          # boxes
        dx, dy, dz = cx - col[0, o], cy - col[1, o], cz - col[2, o]
        lx = col[3, o] * dx + col[6, o] * dy + col[9, o] * dz
        ly = col[4, o] * dx + col[7, o] * dy + col[10, o] * dz
        lz = col[5, o] * dx + col[8, o] * dy + col[11, o] * dz
        ex = abs(lx) - col[12, o]
        ey = abs(ly) - col[13, o]
        ez = abs(lz) - col[14, o]
        ex = ex if ex > 0.0 else 0.0
        ey = ey if ey > 0.0 else 0.0
        ez = ez if ez > 0.0 else 0.0
        out[o] = ex * ex + ey * ey + ez * ez
    for o in range(runs[0], runs[1]):                    # cylinders
        dx, dy, dz = cx - col[0, o], cy - col[1, o], cz - col[2, o]
        lx = col[3, o] * dx + col[6, o] * dy + col[9, o] * dz
        ly = col[4, o] * dx + col[7, o] * dy + col[10, o] * dz
        lz = col[5, o] * dx + col[8, o] * dy + col[11, o] * dz
        er = math.sqrt(lx * lx + ly * ly) - col[12, o]
        ez = abs(lz) - col[13, o]
        er = er if er > 0.0 else 0.0
        ez = ez if ez > 0.0 else 0.0
        out[o] = er * er + ez * ez
    for o in range(runs[1], runs[2]):                    # spheres
        dx, dy, dz = cx - col[0, o], cy - col[1, o], cz - col[2, o]
        out[o] = dx * dx + dy * dy + dz * dz


@jit(inline=True)
def _frame_in(a, b, rot, trans):
    """Link ``b``'s frame in link ``a``'s: ``u = R_a^T (t_b - t_a)`` and ``m = R_a^T R_b`` (row-major), so a
    point ``p`` of ``b``'s frame is at ``u + m p`` in ``a``'s."""
    ex, ey, ez = trans[b, 0] - trans[a, 0], trans[b, 1] - trans[a, 1], trans[b, 2] - trans[a, 2]
    u0 = rot[a, 0, 0] * ex + rot[a, 1, 0] * ey + rot[a, 2, 0] * ez
    u1 = rot[a, 0, 1] * ex + rot[a, 1, 1] * ey + rot[a, 2, 1] * ez
    u2 = rot[a, 0, 2] * ex + rot[a, 1, 2] * ey + rot[a, 2, 2] * ez
    m00 = rot[a, 0, 0] * rot[b, 0, 0] + rot[a, 1, 0] * rot[b, 1, 0] + rot[a, 2, 0] * rot[b, 2, 0]
    m01 = rot[a, 0, 0] * rot[b, 0, 1] + rot[a, 1, 0] * rot[b, 1, 1] + rot[a, 2, 0] * rot[b, 2, 1]
    m02 = rot[a, 0, 0] * rot[b, 0, 2] + rot[a, 1, 0] * rot[b, 1, 2] + rot[a, 2, 0] * rot[b, 2, 2]
    m10 = rot[a, 0, 1] * rot[b, 0, 0] + rot[a, 1, 1] * rot[b, 1, 0] + rot[a, 2, 1] * rot[b, 2, 0]
    m11 = rot[a, 0, 1] * rot[b, 0, 1] + rot[a, 1, 1] * rot[b, 1, 1] + rot[a, 2, 1] * rot[b, 2, 1]
    m12 = rot[a, 0, 1] * rot[b, 0, 2] + rot[a, 1, 1] * rot[b, 1, 2] + rot[a, 2, 1] * rot[b, 2, 2]
    m20 = rot[a, 0, 2] * rot[b, 0, 0] + rot[a, 1, 2] * rot[b, 1, 0] + rot[a, 2, 2] * rot[b, 2, 0]
    m21 = rot[a, 0, 2] * rot[b, 0, 1] + rot[a, 1, 2] * rot[b, 1, 1] + rot[a, 2, 2] * rot[b, 2, 1]
    m22 = rot[a, 0, 2] * rot[b, 0, 2] + rot[a, 1, 2] * rot[b, 1, 2] + rot[a, 2, 2] * rot[b, 2, 2]
    return u0, u1, u2, m00, m01, m02, m10, m11, m12, m20, m21, m22


@jit(inline=True)
def _pair_walk(la, lb, root_a, root_b, tau, floor, nodes, first_child, child_count, rot, trans, pair_stack,
               pair_point):
    """Whether a leaf under ``root_a`` (of link ``la``) and one under ``root_b`` (of ``lb``) are at most
    ``floor`` apart (``(True, ...)``), else ``(False, least)``: the least gap of the node pairs the walk
    pruned, a lower bound of every leaf pair's. Simultaneous descent from the roots, splitting the
    larger of two nodes nearer than ``tau`` (at least ``floor``) and than the least so far: the leaves
    under a node are no nearer than it, so one no nearer than the least can neither touch (the least
    is above ``floor``) nor lower it: the least stays a lower bound, no lower than without that test.

    A node pair's children are tested when it is split (:func:`_node_verdict`: squares first), and only
    those to split in turn are pushed. The walk measures in ``la``'s frame: ``lb``'s node centres are
    moved into it once, when tested (``pair_point``, beside ``pair_stack``), and ``la``'s are used as
    stored (the distance is the world one's: frames are rigid motions)."""
    u0, u1, u2, m00, m01, m02, m10, m11, m12, m20, m21, m22 = _frame_in(la, lb, rot, trans)
    x, y, z = nodes[root_b, 0], nodes[root_b, 1], nodes[root_b, 2]
    px, py, pz = u0 + m00 * x + m01 * y + m02 * z, u1 + m10 * x + m11 * y + m12 * z, u2 + m20 * x + m21 * y + m22 * z
    dx, dy, dz = nodes[root_a, 0] - px, nodes[root_a, 1] - py, nodes[root_a, 2] - pz
    verdict, least = _node_verdict(dx * dx + dy * dy + dz * dz, nodes[root_a, 3], nodes[root_b, 3], tau, floor,
                                   UNBOUNDED, child_count[root_a] == 0 and child_count[root_b] == 0)
    if verdict != DESCEND:
        return verdict == TOUCHES, least
    top = 0
    pair_stack[0, 0], pair_stack[0, 1] = root_a, root_b
    pair_point[0, 0], pair_point[0, 1], pair_point[0, 2] = px, py, pz
    while top >= 0:                         # pairs nearer than tau and the least: split the larger node
        na_, nb_ = pair_stack[top, 0], pair_stack[top, 1]
        px, py, pz = pair_point[top, 0], pair_point[top, 1], pair_point[top, 2]
        top -= 1
        ca, cb = child_count[na_], child_count[nb_]
        ra, rb = nodes[na_, 3], nodes[nb_, 3]
        split_a = cb == 0 or (ca > 0 and ra >= rb)
        split = na_ if split_a else nb_
        xa, ya, za = nodes[na_, 0], nodes[na_, 1], nodes[na_, 2]
        for c in range(first_child[split], first_child[split] + child_count[split]):
            if split_a:                     # a child of a's node against b's (its point as pushed)
                xa, ya, za, ra = nodes[c, 0], nodes[c, 1], nodes[c, 2], nodes[c, 3]
                qx, qy, qz = px, py, pz
                leaves = child_count[c] == 0 and cb == 0
            else:                           # a's node against a child of b's, moved into a's frame
                x, y, z, rb = nodes[c, 0], nodes[c, 1], nodes[c, 2], nodes[c, 3]
                qx = u0 + m00 * x + m01 * y + m02 * z
                qy = u1 + m10 * x + m11 * y + m12 * z
                qz = u2 + m20 * x + m21 * y + m22 * z
                leaves = ca == 0 and child_count[c] == 0
            dx, dy, dz = xa - qx, ya - qy, za - qz
            verdict, least = _node_verdict(dx * dx + dy * dy + dz * dz, ra, rb, tau, floor, least, leaves)
            if verdict == TOUCHES:
                return True, least
            if verdict == DESCEND:
                top += 1
                pair_stack[top, 0], pair_stack[top, 1] = (c, nb_) if split_a else (na_, c)
                pair_point[top, 0], pair_point[top, 1], pair_point[top, 2] = qx, qy, qz
    return False, least


@jit(inline=True)
def table_room(p, q, tables):
    """The entry of self pair ``p``'s joint-space table at ``q``: ``d >= 1`` when the cell of ``q`` and
    every cell fewer than ``d`` cells away from it (in each of the pair's joints) are free of contact
    between the pair, so every configuration less than ``d - 1`` cells from ``q`` is; 0 when the cell
    is not, or ``q`` lies outside the table."""
    index = 0
    for k in range(2):
        j = tables.joint[p, k]
        if j < 0:
            break
        cell = math.floor((q[j] - tables.low[p, k]) / tables.step[p, k])
        if cell < 0 or cell >= tables.dim[p, k]:
            return 0
        index = index * tables.dim[p, k] + cell
    return tables.cells[tables.at[p] + index]


@jit(inline=True)
def _carried(gaps, known, i, k, left, right):
    """Row ``i``'s clearance at state ``k`` (in states) that its checked neighbours ``left``, ``right``
    (-1: none) vouch for: theirs less the states between (<= 0: none)."""
    bound = -1.0
    if left >= 0 and known[left]:
        bound = gaps[left, i] - (k - left)
    if right >= 0 and known[right]:
        other = gaps[right, i] - (right - k)
        bound = other if other > bound else bound
    return bound


#: What a walk does with a node (:func:`_node_verdict`).
PRUNED, TOUCHES, DESCEND = 0, 1, 2


@jit(inline=True)
def _node_verdict(d2, r, adds, tau, floor, least, leaf):
    """A walk's step at a node of radius ``r`` whose centre is at squared distance ``d2`` from an obstacle's
    core (which ``adds`` to it), or from another node's centre (of radius ``adds``): ``(PRUNED, least)``
    with the node's gap taken into the least so far, ``(TOUCHES, least)`` for a leaf at most ``floor``
    away (0 for obstacles), ``(DESCEND, least)`` for a node nearer than ``tau`` (at least ``floor``). Squares
    first, the root (a long-latency instruction, a tenth of the kernel's time) only where needed: farther
    than tau by a margin far above rounding, the node is pruned; its distance counts only if it may be the
    least so far. A node no nearer than the least so far (above ``floor``) is pruned too: the leaves under
    it can neither touch nor lower the least: it stays a lower bound, no lower than without that test."""
    reach = tau + r + adds
    near = least + r + adds
    if d2 > reach * reach * SQUARES_MARGIN:
        if d2 < near * near * SQUARES_MARGIN:
            g = math.sqrt(d2) - r - adds
            least = g if g < least else least
        return PRUNED, least
    if d2 > near * near * SQUARES_MARGIN:
        return PRUNED, least
    g = math.sqrt(d2) - r - adds
    if g > tau or g >= least or (g > floor and leaf):
        return PRUNED, (g if g < least else least)
    return (TOUCHES if leaf else DESCEND), least


@jit(inline=True)
def _link_walk(link, root, tau, spheres, obstacles, scratch):
    """Whether a leaf of ``link``'s obstacle tree (at ``root``) touches an obstacle (``(True, _)``), else
    ``(False, clearance)``: the least gap of the nodes the walks pruned, a lower bound of the link's
    distance to every obstacle. Walks go on below nodes nearer than ``tau``. The root is tested against
    every obstacle at once (:func:`_root_tests`); most walks end there."""
    nodes, child_count, first_child, stack = spheres.nodes, spheres.child_count, spheres.first_child, scratch.stack
    ob_kind, ob_centre, ob_rot, ob_size = obstacles.kind, obstacles.centre, obstacles.rot, obstacles.size
    rot, trans = scratch.rot, scratch.trans
    t0, t1, t2 = trans[link, 0], trans[link, 1], trans[link, 2]
    m00, m01, m02 = rot[link, 0, 0], rot[link, 0, 1], rot[link, 0, 2]
    m10, m11, m12 = rot[link, 1, 0], rot[link, 1, 1], rot[link, 1, 2]
    m20, m21, m22 = rot[link, 2, 0], rot[link, 2, 1], rot[link, 2, 2]
    x, y, z, r = nodes[root, 0], nodes[root, 1], nodes[root, 2], nodes[root, 3]
    _root_tests(t0 + m00 * x + m01 * y + m02 * z, t1 + m10 * x + m11 * y + m12 * z, t2 + m20 * x + m21 * y + m22 * z,
                obstacles)
    # the link's least clearance so far: only a node nearer than it can lower it
    clearance = UNBOUNDED
    for o in range(ob_kind.shape[0]):
        if obstacles.exempt[o, link]:
            continue
        adds = ob_size[o, 0] if ob_kind[o] == SPHERE else 0.0
        verdict, clearance = _node_verdict(obstacles.root_d2[o], r, adds, tau, 0.0, clearance,
                                           child_count[root] == 0)
        if verdict == TOUCHES:
            return True, clearance
        if verdict == PRUNED:
            continue
        least = clearance
        stack[0] = root
        top = 0
        while top >= 0:                          # the root's children, then theirs where they are near
            node = stack[top]
            top -= 1
            for c in range(first_child[node], first_child[node] + child_count[node]):
                x, y, z, r_node = nodes[c, 0], nodes[c, 1], nodes[c, 2], nodes[c, 3]
                d2, adds = _dist2(t0 + m00 * x + m01 * y + m02 * z, t1 + m10 * x + m11 * y + m12 * z,
                                  t2 + m20 * x + m21 * y + m22 * z, ob_kind[o],
                                  ob_centre[o, 0], ob_centre[o, 1], ob_centre[o, 2],
                                  ob_rot[o, 0, 0], ob_rot[o, 0, 1], ob_rot[o, 0, 2], ob_rot[o, 1, 0],
                                  ob_rot[o, 1, 1], ob_rot[o, 1, 2], ob_rot[o, 2, 0], ob_rot[o, 2, 1],
                                  ob_rot[o, 2, 2], ob_size[o, 0], ob_size[o, 1], ob_size[o, 2])
                verdict, least = _node_verdict(d2, r_node, adds, tau, 0.0, least, child_count[c] == 0)
                if verdict == TOUCHES:
                    return True, clearance
                if verdict == DESCEND:
                    top += 1
                    stack[top] = c
        clearance = least
    return False, clearance


@jit(inline=True)
def _frames(ready, track, a, b, n, kinematics, scratch):
    """The link frames of ``scratch.q`` and, along the edge ``a -> b`` of ``n`` states (``track``), their
    velocities, unless ``ready`` (computed already for this configuration); True."""
    if not ready:
        forward_kinematics(scratch.q, kinematics.parent, kinematics.origin_r, kinematics.origin_t, kinematics.kind,
                           kinematics.axis, kinematics.q_index, kinematics.q_fixed, scratch.rot, scratch.trans)
        if track:
            velocities(a, b, n, kinematics.parent, kinematics.kind, kinematics.axis, kinematics.q_index, scratch.rot,
                       scratch.trans, scratch.omega, scratch.vel)
    return True


@jit(inline=True)
def _obstacles_hit(k, left, right, track, use, rec, a, b, n, kinematics, spheres, obstacles, scratch, memo):
    """Whether a link's spheres touch an obstacle at the configuration ``scratch.q``, and whether its frames
    are computed (:func:`_frames`, on the first link that needs them). ``track``: state ``k`` of the edge
    ``a -> b`` of ``n`` states (neighbours ``left``, ``right``), whose clearances in states go to ``gaps[k]``;
    ``use`` / ``rec``: the memo row whose clearances stand in for the walks / receive them (-1: none)."""
    gaps, curve, delta = scratch.gaps, scratch.curve, scratch.delta
    ready = False
    for link in range(spheres.link_root.shape[0]):
        root = spheres.link_root[link]
        if root < 0:
            continue
        if track:                                # the link's clearance to every obstacle, carried over
            bound = _carried(gaps, scratch.known, link, k, left, right)
            if bound > 0.0:
                gaps[k, link] = bound
                continue
        ready = _frames(ready, track, a, b, n, kinematics, scratch)
        # along an edge, walks go on below nodes nearer than tau: the bound they leave then vouches
        # for about REFINE states on either side
        speed = 0.0
        tau = 0.0
        if track:
            speed = rate(link, -1, root, spheres.nodes, scratch.rot, scratch.trans, scratch.omega, scratch.vel)
            tau = REFINE * speed + 0.5 * REFINE * REFINE * curve[link]
            linear = REFINE * delta[link]
            tau = linear if linear < tau else tau
        if use >= 0 and memo.clear[use, link] >= 0.0:
            gaps[k, link] = states_clear(memo.clear[use, link], speed, curve[link], delta[link])
            continue
        hit, clearance = _link_walk(link, root, tau, spheres, obstacles, scratch)
        if hit:
            return True, ready
        if rec >= 0:
            memo.clear[rec, link] = clearance
        if track:
            gaps[k, link] = states_clear(clearance, speed, curve[link], delta[link])
    return False, ready


@jit(inline=True)
def _self_hit(k, left, right, track, use, rec, a, b, n, kinematics, spheres, tables, scratch, memo, ready):
    """Whether a checked pair of links touch each other (simultaneous descent of their self-collision
    trees, or their joint-space table); the rest as :func:`_obstacles_hit` (``ready``: its frames are
    computed)."""
    gaps, q = scratch.gaps, scratch.q
    links = spheres.link_root.shape[0]
    for p in range(spheres.pairs.shape[0]):
        la, lb = spheres.pairs[p, 0], spheres.pairs[p, 1]
        root_a, root_b = spheres.pair_root[p, 0], spheres.pair_root[p, 1]
        row = links + p
        if track:
            bound = _carried(gaps, scratch.known, row, k, left, right)
            if bound > 0.0:
                gaps[k, row] = bound
                continue
        if tables.at[p] >= 0:
            room = table_room(p, q, tables)
            if room >= 1:                       # this state's cell and ``room - 1`` around it are free
                if track:
                    cell = scratch.pair_cell[p]
                    gaps[k, row] = (room - 1) / cell * ROUND_DOWN if cell > 0.0 else UNBOUNDED
                continue
        ready = _frames(ready, track, a, b, n, kinematics, scratch)
        speed = 0.0
        bend = 0.0                              # no speed measured: the global bound only
        tau = 0.0
        if track:
            tau = REFINE * scratch.pair_delta[p]
            moving = spheres.pair_moving[p]
            if moving >= 0:                     # one link below the other: it moves in the other's frame
                speed = rate(moving, la + lb - moving, root_a if moving == la else root_b, spheres.nodes, scratch.rot,
                             scratch.trans, scratch.omega, scratch.vel)
                bend = scratch.pair_curve[p]
                quadratic = REFINE * speed + 0.5 * REFINE * REFINE * bend
                tau = quadratic if quadratic < tau else tau
        if use >= 0 and memo.clear[use, row] >= 0.0:
            least = memo.clear[use, row]
        else:
            hit, least = _pair_walk(la, lb, root_a, root_b, tau, 0.0, spheres.nodes,
                                    spheres.first_child, spheres.child_count, scratch.rot, scratch.trans,
                                    scratch.pair_stack, scratch.pair_point)
            if hit:
                return True
            if rec >= 0:
                memo.clear[rec, row] = least
        if track:
            gaps[k, row] = states_clear(least, speed, bend, scratch.pair_delta[p])
    return False


@jit(inline=True)
def _collides(k, left, right, track, use, rec, a, b, n, kinematics, spheres, tables, obstacles, scratch, memo):
    """Whether the configuration ``scratch.q`` collides (see :func:`_obstacles_hit` for the rest). The link
    frames (and velocities) are computed when a link or pair first needs them: along an edge, a tested state
    whose links and pairs are all vouched for by its checked neighbours or a joint-space table needs none."""
    if track:
        for row in range(scratch.gaps.shape[1]):      # pairs never tested (exempt, no spheres) bound nothing
            scratch.gaps[k, row] = UNBOUNDED
    hit, ready = _obstacles_hit(k, left, right, track, use, rec, a, b, n, kinematics, spheres, obstacles, scratch,
                                memo)
    if hit:
        return True
    return _self_hit(k, left, right, track, use, rec, a, b, n, kinematics, spheres, tables, scratch, memo, ready)


# ---------------------------------------------------------------------- the entry points
@jit
def check_states(qs, out, table):
    """``out[i]``: whether row ``i`` of ``qs`` is collision-free (joint limits are the caller's)."""
    kinematics, spheres, tables = view_kinematics(table), view_spheres(table), view_tables(table)
    obstacles, scratch, memo = view_obstacles(table), view_scratch(table), view_memo(table)
    q = scratch.q
    for row in range(qs.shape[0]):
        for j in range(q.shape[0]):
            q[j] = qs[row, j]
        out[row] = not _collides(0, -1, -1, False, -1, -1, q, q, 1, kinematics, spheres, tables, obstacles,
                                 scratch, memo)
    return qs.shape[0]


@jit
def _position(n, k, bisection, queue):
    """Where state ``k`` comes in the planner's order of an edge of ``n`` states (0-based): ``k - 1``
    in sequence; by bisection, its place in ``n`` first, then the middles of ``1..n-1`` and of its
    halves breadth first (:func:`~gnn_mp_envs.robots.checkers.bisection_order`). ``queue``:
    scratch of at least ``2 n + 2`` rows."""
    if not bisection:
        return k - 1
    if k == n:
        return 0
    position = 1
    head, tail = 0, 1
    queue[0, 0], queue[0, 1] = 1, n - 1
    while head < tail:
        lo, hi = queue[head, 0], queue[head, 1]
        head += 1
        if lo > hi:
            continue
        mid = (lo + hi) // 2
        if mid == k:
            return position
        position += 1
        queue[tail, 0], queue[tail, 1] = lo, mid - 1
        queue[tail + 1, 0], queue[tail + 1, 1] = mid + 1, hi
        tail += 2
    return -1


@jit(inline=True)
def _memo_find(a, memo):
    """The memo row of configuration ``a`` (newest first; -1: not remembered)."""
    for m in range(memo.meta[0]):
        row = memo.meta[1] - 1 - m
        if row < 0:
            row += memo.q.shape[0]
        same = True
        for j in range(a.shape[0]):
            if memo.q[row, j] != a[j]:
                same = False
                break
        if same:
            return row
    return -1


@jit(inline=True)
def _memo_open(memo):
    """The memo row the next test fills in (not a valid row until the test ends free)."""
    slot = memo.meta[1]
    for j in range(memo.q.shape[1]):
        memo.q[slot, j] = math.nan
    for row in range(memo.clear.shape[1]):
        memo.clear[slot, row] = -1.0       # -1: not walked (carried over, a table, no spheres)
    return slot


@jit(inline=True)
def _memo_close(slot, q, memo):
    """Row ``slot`` holds configuration ``q`` (tested free) from now on."""
    for j in range(q.shape[0]):
        memo.q[slot, j] = q[j]
    memo.meta[1] = (slot + 1) % memo.q.shape[0]
    memo.meta[0] = min(memo.meta[0] + 1, memo.q.shape[0])


@jit(inline=True)
def _edge_length(a, b, resolution, low, high):
    """States of the edge ``a -> b`` (``n = max(1, ceil(|b - a| / resolution))``) and the last one inside
    the box ``[low, high]`` (``a`` is inside and the box convex: the states leave it once)."""
    dof = a.shape[0]
    acc = 0.0
    for j in range(dof):
        acc += (b[j] - a[j]) * (b[j] - a[j])
    n = max(1, math.ceil(math.sqrt(acc) / resolution))
    inside = True
    for j in range(dof):
        if not (low[j] <= b[j] <= high[j]):
            inside = False
    if inside:
        return n, n
    for k in range(1, n + 1):
        t = k / n
        out = False
        for j in range(dof):
            v = a[j] + t * (b[j] - a[j])
            if not (low[j] <= v <= high[j]):
                out = True
        if out:
            return n, k - 1
    return n, n


@jit(inline=True)
def _edge_rates(a, b, n, spheres, tables, scratch):
    """The edge's motion bounds per link and pair, and the cells of each pair's table crossed per state."""
    motion_bounds(a, b, n, spheres.reach, scratch.delta, scratch.curve)
    motion_bounds(a, b, n, spheres.pair_reach, scratch.pair_delta, scratch.pair_curve)
    for p in range(spheres.pairs.shape[0]):
        acc = 0.0
        for k in range(2):
            j = tables.joint[p, k]
            if j >= 0:
                r = abs(b[j] - a[j]) / n / tables.step[p, k]
                acc = r if r > acc else acc
        scratch.pair_cell[p] = acc
    for k in range(n + 1):
        scratch.known[k] = False


@jit(inline=True)
def _next_interval(head, tail, rows, scratch):
    """Bisection: the next interval of the queue whose checked ends do not vouch for all of it, as
    ``(found, its middle, left end, right end, interval low, high, next head)``."""
    queue, known, gaps = scratch.queue, scratch.known, scratch.gaps
    while head < tail:
        lo, hi = queue[head, 0], queue[head, 1]
        head += 1
        if lo > hi:
            continue
        left, right = lo - 1, hi + 1
        if known[left] and known[right]:
            free = True
            for i in range(rows):
                gl, gr = gaps[left, i], gaps[right, i]
                if not (gl > 0.0 and gr > 0.0 and gl + gr > right - left):
                    free = False
                    break
            if free:
                continue
        return True, (lo + hi) // 2, left, right, lo, hi, head
    return False, 0, -1, -1, 0, 0, head


@jit(inline=True)
def _skip_ahead(k_next, n, limit, rows, scratch):
    """In sequence: whether the last checked state's bounds vouch for the states ahead, as ``(what, next
    state)``; ``what``: 0 test the next state, 1 they vouch for the rest of the edge, 2 they vouch up to
    the returned state (known free, with bounds carried over: look again from there)."""
    known, gaps = scratch.known, scratch.gaps
    last = k_next - 1
    if not known[last]:
        return 0, k_next
    room = UNBOUNDED
    for i in range(rows):
        r = gaps[last, i]
        room = r if r < room else room
    skip = int(room) if room < 1e18 else n
    if room == skip:                    # the bound must exceed the motion strictly
        skip -= 1
    if skip < 1:
        return 0, k_next
    end = last + skip
    if end >= n and n <= limit:
        return 1, k_next
    if end > limit:
        end = limit
    for i in range(rows):
        gaps[end, i] = gaps[last, i] - (end - last)
    known[end] = True
    return 2, end + 1


@jit
def check_edge(a, b, resolution, low, high, bisection, table):
    """The edge ``a -> b`` (``a`` valid) of states ``a + (k / n)(b - a)``, ``k = 1..n``,
    ``n = max(1, ceil(|b - a| / resolution))``, in the planner's order (``bisection``: ``n`` first,
    then the middles of the remaining intervals breadth first; else ``1..n``), stopping at the first
    invalid state (out of the box ``[low, high]`` or in collision). Returns how many states that
    order looks at: the position of the first invalid state plus one (negated), or ``n``; 0 when the
    scratch holds fewer than ``n + 1`` states (the caller grows it and calls again). The same
    arithmetic as :class:`~gnn_mp_envs.robots.checkers.PybulletChecker`'s ``check_motion``.

    Phases: the start (``0``: its clearances, from the memo or walked; not a check), the far end
    (``1``: looked at first by bisection, before the start), the intervals (``2``: bisection) or the
    states in sequence (``3``)."""
    kinematics, spheres, tables = view_kinematics(table), view_spheres(table), view_tables(table)
    obstacles, scratch, memo = view_obstacles(table), view_scratch(table), view_memo(table)
    q, known, queue = scratch.q, scratch.known, scratch.queue
    rows = spheres.link_root.shape[0] + spheres.pairs.shape[0]
    n, limit = _edge_length(a, b, resolution, low, high)
    if n + 1 > known.shape[0]:
        return 0
    _edge_rates(a, b, n, spheres, tables, scratch)
    phase = 1 if bisection else 0       # bisection: the far end first, then the start (if that end is free)
    if bisection and limit < n:
        return -1                       # the far end, looked at first, is out of bounds
    k_next, head, tail, lo, hi = 1, 0, 0, 0, 0
    start_memo = -1                     # the memo row of the edge's start (-1: not remembered)
    while True:
        # ---- the next state to test: kk, with its checked neighbours left and right (-1: none)
        kk, left, right = 0, -1, -1
        if phase == 0:                  # the start: its bounds only (not a check)
            start_memo = _memo_find(a, memo)
        elif phase == 1:                # bisection: the far end first (the start is not known yet)
            kk = n
        elif phase == 2:                # bisection: the next interval that needs a test
            found, kk, left, right, lo, hi, head = _next_interval(head, tail, rows, scratch)
            if not found:
                return n
        else:                           # sequential: skip ahead while the last bounds vouch
            if k_next > n:
                return n
            if k_next > limit:
                return -(_position(n, k_next, bisection, queue) + 1)
            what, k_next = _skip_ahead(k_next, n, limit, rows, scratch)
            if what == 1:
                return n
            if what == 2:
                continue
            kk, left = k_next, k_next - 1
        if phase == 0:
            for j in range(q.shape[0]):
                q[j] = a[j]
        else:
            t = kk / n
            for j in range(q.shape[0]):
                q[j] = a[j] + t * (b[j] - a[j])
        # ---- test it: a start found in the memo reuses its clearances; a start not found and a far
        # end are remembered
        use = start_memo if phase == 0 else -1
        slot = _memo_open(memo) if phase == 1 or (phase == 0 and start_memo < 0) else -1
        rec = slot if slot >= 0 else use        # the memo row this test's walks fill in
        hit = _collides(kk, left, right, True, use, rec, a, b, n, kinematics, spheres, tables, obstacles, scratch,
                        memo)
        # ---- what follows from it
        if slot >= 0 and not hit:
            _memo_close(slot, q, memo)
        if phase == 0:
            known[0] = not hit          # a start in collision vouches for nothing
            phase = 2 if bisection else 3
        elif hit:
            return -(_position(n, kk, bisection, queue) + 1)
        else:
            known[kk] = True
            if phase == 1:              # then the start, for the bounds of the states between
                queue[0, 0], queue[0, 1] = 1, n - 1
                head, tail, phase = 0, 1, 0
            elif phase == 2:
                queue[tail, 0], queue[tail, 1] = lo, kk - 1
                queue[tail + 1, 0], queue[tail + 1, 1] = kk + 1, hi
                tail += 2
            else:
                k_next = kk + 1


@intrinsic
def _fma(typingctx, x, y, z):
    """``x * y + z`` rounded once (LLVM's ``llvm.fma.f64``: exact on every CPU, in hardware or not)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        f64 = ir.DoubleType()
        fma = cgutils.get_or_insert_function(builder.module, ir.FunctionType(f64, [f64, f64, f64]), "llvm.fma.f64")
        return builder.call(fma, args)

    return sig, codegen


@jit
def joint_distance(a, b):
    """``|a - b|`` (joint-space L2) of the arms' problems, the one definition their compiled and Python
    steps share (steering, goal connections): the squares summed in order with one fused multiply-add
    each (:func:`_fma`), so the same floats on every CPU. numpy's ``d @ d`` is not that: it rounds as
    the BLAS kernel the CPU selects does (fused on some CPUs, a rounded product then a sum on others, such
    as OpenBLAS's Haswell kernel)."""
    s = 0.0
    for j in range(a.shape[0]):
        dj = a[j] - b[j]
        s = _fma(dj, dj, s)
    return math.sqrt(s)


@jit
def steer_edge(a, target, step, resolution, low, high, bisection, table, x_new, distance):
    """Steer from ``a`` toward ``target`` by at most ``step`` (joint-space L2) and check that edge, in
    one call. ``distance[0]`` = :func:`joint_distance` of the two; below ``ZERO_LENGTH`` nothing else
    is done (answer 1). Else ``x_new`` = ``target`` when the distance is at most ``step``, else
    ``a + (step / distance)(target - a)``, and the answer is :func:`check_edge`'s for the edge
    ``a -> x_new``. The same floats as :class:`~gnn_mp_envs.robots.checkers.PybulletChecker`'s ``steer``."""
    dof = a.shape[0]
    d = joint_distance(target, a)
    distance[0] = d
    if d < ZERO_LENGTH:
        return 1
    if d <= step:
        for j in range(dof):
            x_new[j] = target[j]
    else:
        r = step / d
        for j in range(dof):
            x_new[j] = a[j] + r * (target[j] - a[j])
    return check_edge(a, x_new, resolution, low, high, bisection, table)


# ---------------------------------------------------------------------- the compiled planning loop's kernel
@jit
def planner_steer(a, target, step, context, x_new, distance):
    """:func:`steer_edge` with the context the planning loop holds (``table, low, high, resolution,
    bisection``; :mod:`gnn_mp_envs.core.loop`)."""
    table, low, high, resolution, bisection = context
    return steer_edge(a, target, step, resolution, low, high, bisection, table, x_new, distance)


@jit
def planner_motion(a, b, context):
    """:func:`check_edge` with the planning loop's context."""
    table, low, high, resolution, bisection = context
    return check_edge(a, b, resolution, low, high, bisection, table)


# ---------------------------------------------------------------------- building the tables
@jit
def free_cells(la, lb, root_a, root_b, joints, low, step, dim, floor, spin_axis, q, parent, origin_r, origin_t, kind,
               axis, q_index, q_fixed, nodes, first_child, child_count, rot, trans, pair_stack, pair_point, out):
    """``out[c]``: no leaf of link ``la``'s tree at ``root_a`` comes within ``floor`` of one of ``lb``'s
    at the centre of cell ``c`` of the grid of ``dim[k]`` cells of ``step[k]`` from ``low[k]`` over
    joints ``joints`` (row-major; ``joints[1] < 0``: one joint) with the other joints at ``q``; where
    ``spin_axis`` is not zero (``lb`` also turns about that axis of its frame, its own joint's), of the solid
    ``lb``'s leaves sweep at every angle of that joint (:func:`spun_pair_near`)."""
    spun = spin_axis[0] != 0.0 or spin_axis[1] != 0.0 or spin_axis[2] != 0.0
    for c in range(dim[0] * dim[1]):
        i0, i1 = c // dim[1], c % dim[1]
        q[joints[0]] = low[0] + (i0 + 0.5) * step[0]
        if joints[1] >= 0:
            q[joints[1]] = low[1] + (i1 + 0.5) * step[1]
        forward_kinematics(q, parent, origin_r, origin_t, kind, axis, q_index, q_fixed, rot, trans)
        if spun:
            out[c] = not spun_pair_near(la, lb, root_a, root_b, floor, spin_axis[0], spin_axis[1], spin_axis[2],
                                        nodes, first_child, child_count, rot, trans, pair_stack)
        else:
            hit, _ = _pair_walk(la, lb, root_a, root_b, floor, floor, nodes, first_child, child_count, rot, trans,
                                pair_stack, pair_point)
            out[c] = not hit


@jit(inline=True)
def _around_axis(x, y, z, ax, ay, az):
    """The point ``(x, y, z)``'s distance from the line through the origin along the unit ``a``, and its
    coordinate along it: a circle about that line, as ``(radius, height)``."""
    h = x * ax + y * ay + z * az
    rx, ry, rz = x - h * ax, y - h * ay, z - h * az
    return math.sqrt(rx * rx + ry * ry + rz * rz), h


@jit
def spun_pair_near(la, lb, root_a, root_b, floor, ax, ay, az, nodes, first_child, child_count, rot, trans,
                   pair_stack):
    """Whether a leaf under ``root_a`` (of link ``la``) comes within ``floor`` of the solid that a leaf
    under ``root_b`` sweeps as link ``lb`` turns about the line through its frame's origin along ``a`` (its
    own revolute joint's axis, unit, in its frame) by any angle: a sphere ``(c, r)`` of ``lb`` sweeps the
    points within ``r`` of the circle of ``c`` about that line, and the other's centre is as far from that
    circle as the two points ``(radius, height)`` about the line (:func:`_around_axis`) are apart, whatever
    the angle. Simultaneous descent from the roots (nested spheres sweep nested solids), splitting the
    larger of two nodes within ``floor``."""
    # la's frame in lb's: points p of la at R_b^T (R_a p + t_a - t_b)
    u0, u1, u2, m00, m01, m02, m10, m11, m12, m20, m21, m22 = _frame_in(lb, la, rot, trans)
    top = 0
    pair_stack[0, 0], pair_stack[0, 1] = root_a, root_b
    while top >= 0:
        na_, nb_ = pair_stack[top, 0], pair_stack[top, 1]
        top -= 1
        x, y, z = nodes[na_, 0], nodes[na_, 1], nodes[na_, 2]
        rho_a, h_a = _around_axis(u0 + m00 * x + m01 * y + m02 * z, u1 + m10 * x + m11 * y + m12 * z,
                                  u2 + m20 * x + m21 * y + m22 * z, ax, ay, az)
        rho_b, h_b = _around_axis(nodes[nb_, 0], nodes[nb_, 1], nodes[nb_, 2], ax, ay, az)
        ra, rb = nodes[na_, 3], nodes[nb_, 3]
        gap = math.sqrt((rho_a - rho_b) ** 2 + (h_a - h_b) ** 2) - ra - rb
        if gap > floor:
            continue
        ca, cb = child_count[na_], child_count[nb_]
        if ca == 0 and cb == 0:
            return True
        if cb == 0 or (ca > 0 and ra >= rb):
            for c in range(first_child[na_], first_child[na_] + ca):
                top += 1
                pair_stack[top, 0], pair_stack[top, 1] = c, nb_
        else:
            for c in range(first_child[nb_], first_child[nb_] + cb):
                top += 1
                pair_stack[top, 0], pair_stack[top, 1] = na_, c
    return False
