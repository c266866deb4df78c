"""The arm task family: the xArm6 on its table (:data:`~gnn_mp_envs.robots.catalog.XARM6`), scenes drawn
from a family, IK goals into the structure, starts on the far side, and a straight start-goal motion
that must be blocked."""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import InvalidProblemError, Problem
from gnn_mp_envs.robots.catalog import XARM6, XARM6_HIGH, XARM6_LOW
from gnn_mp_envs.robots.checkers import Checker, PybulletChecker, checker_name, make_checker
from gnn_mp_envs.robots.geometry import EndEffectorTarget, Obstacle, Scene, tool_quaternion
from gnn_mp_envs.robots.problem import JointSpaceProblem
from gnn_mp_envs.robots.render import CAMERA, check_camera, render_robot
from gnn_mp_envs.robots.world import RobotWorld
from gnn_mp_envs.tasks.arm.scenes import SCENE_FAMILIES, sample_scene, start_target
from gnn_mp_envs.tasks.base import Task, check_keys

#: RRT/BiRRT extension length in joint space (rad, L2 over the six joints).
STEP_SIZE = 0.4
#: Collision-checking resolution along edges (rad, joint-space L2). With the robot's padding it keeps
#: returned paths valid at the benchmark's 10x finer re-check (docs/arm.md).
RESOLUTION = 0.01
#: Typical reaching postures (joint 1 relative to the target's azimuth, joint 6 free):
#: tool down / tool horizontal, wrist unflipped / flipped. Half the IK seeds start near one.
POSTURES = np.array([[0.0, 0.8, -1.45, np.pi, -0.65, 0.0],
                     [0.0, 0.5, -0.85, 0.0, 0.35, 0.0],
                     [0.0, 0.4, -0.75, np.pi, 1.2, 0.0],
                     [0.0, 0.9, -0.95, 0.0, -1.55, 0.0]])
#: IK seeds tried per target.
IK_TRIES = 20
#: Scene and start/goal draws before a problem generator gives up.
MAX_SCENE_TRIES = 50
START_TRIES = 10
#: The two training families; ``scene="train"`` draws one of them per problem.
TRAIN_FAMILIES = ("train-a", "train-b")


def xarm6_ik(world: RobotWorld, target: EndEffectorTarget, rng: np.random.Generator, tries: int = IK_TRIES,
             pos_tol: float = 0.01, axis_tol: float = 0.15) -> np.ndarray | None:
    """A configuration of the xArm6 reaching ``target`` and free for pybullet's check (with the robot's
    padding), from random IK seeds around its reaching postures (its continuous joints wrapped); or None."""
    p, cid = world.p, world.client
    lo, hi = XARM6_LOW.tolist(), XARM6_HIGH.tolist()
    ranges = (XARM6_HIGH - XARM6_LOW).tolist()
    pos = np.asarray(target.position)
    axis = np.asarray(target.axis) / np.linalg.norm(target.axis)
    azimuth = float(np.arctan2(pos[1], pos[0]))
    for k in range(tries):
        if k % 2 == 0:
            seed = POSTURES[int(rng.integers(len(POSTURES)))] + rng.normal(0.0, 0.25, 6)
            seed[0] += azimuth
            seed[5] = rng.uniform(-np.pi, np.pi)
            seed = np.clip(seed, XARM6_LOW, XARM6_HIGH)
        else:
            seed = rng.uniform(XARM6_LOW, XARM6_HIGH)
        orn = tool_quaternion(target.axis, float(rng.uniform(*target.roll)))
        world.set_config(seed)
        q = np.array(p.calculateInverseKinematics(
            world.robot, XARM6.ee_link, pos.tolist(), orn.tolist(), lowerLimits=lo, upperLimits=hi,
            jointRanges=ranges, restPoses=seed.tolist(), maxNumIterations=200,
            residualThreshold=1e-5, physicsClientId=cid))
        for j in (0, 3, 5):  # wrap the continuous joints into their one-turn range
            q[j] = (q[j] - XARM6_LOW[j]) % (2 * np.pi) + XARM6_LOW[j]
        if np.any(q < XARM6_LOW) or np.any(q > XARM6_HIGH):
            continue
        x, z = world.flange(q)
        if np.linalg.norm(x - pos) > pos_tol or float(z @ axis) < np.cos(axis_tol):
            continue
        if not world.collides(q):
            return q
    return None


class ArmProblem(JointSpaceProblem):
    """A problem of the arm task (the xArm6 in one tabletop scene)."""

    task = "arm"

    def __init__(self, world: RobotWorld, scene: Scene | tuple[Obstacle, ...], start: np.ndarray, goal: np.ndarray,
                 checker: Checker, step_size: float = STEP_SIZE, resolution: float = RESOLUTION) -> None:
        super().__init__(world, scene, start, goal, step_size, checker, resolution)


