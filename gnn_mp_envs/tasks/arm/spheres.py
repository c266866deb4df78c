"""The compiled sphere checker: forward kinematics, sphere trees that cover each link's collision
geometry, exact sphere-vs-box / cylinder / sphere tests and self-collision, one call per edge.

A robot's sphere model (made by ``python -m tools.spherize`` from its mesh files, see
:mod:`gnn_mp_envs.tasks.arm.spherize`) holds, per link, a tree of spheres in the link's frame: the
root bounds the link, each inner node bounds its children, and the leaves (the fine spheres)
cover the link's convex hulls grown by the model's margin. A configuration collides when a leaf
touches an obstacle, or a leaf of another link that may not touch it (the pairs pybullet checks:
every pair but parent-child links and the robot's allowed-collision pairs). The trees are walked
from the root, so a link far from everything costs one test per obstacle.

:meth:`SphereChecker.check_edge` checks the states of a whole edge in one compiled call, in the
order it is given (the far end first, then by bisection), and stops at the first invalid one; each
state it looks at is one collision check, as with the pybullet checker. States are skipped only where
certified bounds vouch for them: how far and how fast each link can move along the edge, and, for
self pairs that only the wrist's one or two joints move, a joint-space table of where they are free.
Everything is float64 and a pure function of the configuration and the scene.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gnn_mp_envs.core.problem import ZERO_LENGTH
from gnn_mp_envs.tasks.arm.urdf import FIXED, PRISMATIC, REVOLUTE, URDFRobot, read_urdf
from llvmlite import ir
from numba import carray, types
from numba.core import cgutils
from numba.core.extending import intrinsic

#: Obstacle kinds of the compiled tests.
BOX, CYLINDER, SPHERE = 0, 1, 2
_KINDS = {"box": BOX, "cylinder": CYLINDER, "sphere": SPHERE}
#: Along an edge the tree walks refine distance bounds below this many states' motion (more work
#: per tested state, fewer tested states; measured with tools/bench_checker.py).
REFINE = 2.0
#: Joint-space tables of the wrist's self pairs (:meth:`SphereChecker._joint_tables`): a cell is free
#: when the pair's leaves are more than this apart at its centre (m); smaller: finer tables.
TABLE_FLOOR = 0.003
#: At most this many cells per pair's table (a coarser grid, with a higher floor, past it).
TABLE_CELLS = 1 << 17
#: How many tested edge ends (free far ends and starts) the checker remembers, with the clearances their
#: walks found, so that an edge starting at one (the tree's nodes are the far ends of the edges that
#: made them) need not walk again.
MEMO_STATES = 128
_TABLES: dict[tuple, tuple] = {}
#: Walks compare squared distances where they differ by more than this factor (far above rounding), so
#: that a node's pruning and the least clearance are those of comparing the distances themselves.
SQUARES_MARGIN = 1.0 + 1e-12
#: Format tag of the sphere model files.
MODEL_FORMAT = "gnn-mp-envs sphere model, version 1"


# ---------------------------------------------------------------------- what the kernel reads
#: Every array the kernel reads, in the order of its table (:meth:`SphereChecker._pack`): name, dtype,
#: dimensions.
_FIELDS = (("q", np.float64, 1), ("gaps", np.float64, 2), ("known", np.bool_, 1), ("reach", np.float64, 2),
           ("pair_reach", np.float64, 2), ("delta", np.float64, 1), ("pdelta", np.float64, 1),
           ("curve", np.float64, 1), ("pcurve", np.float64, 1), ("omega", np.float64, 2), ("vel", np.float64, 2),
           ("queue", np.int64, 2), ("parent", np.int64, 1), ("origin_r", np.float64, 3),
           ("origin_t", np.float64, 2), ("kind", np.int64, 1), ("axis", np.float64, 2), ("q_index", np.int64, 1),
           ("q_fixed", np.float64, 1), ("link_root", np.int64, 1), ("self_root", np.int64, 1),
           ("nodes", np.float64, 2), ("first_child", np.int64, 1), ("child_count", np.int64, 1),
           ("pairs", np.int64, 2), ("exempt", np.bool_, 2), ("ob_kind", np.int64, 1), ("ob_centre", np.float64, 2),
           ("ob_rot", np.float64, 3), ("ob_size", np.float64, 2), ("rot", np.float64, 3), ("trans", np.float64, 2),
           ("stack", np.int64, 1), ("pair_stack", np.int64, 2), ("pair_moving", np.int64, 1), ("pcell", np.float64, 1),
           ("table_at", np.int64, 1), ("table_joint", np.int64, 2), ("table_low", np.float64, 2),
           ("table_step", np.float64, 2), ("table_dim", np.int64, 2), ("table", np.int32, 1),
           ("memo_q", np.float64, 2), ("memo_clear", np.float64, 2), ("memo_meta", np.int64, 1))


@intrinsic
def _voidptr(typingctx, address):
    """The int64 ``address`` as a ``void*`` (for :func:`numba.carray`)."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return types.voidptr(types.int64), codegen


def _view1(table, i, dtype):
    """Row ``i`` of the kernel's table as the 1-D array it describes (no reference count: see ``_pack``)."""
    return carray(_voidptr(table[i, 0]), (table[i, 1],), dtype)


def _view2(table, i, dtype):
    """Row ``i`` of the kernel's table as a 2-D array."""
    return carray(_voidptr(table[i, 0]), (table[i, 1], table[i, 2]), dtype)


def _view3(table, i, dtype):
    """Row ``i`` of the kernel's table as a 3-D array."""
    return carray(_voidptr(table[i, 0]), (table[i, 1], table[i, 2], table[i, 3]), dtype)


# ---------------------------------------------------------------------- the model file
@dataclass(frozen=True)
class SphereModel:
    """Per-link sphere trees of one robot, in link frames: two per link, one tested against
    obstacles (``roots``: the tightest, where the dataset's starts and goals come closest to
    obstacles) and one against the robot's other links (``self_roots``: looser, so fewer leaves;
    self-clearances are larger).

    ``nodes``: ``(n, 4)`` centre and radius of every tree node; ``first_child`` / ``child_count``:
    each node's children (consecutive rows; 0 children: a leaf, a fine sphere); ``roots`` /
    ``self_roots``: link name -> its tree's root row. ``meta``: margin, overshoot per link, source
    files, the command that made it."""

    nodes: np.ndarray
    first_child: np.ndarray
    child_count: np.ndarray
    roots: dict[str, int]
    self_roots: dict[str, int]
    meta: dict[str, Any]

    @property
    def margin(self) -> float:
        """How far beyond each link's convex hulls the leaves reach at least (m)."""
        return float(self.meta["margin"])

    def leaves(self, link: str, self_collision: bool = False) -> np.ndarray:
        """The fine spheres ``(k, 4)`` of ``link``: the leaves of its obstacle tree (or of its
        self-collision tree)."""
        out, stack = [], [(self.self_roots if self_collision else self.roots)[link]]
        while stack:
            i = stack.pop()
            if self.child_count[i] == 0:
                out.append(i)
            else:
                stack.extend(range(self.first_child[i], self.first_child[i] + self.child_count[i]))
        return self.nodes[sorted(out)]

    def save(self, path: str | Path) -> None:
        names = sorted(self.roots, key=self.roots.get)
        np.savez_compressed(path, nodes=self.nodes, first_child=self.first_child, child_count=self.child_count,
                            root_names=np.array(names), root_rows=np.array([self.roots[n] for n in names]),
                            self_root_rows=np.array([self.self_roots[n] for n in names]),
                            meta=np.array(json.dumps({"format": MODEL_FORMAT, **self.meta}, sort_keys=True)))


