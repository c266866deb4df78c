"""Arm: a 6-DoF xArm6 on a table, planned in joint space with BiRRT (or RRT).

Each :class:`ArmTask` owns one pybullet client in ``DIRECT`` mode (created in the
constructor, disconnected by :meth:`ArmTask.close`) holding the robot
(``xarm/xarm6_robot.urdf`` from ``pybullet_data``, fixed base at the origin on the
table top), the table and the obstacle bodies of the current scene.

Validity of a configuration: within the joint limits, no contact between a robot link
and the table or an obstacle, and no self-collision. Self-collision is loaded with
``URDF_USE_SELF_COLLISION``, under which Bullet skips parent-child (adjacent) link pairs;
every other link pair is checked. One check sets the six joints
(``resetJointStatesMultiDof``), runs ``performCollisionDetection`` and scans
``getContactPoints`` of the robot for a point at distance <= 0; this measured ~25 us,
faster than per-pair ``getClosestPoints`` queries (~35 us for two bodies alone, plus
~8 us per self-collision link pair). Each configuration checked counts one collision check;
edges are interpolated every :data:`RESOLUTION` rad (joint-space L2) and stop at the
first invalid configuration.

Problems come from the scene families of :mod:`gnn_mp_envs.tasks.arm_scenes`; goals are
inverse-kinematics solutions that put the tool inside the crevice / shelf / cubby, starts
are tool-down poses on the far side of the robot, and a problem whose straight joint-space
segment from start to goal is collision-free is rejected and redrawn.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import Edge, InvalidProblemError, Problem
from gnn_mp_envs.tasks.arm_scenes import (SCENE_FAMILIES, TABLE_EXTENT, TABLE_THICKNESS,
                                          EndEffectorTarget, Obstacle, Scene, sample_scene,
                                          start_target)
from gnn_mp_envs.tasks.base import Task

URDF = "xarm/xarm6_robot.urdf"
#: pybullet joint indices of the six revolute joints (index 0 is the fixed world joint).
JOINTS = (1, 2, 3, 4, 5, 6)
#: The link whose frame is the tool flange.
EE_LINK = 6
#: Planning limits: the URDF limits, with the +-2 pi joints 1, 4 and 6 cut to one turn
#: (every orientation once; the configuration space stays a box). Joint 4 spans
#: [-pi/2, 3 pi/2] so that both wrist postures (joint 4 near 0 and near pi, which IK
#: returns about equally often) lie inside the box rather than on its boundary.
JOINT_LOW = np.array([-np.pi, -2.059, -3.927, -0.5 * np.pi, -1.69297, -np.pi])
JOINT_HIGH = np.array([np.pi, 2.0944, 0.19198, 1.5 * np.pi, np.pi, np.pi])
#: Typical reaching postures (joint 1 relative to the target's azimuth, joint 6 free):
#: tool down / tool horizontal, wrist unflipped / flipped. Half the IK seeds start near one.
POSTURES = np.array([[0.0, 0.8, -1.45, np.pi, -0.65, 0.0],
                     [0.0, 0.5, -0.85, 0.0, 0.35, 0.0],
                     [0.0, 0.4, -0.75, np.pi, 1.2, 0.0],
                     [0.0, 0.9, -0.95, 0.0, -1.55, 0.0]])
#: RRT/BiRRT extension length in joint space (rad, L2 over the six joints).
STEP_SIZE = 0.4
#: Collision-checking resolution along edges (rad, L2); 0.05 rad moves the flange <= ~4 cm.
RESOLUTION = 0.05
#: A contact at or below this signed distance (m) is a collision.
CONTACT_DISTANCE = 0.0
#: Scene and start/goal draws before a problem generator gives up.
MAX_SCENE_TRIES = 50
START_TRIES = 10
IK_TRIES = 20
#: The two training families; ``scene="train"`` draws one of them per problem.
TRAIN_FAMILIES = ("train-a", "train-b")

_PARK = (0.0, 0.0, -50.0)
_POOL_LIMIT = 64
_COLORS = {"box": (0.55, 0.45, 0.35, 1.0), "cylinder": (0.35, 0.45, 0.6, 1.0),
           "table": (0.82, 0.78, 0.7, 1.0)}


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (x, y, z, w) quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    return np.append(np.sin(angle / 2) * axis, np.cos(angle / 2))


def tool_quaternion(axis: tuple[float, float, float], roll: float) -> np.ndarray:
    """Flange orientation whose z axis (the tool axis) is ``axis``, rolled by ``roll``."""
    z = np.array([0.0, 0.0, 1.0])
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    cross = np.cross(z, a)
    if np.linalg.norm(cross) < 1e-9:
        align = np.array([0.0, 0.0, 0.0, 1.0]) if a[2] > 0 else _axis_angle([1.0, 0.0, 0.0], np.pi)
    else:
        align = _axis_angle(cross, float(np.arccos(np.clip(z @ a, -1.0, 1.0))))
    return _quat_mul(align, _axis_angle(z, roll))


class ArmWorld:
    """One pybullet client with the robot, the table and a pool of obstacle bodies."""

    def __init__(self) -> None:
        import pybullet as p
        import pybullet_data

        self.p = p
        self.client = p.connect(p.DIRECT)
        cid = self.client
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        # Self-collision ON; Bullet then skips parent-child pairs (adjacent links).
        # (URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS would switch off every pair of a chain.)
        self.robot = p.loadURDF(URDF, [0, 0, 0], useFixedBase=True,
                                flags=p.URDF_USE_SELF_COLLISION, physicsClientId=cid)
        x0, y0, x1, y1 = TABLE_EXTENT
        half = [(x1 - x0) / 2, (y1 - y0) / 2, TABLE_THICKNESS / 2]
        self.table = p.createMultiBody(
            0, p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid),
            p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=_COLORS["table"], physicsClientId=cid),
            basePosition=[(x0 + x1) / 2, (y0 + y1) / 2, -TABLE_THICKNESS / 2], physicsClientId=cid)
        # The base link stands on the table: that contact is not a collision.
        for link in (-1, 0):
            p.setCollisionFilterPair(self.robot, self.table, link, -1, 0, physicsClientId=cid)
        self._joints = list(JOINTS)
        self._reset = p.resetJointStatesMultiDof
        self._detect = p.performCollisionDetection
        self._contacts = p.getContactPoints
        self._active: list[tuple[tuple, int]] = []
        self._pool: dict[tuple, list[int]] = {}
        self._pooled = 0
        self.scene: Scene | tuple | None = None
        self.bodies_created = 0
        self._connected = True

    # ------------------------------------------------------------------ scene
    def _new_body(self, ob: Obstacle) -> int:
        p, cid = self.p, self.client
        color = _COLORS.get(ob.kind, _COLORS["box"])
        if ob.kind == "box":
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(ob.size), physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=list(ob.size), rgbaColor=color, physicsClientId=cid)
        elif ob.kind == "cylinder":
            col = p.createCollisionShape(p.GEOM_CYLINDER, radius=ob.size[0], height=ob.size[1], physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=ob.size[0], length=ob.size[1], rgbaColor=color,
                                      physicsClientId=cid)
        else:
            raise ValueError(f"unknown obstacle kind {ob.kind!r} (box or cylinder)")
        self.bodies_created += 1
        return p.createMultiBody(0, col, vis, basePosition=list(_PARK), physicsClientId=cid)

    def load(self, scene: Scene | tuple[Obstacle, ...]) -> None:
        """Make ``scene`` (a Scene or a tuple of obstacles) the current one.

        A no-op when it already is, so problems can call it before every check. Bodies of
        the previous scene are parked far below the table and reused by shape.
        """
        if scene is self.scene:
            return
        self._require()
        p, cid = self.p, self.client
        for key, body in self._active:
            p.resetBasePositionAndOrientation(body, _PARK, (0, 0, 0, 1), physicsClientId=cid)
            self._pool.setdefault(key, []).append(body)
            self._pooled += 1
        self._active = []
        obstacles = scene.obstacles if isinstance(scene, Scene) else tuple(scene)
        for ob in obstacles:
            key = ob.key()
            free = self._pool.get(key)
            if free:
                body = free.pop()
                self._pooled -= 1
            else:
                body = self._new_body(ob)
            orn = (0.0, 0.0, float(np.sin(ob.yaw / 2)), float(np.cos(ob.yaw / 2)))
            p.resetBasePositionAndOrientation(body, list(ob.position), orn, physicsClientId=cid)
            self._active.append((key, body))
        # Keep the pool bounded: drop parked bodies beyond the limit.
        while self._pooled > _POOL_LIMIT:
            key = next(k for k, v in self._pool.items() if v)
            p.removeBody(self._pool[key].pop(), physicsClientId=cid)
            self._pooled -= 1
        self.scene = scene

    @property
    def obstacle_bodies(self) -> list[int]:
        return [b for _, b in self._active]

    # ------------------------------------------------------------------ robot
    def set_config(self, q: np.ndarray) -> None:
        self.p.resetJointStatesMultiDof(self.robot, self._joints, [[v] for v in np.asarray(q).tolist()],
                                        physicsClientId=self.client)

    def collides(self, q: np.ndarray | list[float]) -> bool:
        """True when configuration ``q`` (six joint angles) touches the table, an obstacle
        or itself. The hot path of the task: one call per collision check."""
        cid, robot = self.client, self.robot
        self._reset(robot, self._joints, [[v] for v in q], physicsClientId=cid)
        self._detect(physicsClientId=cid)
        for cp in self._contacts(bodyA=robot, physicsClientId=cid):
            if cp[8] <= CONTACT_DISTANCE:
                return True
        return False

    def contacts(self, q: np.ndarray) -> list[tuple[int, int, int, int, float]]:
        """(bodyA, bodyB, linkA, linkB, distance) of every penetrating contact at ``q``."""
        self.set_config(q)
        self.p.performCollisionDetection(physicsClientId=self.client)
        return [(cp[1], cp[2], cp[3], cp[4], cp[8])
                for cp in self.p.getContactPoints(bodyA=self.robot, physicsClientId=self.client)
                if cp[8] <= CONTACT_DISTANCE]

    def flange(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flange position and tool axis (unit z of the flange frame) at ``q``."""
        self.set_config(q)
        s = self.p.getLinkState(self.robot, EE_LINK, computeForwardKinematics=True, physicsClientId=self.client)
        rot = np.array(self.p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
        return np.array(s[4]), rot[:, 2]

    def flange_positions(self, qs: np.ndarray) -> np.ndarray:
        """Flange positions (N, 3) of configurations ``qs`` (N, 6)."""
        return np.array([self.flange(q)[0] for q in np.asarray(qs).reshape(-1, 6)]).reshape(-1, 3)

    def ik(self, target: EndEffectorTarget, rng: np.random.Generator, tries: int = IK_TRIES,
           pos_tol: float = 0.01, axis_tol: float = 0.15) -> np.ndarray | None:
        """A collision-free configuration reaching ``target``, from random IK seeds; or None."""
        p, cid = self.p, self.client
        lo, hi = JOINT_LOW.tolist(), JOINT_HIGH.tolist()
        ranges = (JOINT_HIGH - JOINT_LOW).tolist()
        pos = np.asarray(target.position)
        axis = np.asarray(target.axis) / np.linalg.norm(target.axis)
        azimuth = float(np.arctan2(pos[1], pos[0]))
        for k in range(tries):
            if k % 2 == 0:
                seed = POSTURES[int(rng.integers(len(POSTURES)))] + rng.normal(0.0, 0.25, 6)
                seed[0] += azimuth
                seed[5] = rng.uniform(-np.pi, np.pi)
                seed = np.clip(seed, JOINT_LOW, JOINT_HIGH)
            else:
                seed = rng.uniform(JOINT_LOW, JOINT_HIGH)
            orn = tool_quaternion(target.axis, float(rng.uniform(*target.roll)))
            self.set_config(seed)
            q = np.array(p.calculateInverseKinematics(
                self.robot, EE_LINK, pos.tolist(), orn.tolist(), lowerLimits=lo, upperLimits=hi,
                jointRanges=ranges, restPoses=seed.tolist(), maxNumIterations=200,
                residualThreshold=1e-5, physicsClientId=cid))
            for j in (0, 3, 5):  # wrap the continuous joints into their one-turn range
                q[j] = (q[j] - JOINT_LOW[j]) % (2 * np.pi) + JOINT_LOW[j]
            if np.any(q < JOINT_LOW) or np.any(q > JOINT_HIGH):
                continue
            x, z = self.flange(q)
            if np.linalg.norm(x - pos) > pos_tol or float(z @ axis) < np.cos(axis_tol):
                continue
            if not self.collides(q):
                return q
        return None

    # ------------------------------------------------------------------ lifecycle
    def _require(self) -> None:
        if not self._connected:
            raise RuntimeError("the arm task's pybullet client is closed")

    @property
    def connected(self) -> bool:
        return self._connected and bool(self.p.isConnected(self.client))

    def close(self) -> None:
        if self._connected:
            self._connected = False
            try:
                self.p.disconnect(self.client)
            except Exception:  # pragma: no cover - already gone (e.g. interpreter teardown)
                pass


class ArmProblem(Problem):
    """Joint-space planning for the xArm6 in one scene of an :class:`ArmWorld`."""

    task = "arm"
    geometric = True

    def __init__(self, world: ArmWorld, scene: Scene | tuple[Obstacle, ...], start: np.ndarray,
                 goal: np.ndarray, step_size: float = STEP_SIZE, resolution: float = RESOLUTION) -> None:
        super().__init__(start, goal, low=JOINT_LOW, high=JOINT_HIGH, step_size=step_size,
                         resolution=resolution)
        self.world = world
        self.scene = scene
        # NaN fails both comparisons, so these bounds tests also reject non-finite states.
        self._low = self.low - 1e-12
        self._high = self.high + 1e-12
        self._low_tol = self._low.tolist()
        self._high_tol = self._high.tolist()

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        return self.scene.obstacles if isinstance(self.scene, Scene) else tuple(self.scene)

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        s = np.asarray(states, dtype=np.float64).reshape(-1, self.state_dim)
        ok = self._in_bounds(s)
        self.world.load(self.scene)
        collides = self.world.collides
        rows = s.tolist()
        for i in np.flatnonzero(ok).tolist():
            if collides(rows[i]):
                ok[i] = False
        return ok

    def check_motion(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Sequential check at ``resolution`` (``b`` included) that stops at the first
        invalid configuration; counts exactly as :meth:`Problem.check_motion`.

        Plain Python floats: for the ~8 states of an edge this is faster than numpy, and
        ``a + (k / n) * (b - a)`` gives the same states as the base class.
        """
        self.edges_checked += 1
        al, bl = a.tolist(), b.tolist()
        dl = [y - x for x, y in zip(al, bl)]
        n = max(1, math.ceil(math.sqrt(sum(v * v for v in dl)) / self.resolution))
        lo, hi = self._low_tol, self._high_tol
        limit = n
        if not all(l <= v <= h for v, l, h in zip(bl, lo, hi)):
            # a is valid and the box convex: the states leave it once, somewhere before b.
            limit = next(k for k in range(1, n + 1)
                         if not all(l <= x + (k / n) * v <= h for x, v, l, h in zip(al, dl, lo, hi))) - 1
        self.world.load(self.scene)
        collides = self.world.collides
        for k in range(1, n + 1):
            self.collision_checks += 1
            t = k / n
            if k > limit or collides([x + t * v for x, v in zip(al, dl)]):
                return False
        return True

    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray:
        d = states - x  # plain joint-space L2 (no angle wrapping: the box is one turn per joint)
        return np.sqrt(np.einsum("...i,...i->...", d, d))

    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """:meth:`Problem.steer` without the generic vectorised helpers (same result)."""
        d = x_to - x_from
        dist = math.sqrt(float(d @ d))
        if dist < 1e-12:
            return None
        if dist <= self.step_size:
            x_new = np.array(x_to, dtype=np.float64)
        else:
            x_new = x_from + (self.step_size / dist) * d
        if not self.check_motion(x_from, x_new):
            return None
        return Edge(x_new, min(dist, self.step_size))

    def goal_connection(self, x: np.ndarray) -> Edge | None:
        d = self.goal - x
        dist = math.sqrt(float(d @ d))
        if dist > self.step_size or not self.check_motion(x, self.goal):
            return None
        return Edge(self.goal.copy(), dist)

    def _in_bounds(self, s: np.ndarray) -> np.ndarray:
        return np.all((s >= self._low) & (s <= self._high), axis=-1)

    def straight_line_free(self) -> bool:
        """Uncounted: is the straight joint-space segment start -> goal collision-free?"""
        before = (self.collision_checks, self.edges_checked)
        free = self.check_motion(self.start, self.goal)
        self.collision_checks, self.edges_checked = before
        return free


#: Camera of :func:`render_arm`: eye, target, up (behind and above the robot's right).
CAMERA = ((-0.75, -1.05, 1.15), (0.3, 0.0, 0.1), (0.0, 0.0, 1.0))
_TREE_RGB = (np.array([40, 110, 220]), np.array([240, 140, 30]))
_PATH_RGB = np.array([20, 190, 60])


def _project(points: np.ndarray, view: np.ndarray, proj: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (N, 2) (column, row) of world points (N, 3); NaN behind the camera."""
    h = np.hstack([points, np.ones((len(points), 1))]) @ (proj @ view).T
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = h[:, :3] / h[:, 3:4]
    px = np.column_stack([(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height])
    px[h[:, 3] <= 0] = np.nan
    return px


def _dots(img: np.ndarray, px: np.ndarray, color: np.ndarray, radius: int = 1) -> None:
    """Draw filled squares of side ``2 radius + 1`` at pixel positions (in place)."""
    px = px[np.isfinite(px).all(axis=1)]
    if not len(px):
        return
    c = np.rint(px).astype(int)
    for dx in range(-radius, radius + 1):
        for dy in range(-radius, radius + 1):
            x, y = c[:, 0] + dx, c[:, 1] + dy
            ok = (x >= 0) & (x < img.shape[1]) & (y >= 0) & (y < img.shape[0])
            img[y[ok], x[ok]] = color


def render_arm(world: ArmWorld, problem: ArmProblem, tree: Any, path: np.ndarray | None,
               width: int = 320, height: int = 240, max_tree_nodes: int = 2000) -> np.ndarray:
    """RGB (height, width, 3) uint8 image of an arm problem (see :meth:`ArmTask.render_rgb`).

    TinyRenderer does not draw debug lines, so tree nodes and the path are projected with
    the camera's view/projection matrices and painted onto the image with numpy.
    """
    p, cid = world.p, world.client
    world.load(problem.scene)
    eye, target, up = CAMERA
    view_l = p.computeViewMatrix(eye, target, up, physicsClientId=cid)
    proj_l = p.computeProjectionMatrixFOV(55.0, width / height, 0.05, 6.0, physicsClientId=cid)
    view = np.array(view_l).reshape(4, 4).T
    proj = np.array(proj_l).reshape(4, 4).T

    def shot(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        world.set_config(q)
        _, _, rgba, _, seg = p.getCameraImage(width, height, view_l, proj_l, renderer=p.ER_TINY_RENDERER,
                                              physicsClientId=cid)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        return rgba[..., :3].copy(), np.asarray(seg).reshape(height, width)

    img, seg_start = shot(problem.start)
    goal_img, seg_goal = shot(problem.goal)
    ghost = (seg_goal & 0xFFFFFF) == world.robot  # pixels of the robot in the goal pose
    ghost &= (seg_goal >= 0)
    img[ghost] = (0.45 * img[ghost] + 0.55 * goal_img[ghost]).astype(np.uint8)
    if tree is not None and len(tree):
        n = len(tree)
        idx = np.arange(n) if n <= max_tree_nodes else np.linspace(0, n - 1, max_tree_nodes).astype(int)
        pts = world.flange_positions(tree.states[idx])
        for t in range(getattr(tree, "num_trees", 1)):
            sel = tree.tree_id[idx] == t
            _dots(img, _project(pts[sel], view, proj, width, height), _TREE_RGB[t % 2], radius=0)
    if path is not None and len(path) > 1:
        dense = [path[0]]
        for a, b in zip(path[:-1], path[1:]):
            k = max(1, int(np.ceil(np.linalg.norm(b - a) / problem.resolution)))
            dense.extend(a + (b - a) * (np.arange(1, k + 1) / k)[:, None])
        px = _project(world.flange_positions(np.array(dense)), view, proj, width, height)
        # Join consecutive points so the trace is a continuous line.
        segs = [px[i] + (px[i + 1] - px[i]) * s for i in range(len(px) - 1) for s in np.linspace(0, 1, 6)]
        _dots(img, np.array(segs), _PATH_RGB, radius=1)
    for q, color in ((problem.start, np.array([220, 30, 30])), (problem.goal, np.array([30, 160, 30]))):
        _dots(img, _project(world.flange_positions(q), view, proj, width, height), color, radius=3)
    return img


class ArmTask(Task):
    """xArm6 tabletop problems of one scene family (``train-a``, ``train-b``, ``train`` =
    either training family per problem, or the held-out ``test`` family)."""

    name = "arm"
    planners = ("birrt", "rrt")
    default_max_nodes = 5000

    def __init__(self, scene: str = "train-a", step_size: float = STEP_SIZE,
                 resolution: float = RESOLUTION, require_blocked: bool = True,
                 render_size: tuple[int, int] = (320, 240)) -> None:
        if scene != "train" and scene not in SCENE_FAMILIES:
            raise ValueError(f"unknown arm scene {scene!r}; known: {sorted(SCENE_FAMILIES) + ['train']}")
        self.scene = scene
        self.step_size = float(step_size)
        self.resolution = float(resolution)
        self.require_blocked = bool(require_blocked)
        self.render_size = (int(render_size[0]), int(render_size[1]))
        self.world = ArmWorld()
        #: Problems accepted although their straight start-goal segment was free.
        self.unblocked_problems = 0

    @property
    def client(self) -> int:
        """The pybullet client id of this task."""
        return self.world.client

    def state_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return JOINT_LOW.copy(), JOINT_HIGH.copy()

    def sample_problem(self, rng: np.random.Generator) -> ArmProblem:
        """Scene, goal (IK into the structure) and start (far side), with the straight
        start-goal segment blocked; redraws whatever fails."""
        world = self.world
        fallback = None
        for _ in range(MAX_SCENE_TRIES):
            family = self.scene if self.scene != "train" else TRAIN_FAMILIES[int(rng.integers(2))]
            scene = sample_scene(family, rng)
            world.load(scene)
            goal = world.ik(scene.goal, rng)
            if goal is None:
                continue
            for _ in range(START_TRIES):
                start = world.ik(start_target(scene, rng), rng, tries=5)
                if start is None:
                    continue
                problem = ArmProblem(world, scene, start, goal, self.step_size, self.resolution)
                if not problem.straight_line_free():
                    return problem
                fallback = fallback or problem
        if fallback is None:
            raise RuntimeError(f"could not generate an arm problem in scene {self.scene!r}")
        self.unblocked_problems += 1
        return fallback

    def make_problem(self, spec: Any) -> Problem:
        """A Problem, or a dict ``{"start", "goal"[, "obstacles"]}`` where obstacles are
        :class:`Obstacle` or dicts ``{"kind", "size", "position"[, "yaw"]}`` (default: table only)."""
        if isinstance(spec, dict):
            try:
                obstacles = tuple(o if isinstance(o, Obstacle) else
                                  Obstacle(str(o["kind"]), tuple(map(float, o["size"])),
                                           tuple(map(float, o["position"])), float(o.get("yaw", 0.0)))
                                  for o in spec.get("obstacles", ()))
                spec = ArmProblem(self.world, obstacles, spec["start"], spec["goal"], self.step_size,
                                  self.resolution)
            except KeyError as e:
                raise InvalidProblemError(f"an arm problem dict needs 'start' and 'goal' and obstacles with "
                                          f"'kind', 'size', 'position' (missing {e})") from None
        elif isinstance(spec, ArmProblem) and spec.world is not self.world:
            raise InvalidProblemError("the arm problem belongs to another ArmTask (pybullet client)")
        return super().make_problem(spec)

    def render_rgb(self, problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
        """TinyRenderer image: the arm at the start (and, faded, at the goal), the scene, the
        flange positions of (up to 2000) tree nodes and, on success, the flange trace of the path."""
        if not isinstance(problem, ArmProblem):
            raise TypeError(f"expected an ArmProblem, got {type(problem).__name__}")
        return render_arm(self.world, problem, tree, path, *self.render_size)

    def close(self) -> None:
        self.world.close()

    def __del__(self) -> None:
        try:
            self.world.close()
        except Exception:  # pragma: no cover - interpreter teardown
            pass