class ArmTask(Task):
    """xArm6 tabletop problems of one scene family (``train-a``, ``train-b``, ``train`` =
    either training family per problem, or the held-out ``test`` family), planned with ``checker`` (a name
    of :data:`~gnn_mp_envs.robots.checkers.CHECKERS`; None: the default, the sphere model) and drawn with
    pybullet's checks whichever it is; ``camera``: the images' (eye, target, up)."""

    name = "arm"
    #: ``[is_box, is_cylinder, size (3; a cylinder's radius, height, 0), position (3), cos yaw, sin yaw]``.
    obstacle_width = 10
    max_obstacles = 12
    planners = ("birrt", "rrt")

    def __init__(self, scene: str = "train-a", step_size: float = STEP_SIZE,
                 resolution: float = RESOLUTION, require_blocked: bool = True,
                 render_size: tuple[int, int] = (480, 360), checker: str | None = None,
                 camera: tuple | None = None) -> None:
        if scene != "train" and scene not in SCENE_FAMILIES:
            raise ValueError(f"unknown arm scene {scene!r}; known: {sorted(SCENE_FAMILIES) + ['train']}")
        self.scene = scene
        self.step_size = float(step_size)
        self.resolution = float(resolution)
        self.require_blocked = bool(require_blocked)
        self.render_size = (int(render_size[0]), int(render_size[1]))
        #: The images' camera (eye, target, up; None: :data:`~gnn_mp_envs.robots.render.CAMERA`).
        self.camera = CAMERA if camera is None else check_camera(camera)
        checker = checker_name(checker)           # refused before the simulator starts
        self.world = RobotWorld(XARM6)
        #: The planner's collision checker (:mod:`gnn_mp_envs.robots.checkers`).
        self.checker = make_checker(checker, self.world)
        # problems are drawn with pybullet's check whatever the planner's, so every checker plans the same ones
        self._drawing_checker = (self.checker if isinstance(self.checker, PybulletChecker)
                                 else PybulletChecker(self.world))
        #: Problems accepted although their straight start-goal segment was free.
        self.unblocked_problems = 0

    @property
    def client(self) -> int:
        """The pybullet client id of this task."""
        return self.world.client

    def state_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return XARM6_LOW.copy(), XARM6_HIGH.copy()

    def sample_problem(self, rng: np.random.Generator) -> ArmProblem:
        """Scene, goal (IK into the structure) and start (far side), with the straight
        start-goal segment blocked; redraws whatever fails."""
        world = self.world
        fallback = None
        for _ in range(MAX_SCENE_TRIES):
            family = self.scene if self.scene != "train" else TRAIN_FAMILIES[int(rng.integers(2))]
            scene = sample_scene(family, rng)
            world.load(scene)
            goal = xarm6_ik(world, scene.goal, rng)
            if goal is None:
                continue
            for _ in range(START_TRIES):
                start = xarm6_ik(world, start_target(scene, rng), rng, tries=5)
                if start is None:
                    continue
                drawn = ArmProblem(world, scene, start, goal, self._drawing_checker, self.step_size, self.resolution)
                if not drawn.straight_line_free():
                    return self._with_checker(drawn)
                fallback = fallback or drawn
        if fallback is None:
            raise RuntimeError(f"could not generate an arm problem in scene {self.scene!r}")
        self.unblocked_problems += 1
        return self._with_checker(fallback)

    def _with_checker(self, drawn: ArmProblem) -> ArmProblem:
        """``drawn`` planned with the task's checker."""
        if drawn.checker is self.checker:
            return drawn
        return ArmProblem(self.world, drawn.scene, drawn.start, drawn.goal, self.checker, self.step_size,
                          self.resolution)

    def make_problem(self, spec: Any) -> Problem:
        """A Problem, or a dict ``{"start", "goal"[, "obstacles"]}`` where obstacles are
        :class:`Obstacle` or dicts ``{"kind", "size", "position"[, "yaw"]}`` (default: table only)."""
        if isinstance(spec, dict):
            check_keys(spec, ("start", "goal", "obstacles"), "an arm problem dict")
            for o in spec.get("obstacles", ()):
                if isinstance(o, dict):
                    check_keys(o, ("kind", "size", "position", "yaw"), "an arm obstacle dict")
            try:
                obstacles = tuple(o if isinstance(o, Obstacle) else
                                  Obstacle(str(o["kind"]), o["size"], o["position"], o.get("yaw", 0.0))
                                  for o in spec.get("obstacles", ()))
                spec = ArmProblem(self.world, obstacles, spec["start"], spec["goal"], self.checker, self.step_size,
                                  self.resolution)
            except KeyError as e:
                raise InvalidProblemError(f"an arm problem dict needs 'start' and 'goal' and obstacles with "
                                          f"'kind', 'size', 'position' (missing {e})") from None
        elif isinstance(spec, ArmProblem) and spec.world is not self.world:
            raise InvalidProblemError("the arm problem belongs to another ArmTask (pybullet client)")
        return super().make_problem(spec)

    def obstacle_rows(self, problem: Problem) -> np.ndarray:
        rows = [[ob.kind == "box", ob.kind == "cylinder", *ob.size, *([0.0] * (3 - len(ob.size))),
                 *ob.position, np.cos(ob.yaw), np.sin(ob.yaw)] for ob in problem.obstacles]
        if len(rows) > self.max_obstacles:
            raise InvalidProblemError(f"an arm problem has at most {self.max_obstacles} obstacles, got {len(rows)}")
        return np.asarray(rows, dtype=np.float64).reshape(-1, self.obstacle_width)

    def render_rgb(self, problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
        """TinyRenderer image: the arm at the start (and, faded, at the goal), the scene, the
        flange positions of (up to 2000) tree nodes and, on success, the flange trace of the path."""
        if not isinstance(problem, ArmProblem):
            raise TypeError(f"expected an ArmProblem, got {type(problem).__name__}")
        return render_robot(self.world, problem, tree, path, *self.render_size, camera=self.camera)

    def close(self) -> None:
        self.world.close()
