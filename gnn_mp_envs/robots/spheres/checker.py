"""The sphere checker: :class:`SphereChecker` holds one robot's kinematics, sphere trees, self pairs,
joint-space tables and one scene as the compiled kernel reads them (:mod:`~gnn_mp_envs.robots.spheres.kernel`),
and :class:`SphereCollisionChecker` is the :class:`~gnn_mp_envs.robots.checkers.Checker` of a
:class:`~gnn_mp_envs.robots.world.RobotWorld` that plans with it.

States of an edge are skipped only where certified bounds vouch for them: how far and how fast each
link can move along the edge, and, for self pairs that only one or two joints move (or three, one of them
turning a link about its own axis), a joint-space table of where they are free. Each state the kernel
looks at is one collision check, as with the pybullet checker.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gnn_mp_envs.core.loop import CompiledKernel
from gnn_mp_envs.core.problem import ZERO_LENGTH
from gnn_mp_envs.robots.geometry import Obstacle, Scene
from gnn_mp_envs.robots.model import sphere_model_path, urdf_file
from gnn_mp_envs.robots.spheres import kernel, kinematics
from gnn_mp_envs.robots.spheres.kernel import (BOX, COLUMNS, CYLINDER, KINDS, SPHERE, Kinematics, Memo, Obstacles,
                                               Scratch, Spheres, Tables, check_edge, check_states, free_cells,
                                               joint_distance, planner_motion, planner_steer, steer_edge, table_room)
from gnn_mp_envs.robots.spheres.model import SphereModel, SphereModelError, leaf_rows, load_sphere_model
from gnn_mp_envs.robots.urdf import FIXED, PRISMATIC, REVOLUTE, URDFRobot, read_urdf
from gnn_mp_envs.utils.compiled import FALLBACK_CACHE_DIR, sources_stamp
from gnn_mp_envs.utils.npz import DatasetCacheError, read_npz, write_npz

#: Joint-space tables of the self pairs (:meth:`SphereChecker._joint_tables`): a cell is free when the pair's
#: leaves are more than this apart at its centre (m); smaller: finer tables.
TABLE_FLOOR = 0.003
#: At most this many cells per pair's table (a coarser grid, with a higher floor, past it). The UR5's base and
#: upper arm, within 8.4 mm of each other at every shoulder pan and lift, take 0.87 million cells at a 3.75 mm
#: floor, half of them free (at 2^17 cells the floor grew past the gap). Tables are built once per machine
#: and inputs (:func:`tables_file`).
TABLE_CELLS = 1 << 20
#: How many tested edge ends (free far ends and starts) the checker remembers, with the clearances their
#: walks found, so that an edge starting at one (the tree's nodes are the far ends of the edges that
#: made them) need not walk again.
MEMO_STATES = 128
_TABLES: dict[tuple, Tables] = {}


def _quaternion_matrix(q: Sequence[float]) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _tree_depth(nodes: np.ndarray, first_child: np.ndarray, child_count: np.ndarray) -> int:
    """Levels of the deepest of the trees ``nodes`` holds."""
    depth = np.zeros(len(nodes), dtype=np.int64)
    for i in range(len(nodes)):                 # breadth-first rows: parents before children
        if child_count[i]:
            depth[first_child[i]:first_child[i] + child_count[i]] = depth[i] + 1
    return int(depth.max()) + 1


def _merged_tree(nodes: np.ndarray, first_child: np.ndarray, child_count: np.ndarray, base: int,
                 members: Sequence[tuple[int, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One sphere tree over several trees of links rigidly joined, in one link's frame: ``members`` are
    ``(root, R, t)``, a tree's root row and its link's frame in that frame. The new root (a sphere around
    the members' roots) has the members' roots as its children, and below them their trees, moved by
    ``(R, t)``: the same leaves, so the same answers. Rows from ``base`` on, breadth first (each node's
    children consecutive); returns the new rows' ``nodes``, ``first_child``, ``child_count``."""
    order = [(int(root), k) for k, (root, _, _) in enumerate(members)]      # below the new root: (row, member)
    out_first, out_count = [base + 1], [len(members)]
    i = 0
    while i < len(order):
        row, k = order[i]
        out_first.append(base + 1 + len(order) if child_count[row] else 0)
        out_count.append(int(child_count[row]))
        order.extend((c, k) for c in range(first_child[row], first_child[row] + child_count[row]))
        i += 1
    rows = np.array([row for row, _ in order], dtype=np.int64)
    which = np.array([k for _, k in order], dtype=np.int64)
    moved = np.empty((len(order), 4))
    for k, (_, rot, trans) in enumerate(members):
        mine = which == k
        moved[mine, :3] = nodes[rows[mine], :3] @ rot.T + trans
        moved[mine, 3] = nodes[rows[mine], 3]
    from gnn_mp_envs.robots.spheres.build import bounding_sphere
    root = bounding_sphere(moved[: len(members)])
    return (np.vstack([root[None], moved]), np.array(out_first, dtype=np.int64),
            np.array(out_count, dtype=np.int64))


#: The format of the joint tables' files (:func:`tables_file`).
TABLES_FORMAT = 1


