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
state it looks at is one collision check, as with the pybullet checker. Everything is float64 and a
pure function of the configuration and the scene.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gnn_mp_envs.tasks.arm.urdf import FIXED, PRISMATIC, REVOLUTE, URDFRobot, read_urdf
from numba import types
from numba.experimental import structref

#: Obstacle kinds of the compiled tests.
BOX, CYLINDER, SPHERE = 0, 1, 2
_KINDS = {"box": BOX, "cylinder": CYLINDER, "sphere": SPHERE}
#: Along an edge the tree walks refine distance bounds below this many states' motion (more work
#: per tested state, fewer tested states; measured with tools/bench_checker.py).
REFINE = 3.0
#: Format tag of the sphere model files.
MODEL_FORMAT = "gnn-mp-envs sphere model, version 1"


# ---------------------------------------------------------------------- what the kernel reads
@structref.register
class CheckerArraysType(types.StructRef):
    """The numba type of :class:`CheckerArrays`."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class CheckerArrays(structref.StructRefProxy):
    """Every array the kernel reads, in one object: one argument to type-check per call instead of
    thirty (a compiled call costs about 75 ns per array argument)."""


_FIELDS = ("q", "gaps", "known", "reach", "pair_reach", "delta", "pdelta", "queue", "parent", "origin_r", "origin_t",
           "kind", "axis", "q_index", "q_fixed", "link_root", "self_root", "nodes", "first_child", "child_count",
           "pairs", "exempt", "ob_kind", "ob_centre", "ob_rot", "ob_size", "rot", "trans", "stack", "pair_stack")
structref.define_proxy(CheckerArrays, CheckerArraysType, list(_FIELDS))


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
        # parent * origin
        for i in range(3):
            acc = trans[p, i]
            for k in range(3):
                acc += rot[p, i, k] * origin_t[link, k]
            trans[link, i] = acc
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    acc += rot[p, i, k] * origin_r[link, k, j]
                rot[link, i, j] = acc
        if kind[link] == 1:        # revolute: times Rodrigues(axis, v)
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


def _gap(cx, cy, cz, r, kind, ox, oy, oz, r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz):
    """Distance from the sphere ``(c, r)`` to an obstacle, negative or zero when they touch: a box of
    half extents ``s``, a cylinder of radius ``sx`` and half height ``sy`` along its z, or a sphere of
    radius ``sx``; centred at ``o``, rotated by ``R`` (rows ``r0*``, ``r1*``, ``r2*``). Exact. Scalars
    only: a compiled call with array arguments costs more than the test."""
    dx, dy, dz = cx - ox, cy - oy, cz - oz
    if kind == 2:
        return math.sqrt(dx * dx + dy * dy + dz * dz) - r - sx
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
        return math.sqrt(ex * ex + ey * ey + ez * ez) - r
    er = math.sqrt(lx * lx + ly * ly) - sx
    ez = abs(lz) - sy
    er = er if er > 0.0 else 0.0
    ez = ez if ez > 0.0 else 0.0
    return math.sqrt(er * er + ez * ez) - r


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

    ``arrays`` (:class:`CheckerArrays`) holds the robot's kinematics and spheres, the scene and the
    scratch space.

    A state collides when a leaf of a link's obstacle tree touches an obstacle or a leaf of a
    checked link pair's self-collision trees touches the other's (depth first from the roots).
    Along an edge the answer and the count are those of testing every state, with less work: the
    walks that find no touching leaves leave lower bounds of the distances (the least gap of the
    nodes they pruned) in ``gaps[k, i]``, per link to every obstacle (``i = link``) and per self
    pair (``i = links + pair``); between neighbouring states a link's spheres move at most
    ``delta[link]`` (``reach`` times each joint's step) and a pair's relative to each other at most
    ``pdelta[pair]`` (only the joints between them count). So a link or pair whose bound at a
    checked neighbour state exceeds the motion since is free without a test; an interval whose two
    checked ends vouch for every link and pair across it is free as a whole, with the intervals
    under it (sequential order: the states ahead are skipped the same way)."""
    q, gaps, known, reach, pair_reach = arrays.q, arrays.gaps, arrays.known, arrays.reach, arrays.pair_reach
    delta, pdelta, queue, parent, origin_r = arrays.delta, arrays.pdelta, arrays.queue, arrays.parent, arrays.origin_r
    origin_t, kind, axis, q_index, q_fixed = arrays.origin_t, arrays.kind, arrays.axis, arrays.q_index, arrays.q_fixed
    link_root, self_root, nodes, first_child = arrays.link_root, arrays.self_root, arrays.nodes, arrays.first_child
    child_count, pairs, exempt, ob_kind, ob_centre = (arrays.child_count, arrays.pairs, arrays.exempt, arrays.ob_kind,
                                                      arrays.ob_centre)
    ob_rot, ob_size, rot, trans, stack, pair_stack = (arrays.ob_rot, arrays.ob_size, arrays.rot, arrays.trans,
                                                      arrays.stack, arrays.pair_stack)
    dof = q.shape[0]
    links = parent.shape[0]
    n_ob = ob_kind.shape[0]
    n_pairs = links + pairs.shape[0]
    n, limit = 1, 1
    row = 0
    phase = 0                   # edges: 0 the start, 1 the far end, 2 intervals, 3 sequential states
    k_next = 1
    head, tail = 0, 0
    lo, hi = 0, 0
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
        for link in range(links):
            acc = 0.0
            for j in range(dof):
                acc += abs(b[j] - a[j]) / n * reach[link, j]
            delta[link] = acc
        for p in range(pairs.shape[0]):
            acc = 0.0
            for j in range(dof):
                acc += abs(b[j] - a[j]) / n * pair_reach[p, j]
            pdelta[p] = acc
        for k in range(n + 1):
            known[k] = False
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
        elif phase == 1:                        # bisection: the far end first
            kk, LL = n, 0
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
                        step = delta[i] if i < links else pdelta[i - links]
                        gl, gr = gaps[L, i], gaps[R, i]
                        if not (gl > 0.0 and gr > 0.0 and gl + gr > (R - L) * step):
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
                    step = delta[i] if i < links else pdelta[i - links]
                    if step > 0.0:
                        r = gaps[last, i] / step
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
                        step = delta[i] if i < links else pdelta[i - links]
                        gaps[end, i] = gaps[last, i] - (end - last) * step
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
        if track:                                    # pairs never tested (exempt, no spheres) bound nothing
            for pr in range(gaps.shape[1]):
                gaps[kk, pr] = 1e300
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
                    bound = gaps[LL, link] - (kk - LL) * delta[link]
                if RR >= 0 and known[RR]:
                    other = gaps[RR, link] - (RR - kk) * delta[link]
                    bound = other if other > bound else bound
                if bound > 0.0:
                    gaps[kk, link] = bound
                    continue
            clearance = 1e300
            # along an edge, walks go on below nodes nearer than tau: the bound they leave then vouches
            # for about REFINE states on either side
            tau = REFINE * delta[link] if track else 0.0
            for o in range(n_ob):
                if exempt[o, link]:
                    continue
                least = 1e300
                top = 0
                stack[0] = root
                while top >= 0:
                    node = stack[top]
                    top -= 1
                    x, y, z = nodes[node, 0], nodes[node, 1], nodes[node, 2]
                    g = _gap(t0 + m00 * x + m01 * y + m02 * z, t1 + m10 * x + m11 * y + m12 * z,
                             t2 + m20 * x + m21 * y + m22 * z, nodes[node, 3], ob_kind[o],
                             ob_centre[o, 0], ob_centre[o, 1], ob_centre[o, 2],
                             ob_rot[o, 0, 0], ob_rot[o, 0, 1], ob_rot[o, 0, 2], ob_rot[o, 1, 0], ob_rot[o, 1, 1],
                             ob_rot[o, 1, 2], ob_rot[o, 2, 0], ob_rot[o, 2, 1], ob_rot[o, 2, 2],
                             ob_size[o, 0], ob_size[o, 1], ob_size[o, 2])
                    nc = child_count[node]
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
                clearance = least if least < clearance else clearance
            if hit:
                break
            if track:
                gaps[kk, link] = clearance
        # --- self-collision: simultaneous descent, splitting the larger of two touching inner nodes
        if not hit:
            for p in range(pairs.shape[0]):
                la, lb = pairs[p, 0], pairs[p, 1]
                pr = links + p
                if track:
                    bound = -1.0
                    step = pdelta[p]
                    if LL >= 0 and known[LL]:
                        bound = gaps[LL, pr] - (kk - LL) * step
                    if RR >= 0 and known[RR]:
                        other = gaps[RR, pr] - (RR - kk) * step
                        bound = other if other > bound else bound
                    if bound > 0.0:
                        gaps[kk, pr] = bound
                        continue
                least = 1e300
                tau = REFINE * pdelta[p] if track else 0.0
                top = 0
                pair_stack[0, 0] = self_root[la]
                pair_stack[0, 1] = self_root[lb]
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
                    if g > tau or (g > 0.0 and ca == 0 and cb == 0):
                        least = g if g < least else least
                        continue
                    if ca == 0 and cb == 0:
                        hit = True
                        break
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
                if hit:
                    break
                if track:
                    gaps[kk, pr] = least

        # ---- what follows from it
        if mode == 0:
            out[row] = not hit
            row += 1
        elif phase == 0:
            known[0] = not hit                  # a start in collision vouches for nothing
            phase = 1 if bisection else 3
        elif hit:
            return -(_position(n, kk, bisection, queue) + 1)
        else:
            known[kk] = True
            if phase == 1:
                queue[0, 0], queue[0, 1] = 1, n - 1
                head, tail, phase = 0, 1, 2
            elif phase == 2:
                queue[tail, 0], queue[tail, 1] = lo, kk - 1
                queue[tail + 1, 0], queue[tail + 1, 1] = kk + 1, hi
                tail += 2
            else:
                k_next = kk + 1


