"""The robot simulator: one pybullet ``DIRECT`` client with a robot (a
:class:`~gnn_mp_envs.robots.model.RobotModel`: the xArm6, the Panda, the UR5, the Fetch), the box it
stands on if any, and a pool of obstacle bodies; and the exact collision check (the pybullet
checker's, and the re-check of every returned path).

Validity of a configuration: within the joint limits, no contact between a robot link
and the table or an obstacle, and no self-collision. Self-collision is loaded with
``URDF_USE_SELF_COLLISION``, under which Bullet skips parent-child (adjacent) link pairs;
every other link pair is checked, except the pairs a robot model names in
``allowed_collisions`` (MoveIt's allowed-collision matrix). One check sets the joints
(``resetJointStatesMultiDof``), runs ``performCollisionDetection`` and scans
``getContactPoints`` of the robot for a point at distance <= 0; this measured ~25 us,
faster than per-pair ``getClosestPoints`` queries (~35 us for two bodies alone, plus
~8 us per self-collision link pair).
"""

from __future__ import annotations

import numpy as np

from gnn_mp_envs.robots.geometry import Obstacle, Scene
from gnn_mp_envs.robots.model import RobotModel

#: A contact at or below this signed distance (m) is a collision.
CONTACT_DISTANCE = 0.0

#: Unused obstacle bodies wait below the table, their top at least this far down (m).
PARK_DEPTH = 50.0


def park_position(size: tuple[float, ...]) -> tuple[float, float, float]:
    """Where an unused body of ``size`` (half extents, or radius and height) waits: its top at
    least :data:`PARK_DEPTH` below the table whatever its size (a 200 m tower parked at a fixed
    depth still reached the robot)."""
    return (0.0, 0.0, -PARK_DEPTH - 2.0 * max(float(v) for v in size))

_POOL_LIMIT = 64
#: pybullet never frees collision or visual shapes (there is no removeVisualShape, and
#: removeCollisionShape refuses shapes a removed body used), and scene obstacles have random
#: sizes, so shapes are rarely reused. After this many obstacle bodies the client is rebuilt
#: (disconnect + connect, ~30 ms), which frees them all: memory stays flat over any number of
#: problems (measured: RSS constant within 1 MB over 1,200 resets; 35 MB growth without).
REBUILD_AFTER_BODIES = 200
_COLORS = {"box": (0.55, 0.45, 0.35, 1.0), "cylinder": (0.35, 0.45, 0.6, 1.0),
           "table": (0.82, 0.78, 0.7, 1.0)}


def import_pybullet():
    """``import pybullet`` without the "pybullet build time: ..." line its C module prints at
    import, straight to a file descriptor (so ``sys.stdout`` / ``sys.stderr`` redirection cannot
    catch it; this build writes it to stderr, others to stdout): it would land in the middle of
    tables and JSON piped from the CLI, or under its one-line errors. Both descriptors point to
    /dev/null for the import; an import error is raised (and printed) after they are restored."""
    import sys
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    import os
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    try:
        with open(os.devnull, "w") as devnull:
            for fd in saved:
                os.dup2(devnull.fileno(), fd)
            import pybullet
    finally:
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
    return pybullet