@lru_cache(maxsize=8)
def load_sphere_model(path: str | Path) -> SphereModel:
    """A sphere model file (``.npz``, read without pickle)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"sphere model {path} is missing: reinstall gnn-mp-envs or regenerate it with "
                                "`python -m tools.spherize`")
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        if meta.get("format") != MODEL_FORMAT:
            raise ValueError(f"{path}: not a sphere model of this version ({meta.get('format')!r})")
        names = [str(n) for n in data["root_names"]]
        return SphereModel(data["nodes"].astype(np.float64), data["first_child"].astype(np.int64),
                           data["child_count"].astype(np.int64),
                           {n: int(r) for n, r in zip(names, data["root_rows"])},
                           {n: int(r) for n, r in zip(names, data["self_root_rows"])}, meta)


def build_tree(leaves: np.ndarray, coarse: np.ndarray | None = None, branching: int = 8, leaf_size: int = 8,
               seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sphere tree over ``leaves`` ``(k, 4)``: nodes in breadth-first order (root first, each
    node's children consecutive), every inner node a sphere containing the leaves below it.

    With ``coarse`` (a few spheres covering the same shape more loosely), the root's children are
    one node per coarse sphere: its centre, grown to contain the leaves assigned to it (each leaf
    to the coarse sphere it sticks out of least), so that the second level is a coarse cover of the
    link; below, groups of about ``branching`` by k-means of the centres down to ``leaf_size``.
    Returns ``nodes``, ``first_child``, ``child_count``."""
    from gnn_mp_envs.tasks.arm.spherize import bounding_sphere, group_spheres
    nodes: list[np.ndarray] = []
    first: list[int] = []
    count: list[int] = []
    queue: list[tuple[np.ndarray, np.ndarray | None]] = [(np.arange(len(leaves)), None)]   # (leaf rows, sphere)
    for k, (members, sphere) in enumerate(queue):
        if len(members) == 1 and sphere is None:   # a leaf: the fine sphere itself
            nodes.append(leaves[members[0]])
            first.append(0)
            count.append(0)
            continue
        nodes.append(bounding_sphere(leaves[members]) if sphere is None else sphere)
        if k == 0 and coarse is not None and len(coarse) > 1:
            out = (np.linalg.norm(leaves[:, None, :3] - coarse[None, :, :3], axis=2) + leaves[:, None, 3]
                   - coarse[None, :, 3])
            owner = out.argmin(axis=1)
            groups = []
            for g in range(len(coarse)):
                rows = np.flatnonzero(owner == g)
                if len(rows):
                    reach = float((np.linalg.norm(leaves[rows, :3] - coarse[g, :3], axis=1) + leaves[rows, 3]).max())
                    groups.append((rows, np.r_[coarse[g, :3], max(reach, coarse[g, 3]) * (1 + 1e-9)]))
        elif len(members) <= leaf_size:
            groups = [(members[i:i + 1], None) for i in range(len(members))]
        else:
            _, parts = group_spheres(leaves[members], size=max(1, len(members) // branching), seed=seed)
            groups = [(members[p], None) for p in parts]
            if len(groups) == 1:              # k-means could not split: halves along the longest axis
                axis = int(np.argmax(np.ptp(leaves[members, :3], axis=0)))
                order = members[np.argsort(leaves[members, axis], kind="stable")]
                groups = [(order[: len(order) // 2], None), (order[len(order) // 2:], None)]
        first.append(len(queue))
        count.append(len(groups))
        queue.extend(groups)
    return np.array(nodes, dtype=np.float64), np.array(first, dtype=np.int64), np.array(count, dtype=np.int64)


# ---------------------------------------------------------------------- compiled kernels
def _forward_kinematics(q, parent, origin_r, origin_t, kind, axis, q_index, q_fixed, rot, trans):
    """Link frames ``rot[l]``, ``trans[l]`` (world) at configuration ``q``: each link's parent frame
    times its joint's origin, then the joint's rotation about (translation along) its axis."""
    for link in range(parent.shape[0]):
        p = parent[link]
        if p < 0:
            for i in range(3):
                for j in range(3):
                    rot[link, i, j] = 1.0 if i == j else 0.0
                trans[link, i] = 0.0
            continue
        v = q[q_index[link]] if q_index[link] >= 0 else q_fixed[link]
        # parent * origin (an identity origin rotation: the parent's, the same floats without the products)
        plain = (origin_r[link, 0, 0] == 1.0 and origin_r[link, 1, 1] == 1.0 and origin_r[link, 2, 2] == 1.0
                 and origin_r[link, 0, 1] == 0.0 and origin_r[link, 0, 2] == 0.0 and origin_r[link, 1, 0] == 0.0
                 and origin_r[link, 1, 2] == 0.0 and origin_r[link, 2, 0] == 0.0 and origin_r[link, 2, 1] == 0.0)
        for i in range(3):
            acc = trans[p, i]
            for k in range(3):
                acc += rot[p, i, k] * origin_t[link, k]
            trans[link, i] = acc
            if plain:
                for j in range(3):
                    rot[link, i, j] = rot[p, i, j]
                continue
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    acc += rot[p, i, k] * origin_r[link, k, j]
                rot[link, i, j] = acc
        if kind[link] == 1 and axis[link, 0] == 0.0 and axis[link, 1] == 0.0 and axis[link, 2] == 1.0:
            # revolute about z: Rodrigues' matrix below with its zero terms dropped (the same floats)
            c, s = math.cos(v), math.sin(v)
            m22 = (1.0 - c) + c
            for i in range(3):
                a0, a1, a2 = rot[link, i, 0], rot[link, i, 1], rot[link, i, 2]
                rot[link, i, 0] = a0 * c + a1 * s
                rot[link, i, 1] = a0 * -s + a1 * c
                rot[link, i, 2] = a2 * m22
        elif kind[link] == 1:        # revolute: times Rodrigues(axis, v)
            x, y, z = axis[link, 0], axis[link, 1], axis[link, 2]
            c, s = math.cos(v), math.sin(v)
            t = 1.0 - c
            m00, m01, m02 = t * x * x + c, t * x * y - s * z, t * x * z + s * y
            m10, m11, m12 = t * x * y + s * z, t * y * y + c, t * y * z - s * x
            m20, m21, m22 = t * x * z - s * y, t * y * z + s * x, t * z * z + c
            for i in range(3):
                a0, a1, a2 = rot[link, i, 0], rot[link, i, 1], rot[link, i, 2]
                rot[link, i, 0] = a0 * m00 + a1 * m10 + a2 * m20
                rot[link, i, 1] = a0 * m01 + a1 * m11 + a2 * m21
                rot[link, i, 2] = a0 * m02 + a1 * m12 + a2 * m22
        elif kind[link] == 2:      # prismatic: translate along the (rotated) axis
            for i in range(3):
                acc = 0.0
                for k in range(3):
                    acc += rot[link, i, k] * axis[link, k]
                trans[link, i] += v * acc


def _dist2(cx, cy, cz, kind, ox, oy, oz, r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz):
    """The squared distance from the point ``c`` to an obstacle's core (0 inside) and the radius the
    obstacle adds: a box of half extents ``s`` (adds 0), a cylinder of radius ``sx`` and half height
    ``sy`` along its z (adds 0), or a sphere of radius ``sx`` (its core is its centre, it adds ``sx``);
    centred at ``o``, rotated by ``R`` (rows ``r0*``, ``r1*``, ``r2*``). A sphere ``(c, r)`` is
    ``sqrt(d2) - r - adds`` from the obstacle (negative or zero: they touch; exact), so walks can compare
    squares and take the root only where the distance itself is needed. Scalars only: a compiled call
    with array arguments costs more than the test."""
    dx, dy, dz = cx - ox, cy - oy, cz - oz
    if kind == 2:
        return dx * dx + dy * dy + dz * dz, sx
    lx = r00 * dx + r10 * dy + r20 * dz          # local = R^T d
    ly = r01 * dx + r11 * dy + r21 * dz
    lz = r02 * dx + r12 * dy + r22 * dz
    if kind == 0:
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


def _position(n, k, bisection, queue):
    """Where state ``k`` comes in the planner's order of an edge of ``n`` states (0-based): ``k - 1``
    in sequence; by bisection, its place in ``n`` first, then the middles of ``1..n-1`` and of its
    halves breadth first (:func:`~gnn_mp_envs.tasks.arm.problem.bisection_order`). ``queue``:
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


def _velocities(a, b, n, parent, kind, axis, q_index, rot, trans, omega, vel):
    """Per link, at the configuration whose frames ``rot``, ``trans`` hold: the angular velocity
    ``omega[l]`` and the velocity ``vel[l]`` of the frame's origin for one state's step ``(b - a) / n``
    of the edge (world axes; per state, not per second)."""
    for link in range(parent.shape[0]):
        p = parent[link]
        if p < 0:
            for i in range(3):
                omega[link, i] = 0.0
                vel[link, i] = 0.0
            continue
        wx, wy, wz = omega[p, 0], omega[p, 1], omega[p, 2]
        dx, dy, dz = trans[link, 0] - trans[p, 0], trans[link, 1] - trans[p, 1], trans[link, 2] - trans[p, 2]
        vel[link, 0] = vel[p, 0] + wy * dz - wz * dy
        vel[link, 1] = vel[p, 1] + wz * dx - wx * dz
        vel[link, 2] = vel[p, 2] + wx * dy - wy * dx
        omega[link, 0], omega[link, 1], omega[link, 2] = wx, wy, wz
        j = q_index[link]
        if j >= 0 and kind[link] != 0:
            step = (b[j] - a[j]) / n
            for i in range(3):
                world = rot[link, i, 0] * axis[link, 0] + rot[link, i, 1] * axis[link, 1] + rot[link, i, 2] * axis[link, 2]
                if kind[link] == 1:
                    omega[link, i] += step * world
                else:
                    vel[link, i] += step * world


def _motion_bounds(a, b, n, reach, delta, curve):
    """Per row of ``reach`` (a link, or a self pair's relative motion), for one state's step
    ``(b - a) / n``: ``delta``, how far any of its spheres moves at most anywhere (the joints' steps
    times their levers), and ``curve``, how much the speed of any of its points changes at most per
    state. A point's velocity is ``sum_j dq_j a_j x (p - o_j)``; along the edge each axis ``a_j``
    turns at most by the steps of the joints above it and each ``p - o_j`` changes at most by
    ``sum_j dq_j reach_j``, so the change is at most ``3 (sum_j dq_j) delta`` over the joints that move it."""
    steps = np.empty(reach.shape[1])
    for j in range(reach.shape[1]):
        steps[j] = abs(b[j] - a[j]) / n
    for r in range(reach.shape[0]):
        acc = 0.0
        turn = 0.0
        for j in range(reach.shape[1]):
            if reach[r, j] > 0.0:
                acc += steps[j] * reach[r, j]
                turn += steps[j]
        delta[r] = acc
        curve[r] = 3.0 * turn * acc


def _rate(moving, frame, node, nodes, rot, trans, omega, vel):
    """How fast (per state) the points of the sphere ``node`` of link ``moving`` move at most at this
    configuration, relative to link ``frame`` (-1: the world): the speed of its centre plus the
    relative turn rate times its radius (from :func:`_velocities`)."""
    x, y, z = nodes[node, 0], nodes[node, 1], nodes[node, 2]
    ux = rot[moving, 0, 0] * x + rot[moving, 0, 1] * y + rot[moving, 0, 2] * z   # centre from the origin
    uy = rot[moving, 1, 0] * x + rot[moving, 1, 1] * y + rot[moving, 1, 2] * z
    uz = rot[moving, 2, 0] * x + rot[moving, 2, 1] * y + rot[moving, 2, 2] * z
    wx, wy, wz = omega[moving, 0], omega[moving, 1], omega[moving, 2]
    vx = vel[moving, 0] + wy * uz - wz * uy
    vy = vel[moving, 1] + wz * ux - wx * uz
    vz = vel[moving, 2] + wx * uy - wy * ux
    if frame >= 0:          # less the velocity of the point fixed to ``frame`` at the centre
        fx, fy, fz = omega[frame, 0], omega[frame, 1], omega[frame, 2]
        rx = trans[moving, 0] + ux - trans[frame, 0]
        ry = trans[moving, 1] + uy - trans[frame, 1]
        rz = trans[moving, 2] + uz - trans[frame, 2]
        vx -= vel[frame, 0] + fy * rz - fz * ry
        vy -= vel[frame, 1] + fz * rx - fx * rz
        vz -= vel[frame, 2] + fx * ry - fy * rx
        wx, wy, wz = wx - fx, wy - fy, wz - fz
    return math.sqrt(vx * vx + vy * vy + vz * vz) + math.sqrt(wx * wx + wy * wy + wz * wz) * nodes[node, 3]


def _pair_walk(la, lb, root_a, root_b, tau, floor, nodes, first_child, child_count, rot, trans, pair_stack):
    """Whether a leaf under ``root_a`` (of link ``la``) and one under ``root_b`` (of ``lb``) are at most
    ``floor`` apart (``(True, ...)``), else ``(False, least)``: the least gap of the node pairs the walk
    pruned, a lower bound of every leaf pair's. Simultaneous descent from the roots, splitting the
    larger of two nodes nearer than ``tau`` (at least ``floor``)."""
    least = 1e300
    top = 0
    pair_stack[0, 0] = root_a
    pair_stack[0, 1] = root_b
    while top >= 0:
        na_, nb_ = pair_stack[top, 0], pair_stack[top, 1]
        top -= 1
        x, y, z = nodes[na_, 0], nodes[na_, 1], nodes[na_, 2]
        u, v, w = nodes[nb_, 0], nodes[nb_, 1], nodes[nb_, 2]
        dx = (trans[la, 0] + rot[la, 0, 0] * x + rot[la, 0, 1] * y + rot[la, 0, 2] * z
              - trans[lb, 0] - rot[lb, 0, 0] * u - rot[lb, 0, 1] * v - rot[lb, 0, 2] * w)
        dy = (trans[la, 1] + rot[la, 1, 0] * x + rot[la, 1, 1] * y + rot[la, 1, 2] * z
              - trans[lb, 1] - rot[lb, 1, 0] * u - rot[lb, 1, 1] * v - rot[lb, 1, 2] * w)
        dz = (trans[la, 2] + rot[la, 2, 0] * x + rot[la, 2, 1] * y + rot[la, 2, 2] * z
              - trans[lb, 2] - rot[lb, 2, 0] * u - rot[lb, 2, 1] * v - rot[lb, 2, 2] * w)
        g = math.sqrt(dx * dx + dy * dy + dz * dz) - nodes[na_, 3] - nodes[nb_, 3]
        ca, cb = child_count[na_], child_count[nb_]
        if g > tau or (g > floor and ca == 0 and cb == 0):
            least = g if g < least else least
            continue
        if ca == 0 and cb == 0:
            return True, least
        if cb == 0 or (ca > 0 and nodes[na_, 3] >= nodes[nb_, 3]):
            for c in range(first_child[na_], first_child[na_] + ca):
                top += 1
                pair_stack[top, 0] = c
                pair_stack[top, 1] = nb_
        else:
            for c in range(first_child[nb_], first_child[nb_] + cb):
                top += 1
                pair_stack[top, 0] = na_
                pair_stack[top, 1] = c
    return False, least


def _table_room(p, q, table_at, table_joint, table_low, table_step, table_dim, table):
    """The entry of self pair ``p``'s joint-space table at ``q``: ``d >= 1`` when the cell of ``q`` and
    every cell fewer than ``d`` cells away from it (in each of the pair's joints) are free of contact
    between the pair, so every configuration less than ``d - 1`` cells from ``q`` is; 0 when the cell
    is not, or ``q`` lies outside the table."""
    index = 0
    for k in range(2):
        j = table_joint[p, k]
        if j < 0:
            break
        cell = math.floor((q[j] - table_low[p, k]) / table_step[p, k])
        if cell < 0 or cell >= table_dim[p, k]:
            return 0
        index = index * table_dim[p, k] + cell
    return table[table_at[p] + index]


def _free_cells(la, lb, root_a, root_b, joints, low, step, dim, floor, q, parent, origin_r, origin_t, kind, axis,
                q_index, q_fixed, nodes, first_child, child_count, rot, trans, pair_stack, out):
    """``out[c]``: no leaf of link ``la``'s tree at ``root_a`` comes within ``floor`` of one of ``lb``'s
    at the centre of cell ``c`` of the grid of ``dim[k]`` cells of ``step[k]`` from ``low[k]`` over
    joints ``joints`` (row-major; ``joints[1] < 0``: one joint) with the other joints at ``q``."""
    cells = dim[0] * dim[1]
    for c in range(cells):
        i0, i1 = c // dim[1], c % dim[1]
        q[joints[0]] = low[0] + (i0 + 0.5) * step[0]
        if joints[1] >= 0:
            q[joints[1]] = low[1] + (i1 + 0.5) * step[1]
        _forward_kinematics(q, parent, origin_r, origin_t, kind, axis, q_index, q_fixed, rot, trans)
        hit, _ = _pair_walk(la, lb, root_a, root_b, floor, floor, nodes, first_child, child_count, rot, trans,
                            pair_stack)
        out[c] = not hit


def _states_clear(gap, rate, curve, delta):
    """How many states away (either way along the edge, real-valued) spheres at least ``gap`` from
    everything stay clear, that is, states nearer than it are free: the larger of ``gap / delta``
    (spheres move at most ``delta`` per state anywhere) and the root of ``rate s + curve s^2 / 2 =
    gap`` (they move at ``rate`` per state here, and that speed changes by at most ``curve`` per
    state; ``rate = curve = 0``: no such bound). Slightly rounded down; ``1e300`` where nothing moves."""
    if gap <= 0.0:
        return gap
    if delta <= 0.0:
        return 1e300
    out = gap / delta
    den = rate + math.sqrt(rate * rate + 2.0 * curve * gap)
    if den > 0.0:
        quadratic = 2.0 * gap / den
        out = quadratic if quadratic > out else out
    return out * (1.0 - 1e-12)


def _run(mode, qs, out, a, b, resolution, low, high, bisection, arrays):
    """The checker's one kernel, in one body (a compiled call with array arguments costs more than
    the tests it would wrap).

    ``mode == 0``: ``out[i]`` = row ``i`` of ``qs`` is collision-free; returns the row count.

    ``mode == 1``: the edge ``a -> b`` (``a`` valid) of states ``a + (k / n)(b - a)``, ``k = 1..n``,
    ``n = max(1, ceil(|b - a| / resolution))``, in the planner's order (``bisection``: ``n`` first,
    then the middles of the remaining intervals breadth first; else ``1..n``), stopping at the first
    invalid state (out of the box ``[low, high]`` or in collision). Returns how many states that
    order looks at: the position of the first invalid state plus one (negated), or ``n``; 0 when the
    scratch arrays hold fewer than ``n + 1`` states (the caller grows them and calls again). The
    same arithmetic as :meth:`ArmProblem.check_motion <gnn_mp_envs.tasks.arm.problem.ArmProblem.check_motion>`.

    ``arrays`` (the table of :meth:`SphereChecker._pack`) holds the robot's kinematics and spheres, the
    scene and the scratch space.

    A state collides when a leaf of a link's obstacle tree touches an obstacle or a leaf of a
    checked link pair's self-collision trees touches the other's (depth first from the roots).
    Along an edge the answer and the count are those of testing every state, with less work.
    ``gaps[k, i]`` holds, for a state ``k`` known to be free, how many states away on either side (real
    valued) link ``i``'s spheres stay clear of every obstacle (``i = link``), or a self pair's of each
    other (``i = links + pair``). A walk that finds no touching leaves leaves a lower bound of the
    distances (the least gap of the nodes it pruned); it becomes states through the motion bounds
    (:func:`_states_clear`): anywhere, a link's spheres move at most ``delta[link]`` per state
    (``reach`` times each joint's step) and a pair's relative to each other at most
    ``pdelta[pair]`` (only the joints between them count); near the tested state they move at the
    speed :func:`_rate` measures there, which changes by at most ``curve`` (``pcurve``) per state. A
    self pair with a joint-space table (:meth:`SphereChecker._joint_tables`) is looked up instead of
    walked where its cell is free, and vouches for as many cells as the table says. So a link or
    pair that a checked neighbour state vouches for is free without a test; an interval whose two
    checked ends vouch for every link and pair across it is free as a whole, with the intervals
    under it (sequential order: the states ahead are skipped the same way).

    Edges start where earlier ones ended (a tree's nodes are the far ends of the edges that made
    them), so the clearances the walks find at a free start or far end are remembered
    (``memo_q``, ``memo_clear``: the last :data:`MEMO_STATES` such states, forgotten when the scene
    changes), and an edge whose start is one of them takes them instead of walking again. They are
    lower bounds of distances, so only the work depends on what the checker saw before, never an
    answer or a count."""
    # the arrays of ``arrays``, the table of :meth:`SphereChecker._pack` (rows in :data:`_FIELDS` order)
    q = _view1(arrays, 0, np.float64)
    gaps = _view2(arrays, 1, np.float64)
    known = _view1(arrays, 2, np.bool_)
    reach = _view2(arrays, 3, np.float64)
    pair_reach = _view2(arrays, 4, np.float64)
    delta = _view1(arrays, 5, np.float64)
    pdelta = _view1(arrays, 6, np.float64)
    curve = _view1(arrays, 7, np.float64)
    pcurve = _view1(arrays, 8, np.float64)
    omega = _view2(arrays, 9, np.float64)
    vel = _view2(arrays, 10, np.float64)
    queue = _view2(arrays, 11, np.int64)
    parent = _view1(arrays, 12, np.int64)
    origin_r = _view3(arrays, 13, np.float64)
    origin_t = _view2(arrays, 14, np.float64)
    kind = _view1(arrays, 15, np.int64)
    axis = _view2(arrays, 16, np.float64)
    q_index = _view1(arrays, 17, np.int64)
    q_fixed = _view1(arrays, 18, np.float64)
    link_root = _view1(arrays, 19, np.int64)
    self_root = _view1(arrays, 20, np.int64)
    nodes = _view2(arrays, 21, np.float64)
    first_child = _view1(arrays, 22, np.int64)
    child_count = _view1(arrays, 23, np.int64)
    pairs = _view2(arrays, 24, np.int64)
    exempt = _view2(arrays, 25, np.bool_)
    ob_kind = _view1(arrays, 26, np.int64)
    ob_centre = _view2(arrays, 27, np.float64)
    ob_rot = _view3(arrays, 28, np.float64)
    ob_size = _view2(arrays, 29, np.float64)
    rot = _view3(arrays, 30, np.float64)
    trans = _view2(arrays, 31, np.float64)
    stack = _view1(arrays, 32, np.int64)
    pair_stack = _view2(arrays, 33, np.int64)
    pair_moving = _view1(arrays, 34, np.int64)
    pcell = _view1(arrays, 35, np.float64)
    table_at = _view1(arrays, 36, np.int64)
    table_joint = _view2(arrays, 37, np.int64)
    table_low = _view2(arrays, 38, np.float64)
    table_step = _view2(arrays, 39, np.float64)
    table_dim = _view2(arrays, 40, np.int64)
    table = _view1(arrays, 41, np.int32)
    memo_q = _view2(arrays, 42, np.float64)
    memo_clear = _view2(arrays, 43, np.float64)
    memo_meta = _view1(arrays, 44, np.int64)
    dof = q.shape[0]
    links = parent.shape[0]
    n_ob = ob_kind.shape[0]
    n_pairs = links + pairs.shape[0]
    n, limit = 1, 1
    row = 0
    phase = 0                   # edges: 0 the start, 1 the far end, 2 intervals, 3 sequential states
    #                             (bisection: the far end, then the start, then intervals)
    k_next = 1
    head, tail = 0, 0
    lo, hi = 0, 0
    memo = -1                   # the memo row of the edge's start (-1: not remembered)
    if mode == 1:
        acc = 0.0
        for j in range(dof):
            acc += (b[j] - a[j]) * (b[j] - a[j])
        n = max(1, math.ceil(math.sqrt(acc) / resolution))
        if n + 1 > known.shape[0]:
            return 0
        limit = n
        inside = True
        for j in range(dof):
            if not (low[j] <= b[j] <= high[j]):
                inside = False
        if not inside:                          # a is inside and the box convex: the states leave it once
            for k in range(1, n + 1):
                t = k / n
                out_ = False
                for j in range(dof):
                    v = a[j] + t * (b[j] - a[j])
                    if not (low[j] <= v <= high[j]):
                        out_ = True
                if out_:
                    limit = k - 1
                    break
        _motion_bounds(a, b, n, reach, delta, curve)
        _motion_bounds(a, b, n, pair_reach, pdelta, pcurve)
        for p in range(pairs.shape[0]):     # cells of the pair's table crossed per state, at most
            acc = 0.0
            for k in range(2):
                j = table_joint[p, k]
                if j >= 0:
                    r = abs(b[j] - a[j]) / n / table_step[p, k]
                    acc = r if r > acc else acc
            pcell[p] = acc
        for k in range(n + 1):
            known[k] = False
        if bisection:                           # the far end first, then the start (only if that end is free)
            phase = 1
        if bisection and limit < n:
            return -1                           # the far end, looked at first, is out of bounds
    while True:
        # ---- the next state to test: kk, with its checked neighbours LL and RR (-1: none)
        track = mode == 1
        kk, LL, RR = 0, -1, -1
        if mode == 0:
            if row >= qs.shape[0]:
                return row
            for j in range(dof):
                q[j] = qs[row, j]
        elif phase == 0:                        # the start: its bounds only (not a check)
            for j in range(dof):
                q[j] = a[j]
            filled = memo_meta[0]
            for m in range(filled):             # newest first
                row_ = memo_meta[1] - 1 - m
                if row_ < 0:
                    row_ += memo_q.shape[0]
                same = True
                for j in range(dof):
                    if memo_q[row_, j] != a[j]:
                        same = False
                        break
                if same:
                    memo = row_
                    break
        elif phase == 1:                        # bisection: the far end first (the start is not known yet)
            kk = n
        elif phase == 2:                        # bisection: the next interval that needs a test
            found = False
            while head < tail:
                lo, hi = queue[head, 0], queue[head, 1]
                head += 1
                if lo > hi:
                    continue
                L, R = lo - 1, hi + 1
                if known[L] and known[R]:
                    free = True
                    for i in range(n_pairs):
                        gl, gr = gaps[L, i], gaps[R, i]
                        if not (gl > 0.0 and gr > 0.0 and gl + gr > R - L):
                            free = False
                            break
                    if free:
                        continue
                kk, LL, RR = (lo + hi) // 2, L, R
                found = True
                break
            if not found:
                return n
        else:                                   # sequential: skip ahead while the last bounds vouch
            if k_next > n:
                return n
            if k_next > limit:
                return -(_position(n, k_next, bisection, queue) + 1)
            last = k_next - 1
            if known[last]:
                room = 1e300
                for i in range(n_pairs):
                    r = gaps[last, i]
                    room = r if r < room else room
                skip = int(room) if room < 1e18 else n
                if room == skip:                # the bound must exceed the motion strictly
                    skip -= 1
                if skip >= 1:
                    end = last + skip
                    if end >= n and n <= limit:
                        return n
                    if end > limit:
                        end = limit
                    for i in range(n_pairs):
                        gaps[end, i] = gaps[last, i] - (end - last)
                    known[end] = True
                    k_next = end + 1
                    continue
            kk, LL = k_next, k_next - 1
        if mode == 1 and phase != 0:
            t = kk / n
            for j in range(dof):
                q[j] = a[j] + t * (b[j] - a[j])
        # ---- test it
        _forward_kinematics(q, parent, origin_r, origin_t, kind, axis, q_index, q_fixed, rot, trans)
        if track:
            _velocities(a, b, n, parent, kind, axis, q_index, rot, trans, omega, vel)
            for pr in range(gaps.shape[1]):          # pairs never tested (exempt, no spheres) bound nothing
                gaps[kk, pr] = 1e300
        # a start found in the memo reuses its clearances; a start not found and a far end are remembered
        use = memo if phase == 0 else -1
        slot = -1
        if track and (phase == 1 or (phase == 0 and memo < 0)):
            slot = memo_meta[1]
            for j in range(dof):
                memo_q[slot, j] = math.nan      # not a valid row until the test ends free
            for pr in range(memo_clear.shape[1]):
                memo_clear[slot, pr] = -1.0     # -1: not walked (carried over, a table, no spheres)
        rec = slot if slot >= 0 else use        # the memo row this test's walks fill in
        hit = False
        # --- obstacles
        for link in range(links):
            root = link_root[link]
            if root < 0:
                continue
            t0, t1, t2 = trans[link, 0], trans[link, 1], trans[link, 2]
            m00, m01, m02 = rot[link, 0, 0], rot[link, 0, 1], rot[link, 0, 2]
            m10, m11, m12 = rot[link, 1, 0], rot[link, 1, 1], rot[link, 1, 2]
            m20, m21, m22 = rot[link, 2, 0], rot[link, 2, 1], rot[link, 2, 2]
            if track:                                # the link's clearance to every obstacle, carried over
                bound = -1.0
                if LL >= 0 and known[LL]:
                    bound = gaps[LL, link] - (kk - LL)
                if RR >= 0 and known[RR]:
                    other = gaps[RR, link] - (RR - kk)
                    bound = other if other > bound else bound
                if bound > 0.0:
                    gaps[kk, link] = bound
                    continue
            clearance = 1e300
            # along an edge, walks go on below nodes nearer than tau: the bound they leave then vouches
            # for about REFINE states on either side
            rate = 0.0
            tau = 0.0
            if track:
                rate = _rate(link, -1, root, nodes, rot, trans, omega, vel)
                tau = REFINE * rate + 0.5 * REFINE * REFINE * curve[link]
                linear = REFINE * delta[link]
                tau = linear if linear < tau else tau
            if use >= 0 and memo_clear[use, link] >= 0.0:
                clearance = memo_clear[use, link]
                gaps[kk, link] = _states_clear(clearance, rate, curve[link], delta[link])
                continue
            for o in range(n_ob):
                if exempt[o, link]:
                    continue
                # the link's least clearance so far: only a node nearer than it can lower it (the same
                # minimum as the obstacle's own least, then the link's)
                least = clearance
                top = 0
                stack[0] = root
                while top >= 0:
                    node = stack[top]
                    top -= 1
                    x, y, z, r = nodes[node, 0], nodes[node, 1], nodes[node, 2], nodes[node, 3]
                    d2, adds = _dist2(t0 + m00 * x + m01 * y + m02 * z, t1 + m10 * x + m11 * y + m12 * z,
                                      t2 + m20 * x + m21 * y + m22 * z, ob_kind[o],
                                      ob_centre[o, 0], ob_centre[o, 1], ob_centre[o, 2],
                                      ob_rot[o, 0, 0], ob_rot[o, 0, 1], ob_rot[o, 0, 2], ob_rot[o, 1, 0],
                                      ob_rot[o, 1, 1], ob_rot[o, 1, 2], ob_rot[o, 2, 0], ob_rot[o, 2, 1],
                                      ob_rot[o, 2, 2], ob_size[o, 0], ob_size[o, 1], ob_size[o, 2])
                    nc = child_count[node]
                    # squares first, the root (a long-latency instruction, a tenth of the kernel's time)
                    # only where needed: farther than tau by a margin far above rounding, the node is
                    # pruned as below; its distance counts only if it may be the least so far
                    reach_ = tau + r + adds
                    if d2 > reach_ * reach_ * SQUARES_MARGIN:
                        near = least + r + adds
                        if d2 < near * near * SQUARES_MARGIN:
                            g = math.sqrt(d2) - r - adds
                            least = g if g < least else least
                        continue
                    g = math.sqrt(d2) - r - adds
                    if g > tau or (g > 0.0 and nc == 0):
                        least = g if g < least else least
                        continue
                    if nc == 0:
                        hit = True
                        break
                    for c in range(first_child[node], first_child[node] + nc):
                        top += 1
                        stack[top] = c
                if hit:
                    break
                clearance = least
            if hit:
                break
            if rec >= 0:
                memo_clear[rec, link] = clearance
            if track:
                gaps[kk, link] = _states_clear(clearance, rate, curve[link], delta[link])
        # --- self-collision: simultaneous descent, splitting the larger of two touching inner nodes
        if not hit:
            for p in range(pairs.shape[0]):
                la, lb = pairs[p, 0], pairs[p, 1]
                pr = links + p
                if track:
                    bound = -1.0
                    if LL >= 0 and known[LL]:
                        bound = gaps[LL, pr] - (kk - LL)
                    if RR >= 0 and known[RR]:
                        other = gaps[RR, pr] - (RR - kk)
                        bound = other if other > bound else bound
                    if bound > 0.0:
                        gaps[kk, pr] = bound
                        continue
                if table_at[p] >= 0:                  # the pair's joint-space table
                    room = _table_room(p, q, table_at, table_joint, table_low, table_step, table_dim, table)
                    if room >= 1:                       # this state's cell and ``room - 1`` around it are free
                        if track:
                            gaps[kk, pr] = (room - 1) / pcell[p] * (1.0 - 1e-12) if pcell[p] > 0.0 else 1e300
                        continue
                rate = 0.0
                bend = 0.0                              # no speed measured: the global bound only
                tau = 0.0
                if track:
                    tau = REFINE * pdelta[p]
                    lm = pair_moving[p]
                    if lm >= 0:                         # one link below the other: it moves in the other's frame
                        rate = _rate(lm, la + lb - lm, self_root[lm], nodes, rot, trans, omega, vel)
                        bend = pcurve[p]
                        quadratic = REFINE * rate + 0.5 * REFINE * REFINE * bend
                        tau = quadratic if quadratic < tau else tau
                if use >= 0 and memo_clear[use, pr] >= 0.0:
                    least = memo_clear[use, pr]
                else:
                    hit, least = _pair_walk(la, lb, self_root[la], self_root[lb], tau, 0.0, nodes, first_child,
                                            child_count, rot, trans, pair_stack)
                    if hit:
                        break
                    if rec >= 0:
                        memo_clear[rec, pr] = least
                if track:
                    gaps[kk, pr] = _states_clear(least, rate, bend, pdelta[p])

        # ---- what follows from it
        if slot >= 0 and not hit:
            for j in range(dof):
                memo_q[slot, j] = q[j]
            memo_meta[1] = (slot + 1) % memo_q.shape[0]
            memo_meta[0] = min(memo_meta[0] + 1, memo_q.shape[0])
        if mode == 0:
            out[row] = not hit
            row += 1
        elif phase == 0:
            known[0] = not hit                  # a start in collision vouches for nothing
            phase = 2 if bisection else 3
        elif hit:
            return -(_position(n, kk, bisection, queue) + 1)
        else:
            known[kk] = True
            if phase == 1:                      # then the start, for the bounds of the states between
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
    """``x * y + z`` rounded once (LLVM's ``llvm.fma.f64``: exact on every CPU, in hardware or not).
    numpy's ``d @ d`` of a short vector sums so (OpenBLAS's ``ddot``: one fused multiply-add per
    entry, in order); tests/test_spheres.py holds the two equal."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        f64 = ir.DoubleType()
        fma = cgutils.get_or_insert_function(builder.module, ir.FunctionType(f64, [f64, f64, f64]), "llvm.fma.f64")
        return builder.call(fma, args)

    return sig, codegen


def _steer_run(a, target, step, resolution, low, high, bisection, arrays, x_new, distance):
    """Steer from ``a`` toward ``target`` by at most ``step`` (joint-space L2) and check that edge, in
    one call. ``distance[0]`` = ``|target - a|``, summed as numpy's ``d @ d`` sums (:func:`_fma`, in
    order); below ``ZERO_LENGTH`` nothing else is done (answer 1). Else ``x_new`` = ``target`` when
    the distance is at most ``step``, else ``a + (step / distance)(target - a)``, and the answer is
    :func:`_run`'s for the edge ``a -> x_new``. The same floats as :meth:`ArmProblem.steer
    <gnn_mp_envs.tasks.arm.problem.ArmProblem.steer>` with the pybullet checker."""
    dof = a.shape[0]
    s = 0.0
    for j in range(dof):
        dj = target[j] - a[j]
        s = _fma(dj, dj, s)
    d = math.sqrt(s)
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
    return _run(1, _view2(arrays, 1, np.float64)[:0], _view1(arrays, 2, np.bool_)[:0], a, x_new, resolution, low,
                high, bisection, arrays)


_KERNELS: dict[str, Any] = {}


def _kernels() -> dict[str, Any]:
    """The compiled kernels (numba, cached on disk next to this module; compiled on first use)."""
    if not _KERNELS:
        try:
            from numba import njit
        except ImportError:      # pragma: no cover - numba is a dependency
            raise ImportError("the sphere checker needs numba: pip install numba") from None
        g = globals()
        g["_dist2"] = njit(cache=True, nogil=True, inline="always")(g["_dist2"])
        for view in ("_view1", "_view2", "_view3"):
            g[view] = njit(cache=True, nogil=True, inline="always")(g[view])
        g["_forward_kinematics"] = njit(cache=True, nogil=True)(g["_forward_kinematics"])
        g["_position"] = njit(cache=True, nogil=True)(g["_position"])
        g["_velocities"] = njit(cache=True, nogil=True)(g["_velocities"])
        g["_states_clear"] = njit(cache=True, nogil=True, inline="always")(g["_states_clear"])
        g["_motion_bounds"] = njit(cache=True, nogil=True)(g["_motion_bounds"])
        g["_rate"] = njit(cache=True, nogil=True, inline="always")(g["_rate"])
        g["_pair_walk"] = njit(cache=True, nogil=True, inline="always")(g["_pair_walk"])
        g["_table_room"] = njit(cache=True, nogil=True, inline="always")(g["_table_room"])
        _KERNELS["free_cells"] = njit(cache=True, nogil=True)(_free_cells)
        _KERNELS["velocities"] = g["_velocities"]
        _KERNELS["motion_bounds"] = g["_motion_bounds"]
        _KERNELS["rate"] = g["_rate"]
        _KERNELS["table_room"] = g["_table_room"]
        g["_run"] = _KERNELS["run"] = njit(cache=True, nogil=True)(_run)
        _KERNELS["steer_run"] = njit(cache=True, nogil=True)(_steer_run)
        _KERNELS["forward_kinematics"] = g["_forward_kinematics"]
    return _KERNELS


# ---------------------------------------------------------------------- the checker
def _quaternion_matrix(q: Sequence[float]) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


_NO_STATES = np.zeros((0, 1))
_NO_OUT = np.zeros(0, dtype=np.bool_)


def _tree_depth(model: SphereModel) -> int:
    """Levels of the deepest tree of the model."""
    depth = np.zeros(len(model.nodes), dtype=np.int64)
    for i in range(len(model.nodes)):           # breadth-first rows: parents before children
        if model.child_count[i]:
            depth[model.first_child[i]:model.first_child[i] + model.child_count[i]] = depth[i] + 1
    return int(depth.max()) + 1


class SphereChecker:
    """Collision checks of one robot against one scene with the robot's sphere model.

    ``joints``: the planned joints' names, in state order; ``held``: joint name -> fixed value of
    other movable joints (0 where not named); ``allowed``: link-name pairs whose contact is not a
    collision (parent-child pairs never are). :meth:`set_obstacles` loads a scene."""

    def __init__(self, urdf: str | Path, model: SphereModel, joints: Sequence[str],
                 held: dict[str, float] | None = None, allowed: Sequence[tuple[str, str]] = ()) -> None:
        robot: URDFRobot = read_urdf(str(urdf))
        self.robot = robot
        self.model = model
        self.links = robot.links
        index = {name: i for i, name in enumerate(robot.links)}
        held = dict(held or {})
        names = {j.name for j in robot.joints.values()}
        unknown = sorted(set(joints) - names) + sorted(set(held) - names)
        if unknown:
            raise ValueError(f"robot {robot.name!r} has no joint(s) {unknown}")
        n = len(robot.links)
        self.dof = len(joints)
        self._parent = np.full(n, -1, dtype=np.int64)
        self._origin_r = np.zeros((n, 3, 3))
        self._origin_t = np.zeros((n, 3))
        self._kind = np.zeros(n, dtype=np.int64)
        self._axis = np.zeros((n, 3))
        self._q_index = np.full(n, -1, dtype=np.int64)
        self._q_fixed = np.zeros(n)
        position = {name: k for k, name in enumerate(joints)}
        for link, j in robot.joints.items():
            i = index[link]
            self._parent[i] = index[j.parent]
            self._origin_r[i], self._origin_t[i], self._axis[i] = j.rotation, j.translation, j.axis
            self._kind[i] = {FIXED: 0, REVOLUTE: 1, PRISMATIC: 2}[j.kind]
            if j.name in position:
                if j.kind == FIXED:
                    raise ValueError(f"joint {j.name!r} is fixed and cannot be planned")
                self._q_index[i] = position[j.name]
            else:
                self._q_fixed[i] = float(held.get(j.name, 0.0))
        self._root = np.array([model.roots.get(name, -1) for name in robot.links], dtype=np.int64)
        self._self_root = np.array([model.self_roots.get(name, -1) for name in robot.links], dtype=np.int64)
        skip = {frozenset(p) for p in allowed} | robot.parent_child_pairs()
        with_spheres = [name for name in robot.links if name in model.roots]
        self._pairs = np.array([(index[a], index[b]) for k, a in enumerate(with_spheres) for b in with_spheres[k + 1:]
                                if frozenset((a, b)) not in skip], dtype=np.int64).reshape(-1, 2)
        self.self_pairs = [(self.links[a], self.links[b]) for a, b in self._pairs]
        self._rot = np.zeros((n, 3, 3))
        self._trans = np.zeros((n, 3))
        # depth-first stacks: at most (children per node) entries per level of the deepest tree
        # (two trees for pairs)
        depth = _tree_depth(model)
        width = int(model.child_count.max()) + 1
        self._stack = np.zeros(width * depth + 1, dtype=np.int64)
        self._pair_stack = np.zeros((width * 2 * depth + 1, 2), dtype=np.int64)
        self._q = np.zeros(self.dof)
        self._reach = self._joint_reach(robot, index, held)
        # a self pair moves relative to itself only through the joints that move one link and not the other
        ra, rb = self._reach[self._pairs[:, 0]], self._reach[self._pairs[:, 1]]
        self._pair_reach = np.where(rb == 0, ra, 0.0) + np.where(ra == 0, rb, 0.0)
        self._delta = np.zeros(n)
        self._pdelta = np.zeros(len(self._pairs))
        self._curve = np.zeros(n)
        self._pcurve = np.zeros(len(self._pairs))
        self._pcell = np.zeros(len(self._pairs))
        # per self pair, the link that moves in the other's frame when one is below the other (-1: neither)
        self._pair_moving = np.array([self._below(b_, a_) if self._below(b_, a_) >= 0 else self._below(a_, b_)
                                      for a_, b_ in self._pairs], dtype=np.int64)
        self._omega = np.zeros((n, 3))
        self._vel = np.zeros((n, 3))
        self._gaps = self._known = self._queue = np.zeros(0)
        self._tables = self._joint_tables(robot, joints, held)
        self._steer_run = _kernels()["steer_run"]
        self._distance = np.zeros(1)          # where the steer kernel writes the distance it measured
        self._memo_q = np.full((MEMO_STATES, self.dof), np.nan)
        self._memo_clear = np.zeros((MEMO_STATES, n + len(self._pairs)))
        self._memo_meta = np.zeros(2, dtype=np.int64)      # rows filled, next row to write
        self.set_obstacles(())

    def _joint_tables(self, robot: URDFRobot, joints: Sequence[str], held: dict[str, float]) -> tuple:
        """Joint-space tables of the self pairs whose relative pose only one or two joints change
        (the wrist's): over a grid of those joints, how many cells around each cell are free of
        contact between the pair. A cell is free when the pair's leaves are more than
        ``TABLE_FLOOR`` apart at its centre; within the cell they come at most that much nearer.
        Built once per robot and pair set (a few hundred milliseconds)."""
        key = (robot.name, id(self.model), tuple(joints), tuple(sorted(held.items())), self._pairs.tobytes())
        if key not in _TABLES:
            _TABLES[key] = self._build_joint_tables(robot, joints, held)
        return _TABLES[key]

    def _build_joint_tables(self, robot: URDFRobot, joints: Sequence[str], held: dict[str, float]) -> tuple:
        from scipy.ndimage import distance_transform_cdt
        limits = {j.name: (j.lower, j.upper) for j in robot.joints.values()}
        n_pairs = len(self._pairs)
        table_at = np.full(n_pairs, -1, dtype=np.int64)
        table_joint = np.full((n_pairs, 2), -1, dtype=np.int64)
        table_low = np.zeros((n_pairs, 2))
        table_step = np.ones((n_pairs, 2))
        table_dim = np.ones((n_pairs, 2), dtype=np.int64)
        chunks: list[np.ndarray] = []
        size = 0
        free_cells = _kernels()["free_cells"]
        q = np.array([float(held.get(name, 0.0)) for name in joints])
        for p in range(n_pairs):
            moving = np.flatnonzero(self._pair_reach[p] > 0)
            if not 1 <= len(moving) <= 2:
                continue
            low, high = (np.array([limits[joints[j]][k] for j in moving]) for k in (0, 1))
            if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
                continue
            # each joint's share of the floor: cells of ``2 * share / lever`` radians
            floor = TABLE_FLOOR
            while True:
                step = 2 * (floor / len(moving)) / self._pair_reach[p, moving]
                dim = np.ceil((high - low) / step).astype(np.int64)
                if np.prod(dim) <= TABLE_CELLS:
                    break
                floor *= 1.25
            free = np.zeros(int(np.prod(dim)), dtype=np.bool_)
            la, lb = self._pairs[p]
            grid_joints = np.array([*moving, -1][:2], dtype=np.int64)
            free_cells(la, lb, self._self_root[la], self._self_root[lb], grid_joints, low, step,
                       np.array([*dim, 1][:2], dtype=np.int64), floor, q.copy(), self._parent, self._origin_r,
                       self._origin_t, self._kind, self._axis, self._q_index, self._q_fixed, self.model.nodes,
                       self.model.first_child, self.model.child_count, self._rot, self._trans, self._pair_stack, free)
            if not free.any():                  # always near contact at this floor: the walk decides
                continue
            # cells to the nearest cell that is not free (in any joint); all free: as good as unbounded
            room = (distance_transform_cdt(free.reshape(dim), metric="chessboard").ravel() if not free.all()
                    else np.full(free.size, 1 << 30))
            table_at[p] = size
            table_joint[p, : len(moving)] = moving
            table_low[p, : len(moving)] = low
            table_step[p, : len(moving)] = step
            table_dim[p, : len(moving)] = dim
            chunks.append(room.astype(np.int32))
            size += room.size
        table = np.concatenate(chunks) if chunks else np.zeros(1, dtype=np.int32)
        return table_at, table_joint, table_low, table_step, table_dim, table

    def _below(self, link: int, other: int) -> int:
        """``link`` if ``other`` is one of its ancestors, else -1."""
        up = self._parent[link]
        while up >= 0:
            if up == other:
                return link
            up = self._parent[up]
        return -1

    def _joint_reach(self, robot: URDFRobot, index: dict[str, int], held: dict[str, float]) -> np.ndarray:
        """``(links, dof)``: how far any point of each link's spheres can lie from each planned joint's
        axis (0 where the joint does not move the link; 1 for a prismatic joint: its motion), for
        every configuration: the lengths of the joint origins on the way down plus the reach of the
        link's root spheres (triangle inequality). A step ``dq`` moves the link's spheres by at most
        ``sum_j |dq_j| reach[link, j]``."""
        reach = np.zeros((len(self.links), self.dof))
        nodes = self.model.nodes
        for link, i in index.items():
            own = max([float(np.linalg.norm(nodes[r, :3]) + nodes[r, 3])
                       for r in (self._root[i], self._self_root[i]) if r >= 0], default=0.0)
            length, name = own, link
            while name in robot.joints:              # up the chain to the root
                joint = robot.joints[name]
                j = self._q_index[index[name]]
                if j >= 0:
                    reach[i, j] = 1.0 if joint.kind == PRISMATIC else length
                length += float(np.linalg.norm(joint.translation))
                if joint.kind == PRISMATIC:          # its travel lengthens the lever of the joints above
                    length += max(abs(joint.lower), abs(joint.upper), abs(held.get(joint.name, 0.0)))
                name = joint.parent
        return reach

    def set_obstacles(self, obstacles: Sequence[Any], exempt: dict[int, Sequence[str]] | None = None) -> None:
        """Load a scene: a sequence of :class:`~gnn_mp_envs.tasks.arm.scenes.Obstacle` (box, cylinder or
        sphere). ``exempt``: obstacle index -> links whose contact with it is not a collision (the
        base standing on the table)."""
        k = len(obstacles)
        self._ob_kind = np.zeros(k, dtype=np.int64)
        self._ob_centre = np.zeros((k, 3))
        self._ob_rot = np.zeros((k, 3, 3))
        self._ob_size = np.zeros((k, 3))
        for i, ob in enumerate(obstacles):
            self._ob_kind[i] = _KINDS[ob.kind]
            self._ob_centre[i] = ob.position
            self._ob_rot[i] = _quaternion_matrix(ob.quaternion())
            if ob.kind == "box":
                self._ob_size[i] = ob.size
            elif ob.kind == "cylinder":
                self._ob_size[i, :2] = (ob.size[0], ob.size[1] / 2)
            else:
                self._ob_size[i, 0] = ob.size[0]
        self._exempt = np.zeros((k, len(self.links)), dtype=np.bool_)
        index = {name: i for i, name in enumerate(self.links)}
        for o, links in (exempt or {}).items():
            for name in links:
                self._exempt[o, index[name]] = True
        self._memo_meta[:] = 0           # clearances of the last scene's states
        self._memo_q[:] = np.nan
        self._grow(max(self._known.shape[0], 130))

    def _pack(self) -> None:
        """(Re)build the table of the arrays the kernel reads (after the scene or the scratch changed): per
        array of :data:`_FIELDS`, its address and shape. The kernel views them through :func:`numba.carray`,
        arrays without a reference count: read from an object, 45 arrays took 45 atomic increments and
        decrements per call, a fifth of the kernel's time. So the arrays must outlive the table: it is
        kept with them (``_packed_arrays``), and every array replaced (a scene, more scratch) is
        replaced through here."""
        arrays = (self._q, self._gaps, self._known, self._reach, self._pair_reach, self._delta, self._pdelta,
                  self._curve, self._pcurve, self._omega, self._vel, self._queue, self._parent, self._origin_r,
                  self._origin_t, self._kind, self._axis, self._q_index, self._q_fixed, self._root, self._self_root,
                  self.model.nodes, self.model.first_child, self.model.child_count, self._pairs, self._exempt,
                  self._ob_kind, self._ob_centre, self._ob_rot, self._ob_size, self._rot, self._trans, self._stack,
                  self._pair_stack, self._pair_moving, self._pcell, *self._tables, self._memo_q, self._memo_clear,
                  self._memo_meta)
        table = np.zeros((len(_FIELDS), 4), dtype=np.int64)
        for row, (array, (name, dtype, ndim)) in enumerate(zip(arrays, _FIELDS, strict=True)):
            if not (type(array) is np.ndarray and array.dtype == dtype and array.ndim == ndim
                    and array.flags.c_contiguous):
                raise TypeError(f"the sphere kernel's {name!r} must be a C-contiguous {ndim}-D "
                                f"{np.dtype(dtype).name} array, got {getattr(array, 'dtype', type(array))} "
                                f"{getattr(array, 'shape', '')}")
            table[row, 0] = array.ctypes.data
            table[row, 1:1 + ndim] = array.shape
        self._packed, self._packed_arrays = table, arrays

    def valid(self, states: np.ndarray) -> np.ndarray:
        """Whether each row of ``states`` is collision-free (joint limits are the caller's)."""
        qs = np.ascontiguousarray(np.asarray(states, dtype=np.float64).reshape(-1, self.dof))
        out = np.zeros(len(qs), dtype=np.bool_)
        _kernels()["run"](0, qs, out, self._q, self._q, 1.0, self._q, self._q, False, self._packed)
        return out

    def check_motion(self, a: np.ndarray, b: np.ndarray, resolution: float, low: np.ndarray, high: np.ndarray,
                     bisection: bool = True) -> tuple[bool, int]:
        """Check the edge ``a -> b`` (``a`` valid: the tree's node) as the planner does: the states
        ``a + (k / n)(b - a)``, ``k = 1..n``, ``n = max(1, ceil(|b - a| / resolution))``, in the
        planner's order (``bisection``: ``n`` first, then by bisection; else ``1..n``) until the
        first invalid one, out of ``[low, high]`` or in collision: ``(valid, states that order looks
        at)``."""
        run = _kernels()["run"]
        while True:
            r = run(1, _NO_STATES, _NO_OUT, a, b, resolution, low, high, bisection, self._packed)
            if r != 0:
                return r > 0, abs(int(r))
            self._grow_for(float(np.linalg.norm(b - a)), resolution)

    def steer(self, a: np.ndarray, target: np.ndarray, step: float, resolution: float, low: np.ndarray,
              high: np.ndarray, bisection: bool = True) -> tuple[np.ndarray, float, bool, int]:
        """Steer from ``a`` toward ``target`` by at most ``step`` (joint-space L2) and check the edge as
        :meth:`check_motion` does, in one compiled call: ``(x_new, distance to target, valid, states
        looked at)``; a distance below :data:`ZERO_LENGTH` is a refused motion, nothing checked
        ``(x_new undefined, distance, False, 0)``."""
        distance = self._distance
        x_new = np.empty(self.dof)
        while True:
            r = self._steer_run(a, target, step, resolution, low, high, bisection, self._packed, x_new, distance)
            if r != 0:
                break
            self._grow_for(min(step, float(distance[0])), resolution)
        d = float(distance[0])
        if d < ZERO_LENGTH:
            return x_new, d, False, 0
        return (x_new, d, True, r) if r > 0 else (x_new, d, False, -r)

    def _grow_for(self, length: float, resolution: float) -> None:
        """Room for an edge of ``length`` checked every ``resolution`` (the kernel answered 0: too few)."""
        self._grow(max(2 * self._known.shape[0], int(math.ceil(length / resolution)) + 2))

    def _grow(self, states: int) -> None:
        """Room for the distance bounds of ``states`` states of an edge."""
        pairs = len(self.links) + len(self._pairs)
        self._gaps = np.zeros((states, pairs))
        self._known = np.zeros(states, dtype=np.bool_)
        self._queue = np.zeros((2 * states + 2, 2), dtype=np.int64)   # two intervals per state
        self._pack()

    def motion_rates(self, a: np.ndarray, b: np.ndarray, n: int, k: int) -> dict[str, np.ndarray]:
        """The bounds the edge check skips states with, at state ``k`` of the edge ``a -> b`` of ``n``
        steps: per link, ``delta`` (how far its spheres move per state anywhere), ``rate`` (how fast
        here) and ``curve`` (how much that speed changes per state), so that over ``s`` states they
        move at most ``min(s delta, s rate + s^2 curve / 2)``; per self pair, the same for the
        relative motion (``pair_rate`` 0 where neither link is below the other: ``pair_delta`` only)."""
        kernels = _kernels()
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        rot, trans = self.link_frames(a + (k / n) * (b - a))
        omega, vel = np.zeros((len(self.links), 3)), np.zeros((len(self.links), 3))
        kernels["velocities"](a, b, n, self._parent, self._kind, self._axis, self._q_index, rot, trans, omega, vel)
        out = {name: np.zeros(size) for name, size in (("delta", len(self.links)), ("curve", len(self.links)),
                                                       ("pair_delta", len(self._pairs)),
                                                       ("pair_curve", len(self._pairs)))}
        kernels["motion_bounds"](a, b, n, self._reach, out["delta"], out["curve"])
        kernels["motion_bounds"](a, b, n, self._pair_reach, out["pair_delta"], out["pair_curve"])
        rate = kernels["rate"]
        nodes = self.model.nodes
        out["rate"] = np.array([rate(i, -1, r, nodes, rot, trans, omega, vel) if r >= 0 else 0.0
                                for i, r in enumerate(self._root)])
        out["pair_rate"] = np.array([rate(m, la + lb - m, self._self_root[m], nodes, rot, trans, omega, vel)
                                     if m >= 0 else 0.0 for (la, lb), m in zip(self._pairs, self._pair_moving)])
        return out

    def table_room(self, q: np.ndarray) -> np.ndarray:
        """Per self pair, its joint-space table's entry at ``q`` (:meth:`_joint_tables`; -1: no table):
        ``d >= 1`` when ``q``'s cell, and every configuration less than ``d - 1`` cells from ``q`` in each
        of the pair's joints, is free of contact between the pair's spheres."""
        room = _kernels()["table_room"]
        q = np.asarray(q, dtype=np.float64)
        return np.array([room(p, q, *self._tables) if self._tables[0][p] >= 0 else -1 for p in range(len(self._pairs))])

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotation ``(links, 3, 3)`` and translation ``(links, 3)`` of every link at ``q``."""
        rot, trans = np.zeros_like(self._rot), np.zeros_like(self._trans)
        _kernels()["forward_kinematics"](np.asarray(q, dtype=np.float64), self._parent, self._origin_r, self._origin_t,
                                         self._kind, self._axis, self._q_index, self._q_fixed, rot, trans)
        return rot, trans
