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
from gnn_mp_envs.utils.compiled import lazy_njit

#: Obstacle kinds of the compiled tests.
BOX, CYLINDER, SPHERE = 0, 1, 2
_KINDS = {"box": BOX, "cylinder": CYLINDER, "sphere": SPHERE}
#: Format tag of the sphere model files.
MODEL_FORMAT = "gnn-mp-envs sphere model, version 1"


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


def _touches(cx, cy, cz, r, kind, ox, oy, oz, r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz):
    """Whether the sphere ``(c, r)`` touches an obstacle (exact distance; touching counts): a box of
    half extents ``s``, a cylinder of radius ``sx`` and half height ``sy`` along its z, or a sphere of
    radius ``sx``; centred at ``o``, rotated by ``R`` (rows ``r0*``, ``r1*``, ``r2*``). Scalars only:
    a compiled call with array arguments costs more than the test."""
    dx, dy, dz = cx - ox, cy - oy, cz - oz
    if kind == 2:
        rr = r + sx
        return dx * dx + dy * dy + dz * dz <= rr * rr
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
        return ex * ex + ey * ey + ez * ez <= r * r
    er = math.sqrt(lx * lx + ly * ly) - sx
    ez = abs(lz) - sy
    er = er if er > 0.0 else 0.0
    ez = ez if ez > 0.0 else 0.0
    return er * er + ez * ez <= r * r


def _check_states(mode, qs, a, b, n, order, limit, out, q, parent, origin_r, origin_t, kind, axis, q_index,
                  q_fixed, link_root, self_root, nodes, first_child, child_count, pairs, exempt, ob_kind, ob_centre,
                  ob_rot, ob_size, rot, trans, stack, pair_stack):
    """The checker's one kernel, written out in one body (calls with array arguments cost more than
    the tests they would wrap).

    ``mode == 0``: ``out[i]`` = row ``i`` of ``qs`` is collision-free; returns the row count.
    ``mode == 1``: the edge ``a -> b``: the states ``a + (k / n) (b - a)`` for ``k`` in ``order``,
    stopping at the first invalid one (or the first ``k > limit``: out of bounds); returns the
    number of states looked at, negated when the edge is invalid.

    Per state: forward kinematics, then each link's obstacle tree against each obstacle and each
    checked link pair's self-collision trees against each other, depth first from the roots,
    stopping at the first touching pair of leaves."""
    total = order.shape[0] if mode == 1 else qs.shape[0]
    dof = q.shape[0]
    links = parent.shape[0]
    checks = 0
    for idx in range(total):
        if mode == 1:
            k = order[idx]
            checks += 1
            if k > limit:
                return -checks
            t = k / n
            for j in range(dof):
                q[j] = a[j] + t * (b[j] - a[j])
        else:
            checks += 1
            for j in range(dof):
                q[j] = qs[idx, j]
        _forward_kinematics(q, parent, origin_r, origin_t, kind, axis, q_index, q_fixed, rot, trans)
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
            for o in range(ob_kind.shape[0]):
                if exempt[o, link]:
                    continue
                top = 0
                stack[0] = root
                while top >= 0:
                    node = stack[top]
                    top -= 1
                    x, y, z = nodes[node, 0], nodes[node, 1], nodes[node, 2]
                    if _touches(t0 + m00 * x + m01 * y + m02 * z, t1 + m10 * x + m11 * y + m12 * z,
                                t2 + m20 * x + m21 * y + m22 * z, nodes[node, 3], ob_kind[o],
                                ob_centre[o, 0], ob_centre[o, 1], ob_centre[o, 2],
                                ob_rot[o, 0, 0], ob_rot[o, 0, 1], ob_rot[o, 0, 2], ob_rot[o, 1, 0], ob_rot[o, 1, 1],
                                ob_rot[o, 1, 2], ob_rot[o, 2, 0], ob_rot[o, 2, 1], ob_rot[o, 2, 2],
                                ob_size[o, 0], ob_size[o, 1], ob_size[o, 2]):
                        nc = child_count[node]
                        if nc == 0:
                            hit = True
                            break
                        for c in range(first_child[node], first_child[node] + nc):
                            top += 1
                            stack[top] = c
                if hit:
                    break
            if hit:
                break
        # --- self-collision: simultaneous descent, splitting the larger of two touching inner nodes
        if not hit:
            for p in range(pairs.shape[0]):
                la, lb = pairs[p, 0], pairs[p, 1]
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
                    rr = nodes[na_, 3] + nodes[nb_, 3]
                    if dx * dx + dy * dy + dz * dz > rr * rr:
                        continue
                    ca, cb = child_count[na_], child_count[nb_]
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
        if mode == 1:
            if hit:
                return -checks
        else:
            out[idx] = not hit
    return checks


_KERNELS: dict[str, Any] = {}


def _kernels() -> dict[str, Any]:
    """The compiled kernels (numba, cached on disk next to this module; compiled on first use)."""
    if not _KERNELS:
        try:
            from numba import njit
        except ImportError:      # pragma: no cover - numba is a dependency
            raise ImportError("the sphere checker needs numba: pip install numba") from None
        g = globals()
        g["_touches"] = njit(cache=True, nogil=True, inline="always")(g["_touches"])
        g["_forward_kinematics"] = njit(cache=True, nogil=True)(g["_forward_kinematics"])
        _KERNELS["check_states"] = njit(cache=True, nogil=True)(_check_states)
        _KERNELS["forward_kinematics"] = g["_forward_kinematics"]
    return _KERNELS


# ---------------------------------------------------------------------- the checker
def _quaternion_matrix(q: Sequence[float]) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


_NO_ORDER = np.zeros(0, dtype=np.int64)
_NO_ORDER.setflags(write=False)            # the edge orders are read-only too: one compiled signature
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
        self.set_obstacles(())

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

    def _common(self) -> tuple:
        return (self._q, self._parent, self._origin_r, self._origin_t, self._kind, self._axis, self._q_index,
                self._q_fixed, self._root, self._self_root, self.model.nodes, self.model.first_child,
                self.model.child_count, self._pairs, self._exempt, self._ob_kind, self._ob_centre, self._ob_rot,
                self._ob_size, self._rot, self._trans, self._stack, self._pair_stack)

    def valid(self, states: np.ndarray) -> np.ndarray:
        """Whether each row of ``states`` is collision-free (joint limits are the caller's)."""
        qs = np.ascontiguousarray(np.asarray(states, dtype=np.float64).reshape(-1, self.dof))
        out = np.zeros(len(qs), dtype=np.bool_)
        _kernels()["check_states"](0, qs, self._q, self._q, 1.0, _NO_ORDER, 0, out, *self._common())
        return out

    def check_edge(self, a: np.ndarray, b: np.ndarray, n: int, order: np.ndarray, limit: int) -> tuple[bool, int]:
        """Check ``a + (k / n)(b - a)`` for ``k`` in ``order`` until the first invalid state (``k >
        limit`` counts as invalid: out of bounds): ``(valid, states looked at)``."""
        r = _kernels()["check_states"](1, _NO_STATES, a, b, float(n), order, limit, _NO_OUT, *self._common())
        return r > 0, abs(int(r))

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotation ``(links, 3, 3)`` and translation ``(links, 3)`` of every link at ``q``."""
        rot, trans = np.zeros_like(self._rot), np.zeros_like(self._trans)
        _kernels()["forward_kinematics"](np.asarray(q, dtype=np.float64), self._parent, self._origin_r, self._origin_t,
                                         self._kind, self._axis, self._q_index, self._q_fixed, rot, trans)
        return rot, trans