class RobotWorld:
    """One pybullet client with the robot, the box it stands on (if any) and a pool of obstacle bodies."""

    def __init__(self, robot: RobotModel) -> None:
        p = import_pybullet()
        self.p = p
        self.robot_model = robot
        self.low = np.array(robot.low, dtype=np.float64)
        self.high = np.array(robot.high, dtype=np.float64)
        self._joints = list(robot.joints)
        #: The planner's collision threshold: contacts at or below this signed distance (m).
        self.contact_distance = CONTACT_DISTANCE + float(robot.padding)
        self._reset = p.resetJointStatesMultiDof
        self._detect = p.performCollisionDetection
        self._contacts = p.getContactPoints
        self._closest = p.getClosestPoints
        self.bodies_created = 0
        self.rebuilds = 0
        self._connect()

    def _connect(self) -> None:
        """A fresh client with the robot and the table (no obstacles)."""
        import pybullet_data
        p, model = self.p, self.robot_model
        self.client = p.connect(p.DIRECT)
        cid = self.client
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        # Self-collision ON; Bullet then skips parent-child pairs (adjacent links).
        # (URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS would switch off every pair of a chain.)
        self.robot = p.loadURDF(model.urdf, [0, 0, 0], useFixedBase=True,
                                flags=p.URDF_USE_SELF_COLLISION, physicsClientId=cid)
        for joint, value in model.held_joints:   # e.g. the Panda's fingers, beyond the URDF's own limit
            p.resetJointState(self.robot, joint, value, physicsClientId=cid)
        if model.allowed_collisions:
            links = {p.getBodyInfo(self.robot, physicsClientId=cid)[0].decode(): -1}
            links.update({p.getJointInfo(self.robot, j, physicsClientId=cid)[12].decode(): j
                          for j in range(p.getNumJoints(self.robot, physicsClientId=cid))})
            for a, b in model.allowed_collisions:
                p.setCollisionFilterPair(self.robot, self.robot, links[a], links[b], 0, physicsClientId=cid)
        self.table = None
        if model.table is not None:
            half = list(model.table.size)
            self.table = p.createMultiBody(
                0, p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid),
                p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=_COLORS["table"], physicsClientId=cid),
                basePosition=list(model.table.position), physicsClientId=cid)
            # The base link stands on the table: that contact is not a collision.
            for link in model.base_links:
                p.setCollisionFilterPair(self.robot, self.table, link, -1, 0, physicsClientId=cid)
        self._active: list[tuple[tuple, int]] = []
        self._pool: dict[tuple, list[int]] = {}
        self._pooled = 0
        self._bodies_in_client = 0
        self.scene: Scene | tuple | None = None
        self._connected = True

    def _rebuild(self) -> None:
        """Drop every shape pybullet holds by starting a new client (see REBUILD_AFTER_BODIES)."""
        self.p.disconnect(self.client)
        self._connect()
        self.rebuilds += 1

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict:
        """A world pickles as its current scene; unpickling starts a new client and loads it."""
        return {"scene": self.scene, "connected": self._connected, "robot": self.robot_model}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["robot"])
        if state["scene"] is not None:
            self.load(state["scene"])
        if not state["connected"]:
            self.close()

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
        elif ob.kind == "sphere":
            col = p.createCollisionShape(p.GEOM_SPHERE, radius=ob.size[0], physicsClientId=cid)
            vis = p.createVisualShape(p.GEOM_SPHERE, radius=ob.size[0], rgbaColor=color, physicsClientId=cid)
        else:
            raise ValueError(f"unknown obstacle kind {ob.kind!r} (box, cylinder or sphere)")
        self.bodies_created += 1
        self._bodies_in_client += 1
        return p.createMultiBody(0, col, vis, basePosition=list(park_position(ob.size)), physicsClientId=cid)

    def load(self, scene: Scene | tuple[Obstacle, ...]) -> None:
        """Make ``scene`` (a Scene or a tuple of obstacles) the current one.

        A no-op when it already is, so problems can call it before every check. Bodies of
        the previous scene are parked far below the table and reused by shape.
        """
        if scene is self.scene:
            return
        self._require()
        if self._bodies_in_client >= REBUILD_AFTER_BODIES:
            self._rebuild()
        p, cid = self.p, self.client
        for key, body in self._active:
            p.resetBasePositionAndOrientation(body, park_position(key[1:]), (0, 0, 0, 1), physicsClientId=cid)
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
                if not free:
                    del self._pool[key]
            else:
                body = self._new_body(ob)
            p.resetBasePositionAndOrientation(body, list(ob.position), ob.quaternion(), physicsClientId=cid)
            self._active.append((key, body))
        # Keep the pool bounded: drop parked bodies beyond the limit.
        while self._pooled > _POOL_LIMIT:
            key = next(iter(self._pool))
            p.removeBody(self._pool[key].pop(), physicsClientId=cid)
            if not self._pool[key]:
                del self._pool[key]
            self._pooled -= 1
        self.scene = scene

    @property
    def obstacle_bodies(self) -> list[int]:
        return [b for _, b in self._active]

    # ------------------------------------------------------------------ robot
    def set_config(self, q: np.ndarray) -> None:
        self.p.resetJointStatesMultiDof(self.robot, self._joints, [[v] for v in np.asarray(q).tolist()],
                                        physicsClientId=self.client)

    def collides(self, q: np.ndarray | list[float], distance: float | None = None) -> bool:
        """True when configuration ``q`` (the planned joints' angles) touches the table, an
        obstacle or itself: a contact at or below ``distance`` (default: the robot's padding
        above :data:`CONTACT_DISTANCE`). The hot path of the task: one call per collision check.

        A function of the configuration alone: Bullet keeps contact points from earlier queries
        (refreshed, not recomputed) next to the one it computes fresh, so a contact the scan finds
        is confirmed by a query that keeps no state (``getClosestPoints`` of that link pair) before
        it counts. A free configuration costs one detection; only reported contacts pay more."""
        cid, robot = self.client, self.robot
        limit = self.contact_distance if distance is None else distance
        self._reset(robot, self._joints, [[v] for v in q], physicsClientId=cid)
        self._detect(physicsClientId=cid)
        seen = set()
        for cp in self._contacts(bodyA=robot, physicsClientId=cid):
            if cp[8] <= limit:
                key = (cp[2], cp[3], cp[4])
                if key in seen:
                    continue
                seen.add(key)
                for fresh in self._closest(robot, cp[2], limit, linkIndexA=cp[3], linkIndexB=cp[4],
                                           physicsClientId=cid):
                    if fresh[8] <= limit:
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
        s = self.p.getLinkState(self.robot, self.robot_model.ee_link, computeForwardKinematics=True,
                                physicsClientId=self.client)
        rot = np.array(self.p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
        return np.array(s[4]), rot[:, 2]

    def flange_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flange position and orientation (quaternion x, y, z, w) at ``q``."""
        self.set_config(q)
        s = self.p.getLinkState(self.robot, self.robot_model.ee_link, computeForwardKinematics=True,
                                physicsClientId=self.client)
        return np.array(s[4]), np.array(s[5])

    def pose_ik(self, position: np.ndarray, orientation: np.ndarray, seed: np.ndarray, pos_tol: float = 1e-3,
                angle_tol: float = 1e-2, rounds: int = 4, iterations: int = 100) -> np.ndarray | None:
        """Planned joints putting the flange at ``position`` with ``orientation`` (quaternion x, y, z, w),
        by pybullet's IK started at ``seed`` (pulled toward it, restarted from its own answer up to
        ``rounds`` times); None when the answer leaves the joint limits or misses the pose by more
        than ``pos_tol`` (m) / ``angle_tol`` (rad). Collisions are not checked; held joints stay."""
        p, cid, model = self.p, self.client, self.robot_model
        movable = [j for j in range(p.getNumJoints(self.robot, physicsClientId=cid))
                   if p.getJointInfo(self.robot, j, physicsClientId=cid)[2] != p.JOINT_FIXED]
        held = dict(model.held_joints)
        planned = {j: k for k, j in enumerate(model.joints)}
        lo = [self.low[planned[j]] if j in planned else held.get(j, 0.0) for j in movable]
        hi = [self.high[planned[j]] if j in planned else held.get(j, 0.0) for j in movable]
        target = np.asarray(orientation, dtype=np.float64) / np.linalg.norm(orientation)
        q = np.asarray(seed, dtype=np.float64)
        for _ in range(rounds):
            rest = [q[planned[j]] if j in planned else held.get(j, 0.0) for j in movable]
            self.set_config(q)
            solution = p.calculateInverseKinematics(
                self.robot, model.ee_link, list(map(float, position)), list(map(float, orientation)),
                lowerLimits=lo, upperLimits=hi, jointRanges=[max(h - l, 1e-6) for l, h in zip(lo, hi)],
                restPoses=rest, maxNumIterations=iterations, residualThreshold=1e-7, physicsClientId=cid)
            q = np.array([solution[movable.index(j)] for j in model.joints])
            x, quat = self.flange_pose(q)
            angle = 2.0 * np.arccos(min(1.0, abs(float(np.dot(quat, target)))))
            if np.linalg.norm(x - np.asarray(position)) <= pos_tol and angle <= angle_tol:
                return None if np.any(q < self.low) or np.any(q > self.high) else q
        return None

    def flange_positions(self, qs: np.ndarray) -> np.ndarray:
        """Flange positions (N, 3) of configurations ``qs`` (N, dof)."""
        return np.array([self.flange(q)[0] for q in np.asarray(qs).reshape(-1, len(self._joints))]).reshape(-1, 3)

    # ------------------------------------------------------------------ lifecycle
    def _require(self) -> None:
        if not self._connected:
            raise RuntimeError("the robot's pybullet client is closed")

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