_KERNELS: dict[str, Any] = {}


def _kernels() -> dict[str, Any]:
    """The compiled kernels (numba, cached on disk next to this module; compiled on first use)."""
    if not _KERNELS:
        try:
            from numba import njit
        except ImportError:      # pragma: no cover - numba is a dependency
            raise ImportError("the sphere checker needs numba: pip install numba") from None
        g = globals()
        g["_gap"] = njit(cache=True, nogil=True, inline="always")(g["_gap"])
        g["_forward_kinematics"] = njit(cache=True, nogil=True)(g["_forward_kinematics"])
        g["_position"] = njit(cache=True, nogil=True)(g["_position"])
        _KERNELS["run"] = njit(cache=True, nogil=True)(_run)
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
        self._gaps = self._known = self._queue = np.zeros(0)
        self.set_obstacles(())

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
        self._grow(max(self._known.shape[0], 130))

    def _pack(self) -> None:
        """(Re)build the :class:`CheckerArrays` the kernel reads (after the scene or the scratch changed)."""
        self._packed = CheckerArrays(
            self._q, self._gaps, self._known, self._reach, self._pair_reach, self._delta, self._pdelta, self._queue,
            self._parent, self._origin_r, self._origin_t, self._kind, self._axis, self._q_index, self._q_fixed,
            self._root, self._self_root, self.model.nodes, self.model.first_child, self.model.child_count, self._pairs,
            self._exempt, self._ob_kind, self._ob_centre, self._ob_rot, self._ob_size, self._rot, self._trans,
            self._stack, self._pair_stack)

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
            self._grow(max(2 * self._known.shape[0], int(math.ceil(float(np.linalg.norm(b - a)) / resolution)) + 2))

    def _grow(self, states: int) -> None:
        """Room for the distance bounds of ``states`` states of an edge."""
        pairs = len(self.links) + len(self._pairs)
        self._gaps = np.zeros((states, pairs))
        self._known = np.zeros(states, dtype=np.bool_)
        self._queue = np.zeros((2 * states + 2, 2), dtype=np.int64)   # two intervals per state
        self._pack()

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotation ``(links, 3, 3)`` and translation ``(links, 3)`` of every link at ``q``."""
        rot, trans = np.zeros_like(self._rot), np.zeros_like(self._trans)
        _kernels()["forward_kinematics"](np.asarray(q, dtype=np.float64), self._parent, self._origin_r, self._origin_t,
                                         self._kind, self._axis, self._q_index, self._q_fixed, rot, trans)
        return rot, trans