def tables_file(arrays: Sequence[np.ndarray], settings: tuple) -> Path:
    """Where the joint tables built from ``arrays`` (the robot's kinematics, sphere trees, self pairs and joint
    limits) and ``settings`` are kept between processes: a file named by a digest of all of them and of the
    package's sources (:func:`~gnn_mp_envs.utils.compiled.sources_stamp`: changed code builds anew), in
    numba's cache folder (``NUMBA_CACHE_DIR``, else the package's ``__pycache__``, else the fallback folder)."""
    from numba.core import config
    digest = hashlib.sha256(f"{sources_stamp()};{settings!r};".encode())
    for a in arrays:
        a = np.ascontiguousarray(a)
        digest.update(f"{a.dtype.str}{a.shape};".encode())
        digest.update(a.tobytes())
    folder = Path(config.CACHE_DIR) if config.CACHE_DIR else Path(__file__).resolve().parent / "__pycache__"
    if not os.access(folder if folder.exists() else folder.parent, os.W_OK):
        folder = Path(FALLBACK_CACHE_DIR)
    return folder / f"joint-tables-{digest.hexdigest()[:40]}.npz"


def _obstacle_arrays(kind: np.ndarray, centre: np.ndarray, rot: np.ndarray, size: np.ndarray,
                     exempt: np.ndarray) -> Obstacles:
    """The kernel's :class:`~gnn_mp_envs.robots.spheres.kernel.Obstacles`: the obstacles in runs of one kind
    (boxes, cylinders, spheres; in their given order within a run: an answer does not depend on the
    order) and their numbers by coordinate, for the tests of a root sphere against all of them at once."""
    order = np.argsort(kind, kind="stable")
    kind, centre, rot, size, exempt = (np.ascontiguousarray(a[order]) for a in (kind, centre, rot, size, exempt))
    runs = np.array([np.count_nonzero(kind <= k) for k in (BOX, CYLINDER, SPHERE)], dtype=np.int64)
    columns = np.ascontiguousarray(np.concatenate([centre.T, rot.reshape(-1, 9).T, size.T]).reshape(COLUMNS, -1))
    return Obstacles(kind, centre, rot, size, exempt, runs, columns, np.zeros(len(kind)))


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
        parent = np.full(n, -1, dtype=np.int64)
        origin_r, origin_t, axis = np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        kind = np.zeros(n, dtype=np.int64)
        q_index = np.full(n, -1, dtype=np.int64)
        q_fixed = np.zeros(n)
        position = {name: k for k, name in enumerate(joints)}
        for link, j in robot.joints.items():
            i = index[link]
            parent[i] = index[j.parent]
            origin_r[i], origin_t[i], axis[i] = j.rotation, j.translation, j.axis
            kind[i] = j.kind
            if j.name in position:
                if j.kind == FIXED:
                    raise ValueError(f"joint {j.name!r} is fixed and cannot be planned")
                q_index[i] = position[j.name]
            else:
                q_fixed[i] = float(held.get(j.name, 0.0))
        #: The robot's kinematic tree as the kernel reads it.
        self.kinematics = Kinematics(parent, origin_r, origin_t, kind, axis, q_index, q_fixed)
        link_root = np.array([model.roots.get(name, -1) for name in robot.links], dtype=np.int64)
        self_root = np.array([model.self_roots.get(name, -1) for name in robot.links], dtype=np.int64)
        skip = {frozenset(p) for p in allowed} | robot.parent_child_pairs()
        with_spheres = [name for name in robot.links if name in model.roots]
        pairs = np.array([(index[a], index[b]) for k, a in enumerate(with_spheres) for b in with_spheres[k + 1:]
                          if frozenset((a, b)) not in skip], dtype=np.int64).reshape(-1, 2)
        #: The checked self pairs, by link name.
        self.self_pairs = [(self.links[a], self.links[b]) for a, b in pairs]
        reach = self._joint_reach(robot, held, link_root, self_root)
        nodes, first_child, child_count, pairs, pair_root, pair_own = self._body_pairs(pairs, self_root)
        # a self pair moves relative to itself only through the joints that move one link and not the other
        ra, rb = (np.array([reach[link] if own is None else self._levers(robot, link, own, held) for link, own in
                            zip(pairs[:, side], pair_own[side])]).reshape(-1, self.dof) for side in (0, 1))
        pair_reach = np.where(rb == 0, ra, 0.0) + np.where(ra == 0, rb, 0.0)
        # per self pair, the link that moves in the other's frame (-1: neither): the one below the other, else
        # the one moved by every planned joint that moves the other (-1: each has a joint of its own)
        pair_moving = np.array([self._moving(a_, b_, reach) for a_, b_ in pairs], dtype=np.int64)
        nodes, first_child, child_count, bodies = self._body_trees(robot, held, link_root, reach, nodes, first_child,
                                                                   child_count)
        #: The moving rigid bodies whose links' obstacle trees are one tree: head link -> (members, that tree's
        #: root, the head's levers for it); a scene uses it where it exempts every member alike (set_obstacles).
        self.bodies = bodies
        self._own_roots, self._own_reach = link_root, reach
        #: The sphere trees, the self pairs and the joints' levers.
        roots, levers = self._scene_roots(np.zeros((0, n), dtype=np.bool_))
        self.spheres = Spheres(roots, nodes, first_child, child_count, pairs, pair_root, pair_moving, levers,
                               pair_reach)
        # depth-first stacks: at most (children per node) entries per level of the deepest tree
        # (two trees for pairs)
        depth = _tree_depth(nodes, first_child, child_count)
        width = int(child_count.max()) + 1
        k = len(pairs)
        empty = np.zeros(0)
        self.scratch = Scratch(np.zeros(self.dof), np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3)),
                               np.zeros((n, 3)), np.zeros(width * depth + 1, dtype=np.int64),
                               np.zeros((width * 2 * depth + 1, 2), dtype=np.int64),
                               np.zeros((width * 2 * depth + 1, 3)), empty.reshape(0, n + k),
                               np.zeros(0, dtype=np.bool_), np.zeros((0, 2), dtype=np.int64), np.zeros(n),
                               np.zeros(k), np.zeros(n), np.zeros(k), np.zeros(k))
        self.memo = Memo(np.full((MEMO_STATES, self.dof), np.nan), np.zeros((MEMO_STATES, n + k)),
                         np.zeros(2, dtype=np.int64))
        self.tables = self._joint_tables(robot, joints, held)
        self._distance = np.zeros(1)          # where the steer kernel writes the distance it measured
        self.set_obstacles(())                # the kernel's obstacle arrays (an empty scene) and its table

    # ------------------------------------------------------------------ construction
    def _joint_tables(self, robot: URDFRobot, joints: Sequence[str], held: dict[str, float]) -> Tables:
        """Joint-space tables of the self pairs whose relative pose only one or two joints change
        (the wrist's), or three of which one turns a link about its own axis (:meth:`_spin_side`: the
        table then holds for the solid the link sweeps at every angle of that joint): over a grid of those
        joints, how many cells around each cell are free of contact between the pair. A cell is free
        when the pair's leaves are more than ``TABLE_FLOOR`` apart at its centre; within the cell they
        come at most that much nearer. Built once per robot and pair set and kept in a file
        (:meth:`_stored_joint_tables`; building the UR5's takes seconds)."""
        key = (robot.name, id(self.model), tuple(joints), tuple(sorted(held.items())), self.spheres.pairs.tobytes(),
               self.spheres.pair_root.tobytes())
        if key not in _TABLES:
            _TABLES[key] = self._stored_joint_tables(robot, joints, held)
        return _TABLES[key]

    def _stored_joint_tables(self, robot: URDFRobot, joints: Sequence[str], held: dict[str, float]) -> Tables:
        """The joint tables from the file that a process before this one built from the same inputs
        (:func:`tables_file`), else built (seconds for the UR5) and written there for the next process.
        A file that cannot be read is built again; one that cannot be written is not kept."""
        limits = {j.name: (j.lower, j.upper) for j in robot.joints.values()}
        inputs = (*self.kinematics, self.spheres.nodes, self.spheres.first_child, self.spheres.child_count,
                  self.spheres.pairs, self.spheres.pair_root, self.spheres.pair_reach,
                  np.array(list(limits.values()), dtype=np.float64))
        path = tables_file(inputs, (robot.name, tuple(joints), tuple(sorted(held.items())), TABLE_FLOOR,
                                    TABLE_CELLS))
        try:
            stored = read_npz(path, TABLES_FORMAT)
            return Tables(*(np.ascontiguousarray(stored[name], dtype=dtype) for name, dtype, _ in Tables.spec))
        except (OSError, DatasetCacheError, KeyError):
            pass
        tables = self._build_joint_tables(joints, held, limits)
        try:
            write_npz(path, {"format_version": np.array(TABLES_FORMAT), **tables._asdict()})
        except OSError:
            pass
        return tables

    def _build_joint_tables(self, joints: Sequence[str], held: dict[str, float],
                            limits: dict[str, tuple[float, float]]) -> Tables:
        """The tables of the self pairs that one or two joints move, or three with one turning a link about its
        own axis (``limits``: each joint's, by name)."""
        from scipy.ndimage import distance_transform_cdt
        pairs, pair_reach = self.spheres.pairs, self.spheres.pair_reach
        n_pairs = len(pairs)
        at = np.full(n_pairs, -1, dtype=np.int64)
        joint = np.full((n_pairs, 2), -1, dtype=np.int64)
        low_ = np.zeros((n_pairs, 2))
        step_ = np.ones((n_pairs, 2))
        dim_ = np.ones((n_pairs, 2), dtype=np.int64)
        chunks: list[np.ndarray] = []
        size = 0
        q = np.array([float(held.get(name, 0.0)) for name in joints])
        kin, spheres, scratch = self.kinematics, self.spheres, self.scratch
        for p in range(n_pairs):
            moving = np.flatnonzero(pair_reach[p] > 0)
            la, lb = pairs[p]
            root_a, root_b = spheres.pair_root[p]
            spin = self._spin_side(pairs[p], moving)
            if spin is not None:                # one link also turns about its own axis: its swept solid
                if spin == 0:
                    la, lb, root_a, root_b = lb, la, root_b, root_a
                moving = moving[moving != kin.q_index[lb]]
            if not 1 <= len(moving) <= 2:
                continue
            low, high = (np.array([limits[joints[j]][k] for j in moving]) for k in (0, 1))
            if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
                continue
            # each joint's share of the floor: cells of ``2 * share / lever`` radians
            floor = TABLE_FLOOR
            while True:
                step = 2 * (floor / len(moving)) / pair_reach[p, moving]
                dim = np.ceil((high - low) / step).astype(np.int64)
                if np.prod(dim) <= TABLE_CELLS:
                    break
                floor *= 1.25
            free = np.zeros(int(np.prod(dim)), dtype=np.bool_)
            grid_joints = np.array([*moving, -1][:2], dtype=np.int64)
            grid = (grid_joints, low, step, np.array([*dim, 1][:2], dtype=np.int64), floor)
            robot_arrays = (q.copy(), kin.parent, kin.origin_r, kin.origin_t, kin.kind, kin.axis, kin.q_index,
                            kin.q_fixed)
            spin_axis = np.zeros(3) if spin is None else kin.axis[lb] / np.linalg.norm(kin.axis[lb])
            free_cells(la, lb, root_a, root_b, *grid, spin_axis, *robot_arrays, spheres.nodes, spheres.first_child,
                       spheres.child_count, scratch.rot, scratch.trans, scratch.pair_stack, scratch.pair_point, free)
            if not free.any():                  # always near contact at this floor: the walk decides
                continue
            # cells to the nearest cell that is not free (in any joint); all free: as good as unbounded
            room = (distance_transform_cdt(free.reshape(dim), metric="chessboard").ravel() if not free.all()
                    else np.full(free.size, 1 << 30))
            at[p] = size
            joint[p, : len(moving)] = moving
            low_[p, : len(moving)] = low
            step_[p, : len(moving)] = step
            dim_[p, : len(moving)] = dim
            chunks.append(room.astype(np.int32))
            size += room.size
        cells = np.concatenate(chunks) if chunks else np.zeros(1, dtype=np.int32)
        return Tables(at, joint, low_, step_, dim_, cells)

    def _spin_side(self, pair: np.ndarray, moving: np.ndarray) -> int | None:
        """The side (0, 1) of a self pair moved by three joints whose link is one of them turning about its
        own axis (the joint into it: revolute, planned); None if none. Turning about that axis, the link's
        spheres sweep a solid that no angle leaves, so a table over the other two joints holds for every
        angle of the third (:func:`~gnn_mp_envs.robots.spheres.kernel.spun_pair_near`)."""
        if len(moving) != 3:
            return None
        kin = self.kinematics
        for side in (1, 0):
            link = pair[side]
            if kin.kind[link] == REVOLUTE and kin.q_index[link] in moving:
                return side
        return None

    def _moving(self, a: int, b: int, reach: np.ndarray) -> int:
        """The link of the self pair ``(a, b)`` that moves in the other's frame, -1: neither.

        The one below the other; else, where the planned joints that move one link all move the other
        too (a link on the torso beside the arm, or rigidly on the root: none), the other. Either way
        the joints both share move both links as one rigid body, so the pair's relative motion is that
        of a chain of the other link's own joints below a fixed link, the case
        :func:`~gnn_mp_envs.robots.spheres.kinematics.motion_bounds` and
        :func:`~gnn_mp_envs.robots.spheres.kinematics.rate` bound (``pair_reach``: those joints' levers)."""
        below = self._below(b, a)
        if below >= 0:
            return below
        below = self._below(a, b)
        if below >= 0:
            return below
        ja, jb = reach[a] > 0, reach[b] > 0
        if not np.any(jb & ~ja):            # b's joints all move a: a moves in b's frame
            return a
        if not np.any(ja & ~jb):
            return b
        return -1

    def _below(self, link: int, other: int) -> int:
        """``link`` if ``other`` is one of its ancestors, else -1."""
        parent = self.kinematics.parent
        up = parent[link]
        while up >= 0:
            if up == other:
                return link
            up = parent[up]
        return -1

    def _body(self, link: int) -> int:
        """The link that ``link`` is rigidly joined to nearest the root: up its fixed and held joints."""
        parent, q_index = self.kinematics.parent, self.kinematics.q_index
        while parent[link] >= 0 and q_index[link] < 0:
            link = parent[link]
        return link

    def _rigid_bodies(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each link's body (:meth:`_body`) and the link frames at one configuration (any: bodies are rigid)."""
        body = np.array([self._body(i) for i in range(len(self.links))], dtype=np.int64)
        kin, n = self.kinematics, len(self.links)
        rot, trans = np.zeros((n, 3, 3)), np.zeros((n, 3))
        kinematics.forward_kinematics(np.zeros(self.dof), kin.parent, kin.origin_r, kin.origin_t, kin.kind, kin.axis,
                                      kin.q_index, kin.q_fixed, rot, trans)
        return body, rot, trans

    def _body_pairs(self, pairs: np.ndarray, self_root: np.ndarray) -> tuple:
        """The self pairs as the kernel checks them, with the same answers and less work: links rigidly
        joined (fixed or held joints: a gripper's parts, a torso and its head) are one rigid body.

        A pair within one body never moves: its spheres are tested here once (apart, or every
        configuration would collide: :class:`ValueError`) and dropped. The pairs between two bodies that
        are every link of one set against every link of another (a forearm against the gripper's nine
        parts) become one pair whose trees (:func:`_merged_tree`) cover each set in its body's frame, so
        that a walk descends the forearm's tree once, not nine times; other pairs stay as they are.
        Returns the nodes (the model's and the merged trees'), ``first_child``, ``child_count``, the
        kernel's ``pairs``, ``pair_root`` and, per side, the merged tree's reach from its frame's origin
        (``None``: a link's own trees, whose levers :meth:`_joint_reach` gives)."""
        model = self.model
        nodes, first_child, child_count = model.nodes, model.first_child, model.child_count
        body, rot, trans = self._rigid_bodies()
        groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
        for a, b in pairs:
            if body[a] == body[b]:
                self._check_rigid_pair(a, b, rot, trans)
                continue
            groups.setdefault((body[a], body[b]) if body[a] < body[b] else (body[b], body[a]), []).append((a, b))
        out_pairs, out_roots, out_own = [], [], ([], [])
        extra: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        merged: dict[tuple[int, ...], tuple[int, float]] = {}
        size = len(nodes)

        def side(head: int, links: list[int]) -> tuple[int, int, float | None]:
            """(frame link, tree root, its reach): a link's own tree, or one tree over several in ``head``'s frame."""
            nonlocal size
            if len(links) == 1:
                return links[0], int(self_root[links[0]]), None
            key = (head, *links)
            if key not in merged:
                members = [(self_root[m], rot[head].T @ rot[m], rot[head].T @ (trans[m] - trans[head])) for m in links]
                tree = _merged_tree(nodes, first_child, child_count, size, members)
                merged[key] = (size, float(np.linalg.norm(tree[0][0, :3]) + tree[0][0, 3]))
                extra.append(tree)
                size += len(tree[0])
            return (head, *merged[key])

        for (ha, hb), members in groups.items():
            side_a = sorted({a if body[a] == ha else b for a, b in members})
            side_b = sorted({b if body[b] == hb else a for a, b in members})
            if len(members) == 1 or len(members) != len(side_a) * len(side_b):
                for a, b in members:                 # one pair, or not every link against every link: as they are
                    out_pairs.append((a, b))
                    out_roots.append((self_root[a], self_root[b]))
                    out_own[0].append(None)
                    out_own[1].append(None)
                continue
            (la, ra, oa), (lb, rb, ob) = side(ha, side_a), side(hb, side_b)
            out_pairs.append((la, lb))
            out_roots.append((ra, rb))
            out_own[0].append(oa)
            out_own[1].append(ob)
        if extra:
            nodes = np.vstack([nodes, *(t[0] for t in extra)])
            first_child = np.concatenate([first_child, *(t[1] for t in extra)])
            child_count = np.concatenate([child_count, *(t[2] for t in extra)])
        return (nodes, first_child, child_count, np.array(out_pairs, dtype=np.int64).reshape(-1, 2),
                np.array(out_roots, dtype=np.int64).reshape(-1, 2), out_own)

    def _body_trees(self, robot: URDFRobot, held: dict[str, float], link_root: np.ndarray, reach: np.ndarray,
                    nodes: np.ndarray, first_child: np.ndarray, child_count: np.ndarray) -> tuple:
        """One obstacle tree per moving rigid body of several links with trees (a gripper's parts and the
        wrist link they hang from): the members' trees under one root in the body's frame
        (:func:`_merged_tree`), the same leaves, so a link far from everything costs one root test per
        obstacle for the whole body. Bodies fixed to the world keep their links' trees (they never move,
        so their walks are carried along every edge anyway). Returns the nodes, ``first_child`` and
        ``child_count`` with the merged trees appended, and :attr:`bodies`."""
        body, rot, trans = self._rigid_bodies()
        bodies: dict[int, tuple[np.ndarray, int, np.ndarray]] = {}
        extra, size = [], len(nodes)
        for head in np.unique(body):
            members = np.flatnonzero((body == head) & (link_root >= 0))
            if len(members) < 2 or self.kinematics.q_index[head] < 0:     # one link, or fixed to the world
                continue
            tree = _merged_tree(nodes, first_child, child_count, size,
                                [(link_root[m], rot[head].T @ rot[m], rot[head].T @ (trans[m] - trans[head]))
                                 for m in members])
            own = float(np.linalg.norm(tree[0][0, :3]) + tree[0][0, 3])
            bodies[int(head)] = (members, size, np.maximum(reach[head], self._levers(robot, int(head), own, held)))
            extra.append(tree)
            size += len(tree[0])
        if extra:
            nodes = np.vstack([nodes, *(t[0] for t in extra)])
            first_child = np.concatenate([first_child, *(t[1] for t in extra)])
            child_count = np.concatenate([child_count, *(t[2] for t in extra)])
        return nodes, first_child, child_count, bodies

    def _scene_roots(self, excused: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each link's obstacle tree root and levers for a scene whose exemptions are ``excused``
        (obstacles x links): a body's merged tree (:meth:`_body_trees`) where every obstacle exempts all
        of its members or none, else the members' own trees."""
        roots, levers = self._own_roots.copy(), self._own_reach.copy()
        for head, (members, root, reach) in self.bodies.items():
            if (excused[:, members] == excused[:, members[:1]]).all():
                roots[members] = -1
                roots[head], levers[head] = root, reach
        return roots, levers

    def _check_rigid_pair(self, a: int, b: int, rot: np.ndarray, trans: np.ndarray) -> None:
        """Links ``a`` and ``b`` never move relative to each other: their spheres must be apart."""
        from scipy.spatial import cKDTree
        la, lb = (self.model.leaves(self.links[i], True) for i in (a, b))
        wa, wb = (leaves[:, :3] @ rot[i].T + trans[i] for leaves, i in ((la, a), (lb, b)))
        tree = cKDTree(wb)
        for i, near in enumerate(tree.query_ball_point(wa, la[:, 3] + lb[:, 3].max())):
            if near and (np.linalg.norm(wb[near] - wa[i], axis=1) <= la[i, 3] + lb[near, 3]).any():
                raise ValueError(f"links {self.links[a]!r} and {self.links[b]!r} are rigidly joined and their "
                                 f"spheres touch: every configuration would collide (allow the pair)")

    def _levers(self, robot: URDFRobot, link: int, own: float, held: dict[str, float]) -> np.ndarray:
        """``(dof,)``: :meth:`_joint_reach`'s row of ``link`` for spheres within ``own`` of its frame's origin."""
        out = np.zeros(self.dof)
        q_index = self.kinematics.q_index
        index = {name: i for i, name in enumerate(self.links)}
        length, name = own, self.links[link]
        while name in robot.joints:                  # up the chain to the root
            joint = robot.joints[name]
            j = q_index[index[name]]
            if j >= 0:
                out[j] = 1.0 if joint.kind == PRISMATIC else length
            length += float(np.linalg.norm(joint.translation))
            if joint.kind == PRISMATIC:              # its travel lengthens the lever of the joints above
                length += max(abs(joint.lower), abs(joint.upper), abs(held.get(joint.name, 0.0)))
            name = joint.parent
        return out

    def _joint_reach(self, robot: URDFRobot, held: dict[str, float], link_root: np.ndarray,
                     self_root: np.ndarray) -> np.ndarray:
        """``(links, dof)``: how far any point of each link's spheres can lie from each planned joint's
        axis (0 where the joint does not move the link; 1 for a prismatic joint: its motion), for
        every configuration: the lengths of the joint origins on the way down plus the reach of the
        link's root spheres (triangle inequality). A step ``dq`` moves the link's spheres by at most
        ``sum_j |dq_j| reach[link, j]``."""
        nodes = self.model.nodes
        reach = np.zeros((len(self.links), self.dof))
        for i in range(len(self.links)):
            own = max([float(np.linalg.norm(nodes[r, :3]) + nodes[r, 3])
                       for r in (link_root[i], self_root[i]) if r >= 0], default=0.0)
            reach[i] = self._levers(robot, i, own, held)
        return reach

    # ------------------------------------------------------------------ the scene and the table
    def set_obstacles(self, obstacles: Sequence[Any], exempt: dict[int, Sequence[str]] | None = None) -> None:
        """Load a scene: a sequence of :class:`~gnn_mp_envs.robots.geometry.Obstacle` (box, cylinder or
        sphere). ``exempt``: obstacle index -> links whose contact with it is not a collision (the
        base standing on the table)."""
        k = len(obstacles)
        kind = np.zeros(k, dtype=np.int64)
        centre, rot, size = np.zeros((k, 3)), np.zeros((k, 3, 3)), np.zeros((k, 3))
        for i, ob in enumerate(obstacles):
            kind[i] = KINDS[ob.kind]
            centre[i] = ob.position
            rot[i] = _quaternion_matrix(ob.quaternion())
            if ob.kind == "box":
                size[i] = ob.size
            elif ob.kind == "cylinder":
                size[i, :2] = (ob.size[0], ob.size[1] / 2)
            else:
                size[i, 0] = ob.size[0]
        excused = np.zeros((k, len(self.links)), dtype=np.bool_)
        index = {name: i for i, name in enumerate(self.links)}
        for o, links in (exempt or {}).items():
            for name in links:
                excused[o, index[name]] = True
        self.obstacles = _obstacle_arrays(kind, centre, rot, size, excused)
        roots, levers = self._scene_roots(excused)
        self.spheres = self.spheres._replace(link_root=roots, reach=levers)
        self.forget_edge_ends()         # clearances of the last scene's states
        if self.scratch.known.shape[0] < 130:
            self._grow(130)
        else:                           # the scratch is written before it is read: only the table is new
            self._pack()

    def forget_edge_ends(self) -> None:
        """Forget the edge ends remembered with their walks' clearances (the memo): the next edges walk as
        a new checker's would. Only the work changes, never an answer or a count."""
        self.memo.meta[:] = 0
        self.memo.q[:] = np.nan

    def _pack(self) -> None:
        """(Re)build the table of addresses the kernel reads (:func:`~gnn_mp_envs.robots.spheres.kernel.pack`)
        after an array was replaced (a scene, more scratch); the arrays are kept alive with it."""
        groups = (self.kinematics, self.spheres, self.tables, self.obstacles, self.scratch, self.memo)
        table = kernel.pack(groups)
        packed = getattr(self, "_packed", None)
        if packed is not None and packed.shape == table.shape:
            packed[...] = table         # the same table object: a compiled kernel that holds it stays valid
        else:
            self._packed = table
        self._packed_groups = groups

    def _grow_for(self, length: float, resolution: float) -> None:
        """Room for an edge of ``length`` checked every ``resolution`` (the kernel answered 0: too few)."""
        self._grow(max(2 * self.scratch.known.shape[0], int(math.ceil(length / resolution)) + 2))

    def _grow(self, states: int) -> None:
        """Room for the distance bounds of ``states`` states of an edge."""
        rows = len(self.links) + len(self.spheres.pairs)
        self.scratch = self.scratch._replace(gaps=np.zeros((states, rows)), known=np.zeros(states, dtype=np.bool_),
                                             queue=np.zeros((2 * states + 2, 2), dtype=np.int64))  # two per state
        self._pack()

    # ------------------------------------------------------------------ checks
    def valid(self, states: np.ndarray) -> np.ndarray:
        """Whether each row of ``states`` is collision-free (joint limits are the caller's)."""
        qs = np.asarray(states, dtype=np.float64)
        if qs.ndim not in (1, 2) or qs.shape[-1] != self.dof:
            raise ValueError(f"states must have shape ({self.dof},) or (n, {self.dof}), got shape {qs.shape}")
        qs = np.ascontiguousarray(qs.reshape(-1, self.dof))
        out = np.zeros(len(qs), dtype=np.bool_)
        check_states(qs, out, self._packed)
        return out

    def check_motion(self, a: np.ndarray, b: np.ndarray, resolution: float, low: np.ndarray, high: np.ndarray,
                     bisection: bool = True) -> tuple[bool, int]:
        """Check the edge ``a -> b`` (``a`` valid: the tree's node) as the planner does: the states
        ``a + (k / n)(b - a)``, ``k = 1..n``, ``n = max(1, ceil(|b - a| / resolution))``, in the
        planner's order (``bisection``: ``n`` first, then by bisection; else ``1..n``) until the
        first invalid one, out of ``[low, high]`` or in collision: ``(valid, states that order looks
        at)``."""
        while True:
            r = check_edge(a, b, resolution, low, high, bisection, self._packed)
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
            r = steer_edge(a, target, step, resolution, low, high, bisection, self._packed, x_new, distance)
            if r != 0:
                break
            self._grow_for(min(step, float(distance[0])), resolution)
        d = float(distance[0])
        if d < ZERO_LENGTH:
            return x_new, d, False, 0
        return (x_new, d, True, r) if r > 0 else (x_new, d, False, -r)

    # ------------------------------------------------------------------ what the kernel uses, for tests
    def motion_rates(self, a: np.ndarray, b: np.ndarray, n: int, k: int) -> dict[str, np.ndarray]:
        """The bounds the edge check skips states with, at state ``k`` of the edge ``a -> b`` of ``n``
        steps: per link, ``delta`` (how far its spheres move per state anywhere), ``rate`` (how fast
        here) and ``curve`` (how much that speed changes per state), so that over ``s`` states they
        move at most ``min(s delta, s rate + s^2 curve / 2)``; per self pair, the same for the
        relative motion (``pair_rate`` 0 where neither link is below the other: ``pair_delta`` only)."""
        kin, spheres = self.kinematics, self.spheres
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        rot, trans = self.link_frames(a + (k / n) * (b - a))
        omega, vel = np.zeros((len(self.links), 3)), np.zeros((len(self.links), 3))
        kinematics.velocities(a, b, n, kin.parent, kin.kind, kin.axis, kin.q_index, rot, trans, omega, vel)
        out = {name: np.zeros(size) for name, size in (("delta", len(self.links)), ("curve", len(self.links)),
                                                       ("pair_delta", len(spheres.pairs)),
                                                       ("pair_curve", len(spheres.pairs)))}
        kinematics.motion_bounds(a, b, n, spheres.reach, out["delta"], out["curve"])
        kinematics.motion_bounds(a, b, n, spheres.pair_reach, out["pair_delta"], out["pair_curve"])
        rate, nodes = kinematics.rate, spheres.nodes
        out["rate"] = np.array([rate(i, -1, r, nodes, rot, trans, omega, vel) if r >= 0 else 0.0
                                for i, r in enumerate(spheres.link_root)])
        out["pair_rate"] = np.array([rate(m, la + lb - m, ra if m == la else rb, nodes, rot, trans, omega, vel)
                                     if m >= 0 else 0.0 for (la, lb), (ra, rb), m in
                                     zip(spheres.pairs, spheres.pair_root, spheres.pair_moving)])
        return out

    def link_leaves(self, link: int) -> np.ndarray:
        """The leaves ``(k, 4)`` of the kernel's obstacle tree of ``link`` (index) in its frame, for the scene
        loaded: the link's own, or those of every link of its rigid body (:meth:`_body_trees`); empty
        where the link has none (no spheres, or its body's tree holds them)."""
        s = self.spheres
        root = s.link_root[link]
        return s.nodes[leaf_rows(root, s.first_child, s.child_count)] if root >= 0 else np.zeros((0, 4))

    def pair_leaves(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """The leaves ``(k, 4)`` of the kernel's self pair ``p``'s two trees, each in the frame of its link
        (``spheres.pairs[p]``): a link's own self-collision spheres, or those of the links rigidly joined
        to it that the pair's tree covers (:meth:`_body_pairs`)."""
        s = self.spheres
        a, b = (s.nodes[leaf_rows(root, s.first_child, s.child_count)] for root in s.pair_root[p])
        return a, b

    def table_room(self, q: np.ndarray) -> np.ndarray:
        """Per self pair, its joint-space table's entry at ``q`` (:meth:`_joint_tables`; -1: no table):
        ``d >= 1`` when ``q``'s cell, and every configuration less than ``d - 1`` cells from ``q`` in each
        of the pair's joints, is free of contact between the pair's spheres."""
        q = np.asarray(q, dtype=np.float64)
        return np.array([table_room(p, q, self.tables) if self.tables.at[p] >= 0 else -1
                         for p in range(len(self.spheres.pairs))])

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotation ``(links, 3, 3)`` and translation ``(links, 3)`` of every link at ``q``."""
        kin = self.kinematics
        rot, trans = np.zeros_like(self.scratch.rot), np.zeros_like(self.scratch.trans)
        kinematics.forward_kinematics(np.asarray(q, dtype=np.float64), kin.parent, kin.origin_r, kin.origin_t,
                                      kin.kind, kin.axis, kin.q_index, kin.q_fixed, rot, trans)
        return rot, trans


def check_mesh_hashes(model: SphereModel, robot: URDFRobot, path: Path) -> None:
    """Refuse a sphere model made from other mesh files than the robot's (its recorded sha256 against the
    files the URDF names, where they are there), in one line naming the model file."""
    recorded = model.meta.get("mesh_sha256", {})
    for link in robot.links:
        for col in robot.collisions.get(link, ()):
            if col.mesh is not None and col.mesh.name in recorded and col.mesh.exists():
                if hashlib.sha256(col.mesh.read_bytes()).hexdigest() != recorded[col.mesh.name]:
                    raise SphereModelError(f"{path}: made from another {col.mesh.name} than {col.mesh} (sha256 "
                                           "differs): regenerate it with `python -m tools.spherize`")


class SphereCollisionChecker:
    """The :class:`~gnn_mp_envs.robots.checkers.Checker` of a world's robot with its shipped sphere model:
    one :class:`SphereChecker`, built on first use from the robot's URDF, sphere model and the world's
    joint names; the scene is loaded when it changes (with the box the robot stands on, which its base
    links may touch)."""

    name = "spheres"

    def __init__(self, world: Any) -> None:
        if world.robot_model.spheres is None:
            raise ValueError(f"robot {world.robot_model.urdf!r} has no sphere model; use checker='pybullet'")
        self.world = world
        self._checker: SphereChecker | None = None
        self._scene: object = None
        self._compiled: CompiledKernel | None = None

    def __getstate__(self) -> dict:
        """A checker pickles as its world (the compiled state is rebuilt on first use)."""
        return {"world": self.world}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["world"])

    def kernel(self, scene: Any) -> SphereChecker:
        """The robot's :class:`SphereChecker` with ``scene`` loaded."""
        if self._checker is None:
            self._checker = self._build()
        if scene is not self._scene:
            obstacles = list(scene.obstacles if isinstance(scene, Scene) else scene)
            exempt = {}
            table = self.world.robot_model.table
            if table is not None:
                exempt[len(obstacles)] = self._base_links
                obstacles.append(Obstacle(table.kind, table.size, table.position))
            self._checker.set_obstacles(obstacles, exempt)
            self._scene = scene
        return self._checker

    def _build(self) -> SphereChecker:
        world, model = self.world, self.world.robot_model
        world._require()
        p, cid, robot = world.p, world.client, world.robot
        name = lambda j: p.getJointInfo(robot, j, physicsClientId=cid)[1].decode()  # noqa: E731
        link = lambda j: (p.getBodyInfo(robot, physicsClientId=cid)[0].decode() if j < 0   # noqa: E731
                          else p.getJointInfo(robot, j, physicsClientId=cid)[12].decode())
        path = sphere_model_path(model.spheres)
        spheres = load_sphere_model(path)
        urdf = urdf_file(model.urdf)
        check_mesh_hashes(spheres, read_urdf(str(urdf)), path)
        checker = SphereChecker(urdf, spheres, [name(j) for j in model.joints],
                                {name(j): v for j, v in model.held_joints},
                                model.allowed_collisions)
        self._base_links = [link(j) for j in model.base_links]
        return checker

    def prepare(self, scene: Any) -> None:
        self.kernel(scene)

    def valid(self, scene: Any, states: np.ndarray) -> np.ndarray:
        return self.kernel(scene).valid(states)

    def check_motion(self, scene: Any, a: np.ndarray, b: np.ndarray, resolution: float, low: np.ndarray,
                     high: np.ndarray, bisection: bool) -> tuple[bool, int]:
        return self.kernel(scene).check_motion(a, b, resolution, low, high, bisection)

    def steer(self, scene: Any, a: np.ndarray, target: np.ndarray, step: float, resolution: float,
              low: np.ndarray, high: np.ndarray, bisection: bool) -> tuple[np.ndarray, float, bool, int]:
        return self.kernel(scene).steer(a, target, step, resolution, low, high, bisection)

    def compiled_kernel(self, scene: Any, step: float, resolution: float, low: np.ndarray, high: np.ndarray,
                        bisection: bool) -> CompiledKernel:
        """The planning loop's kernel (:mod:`gnn_mp_envs.core.loop`) for ``scene``, with room for edges of
        ``step`` checked every ``resolution`` (the loop cannot grow the scratch)."""
        checker = self.kernel(scene)
        if checker.scratch.known.shape[0] < math.ceil(step / resolution) + 2:
            checker._grow_for(step, resolution)
        kernel = self._compiled                   # the same object while nothing it holds changed
        if kernel is None or (kernel.context[0] is not checker._packed or kernel.context[1] is not low
                              or kernel.context[2] is not high or kernel.context[3] != resolution
                              or kernel.context[4] != bisection):
            kernel = self._compiled = CompiledKernel("spheres", planner_steer, planner_motion, joint_distance,
                                                     (checker._packed, low, high, float(resolution), bool(bisection)))
        return kernel
