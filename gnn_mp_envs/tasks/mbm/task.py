"""The MotionBenchMaker tasks: MBM's own problems of a robot (the Panda, the UR5, the Fetch) by
scene and split, plus perturbed copies of the training problems for learned samplers."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import InvalidProblemError, Problem
from gnn_mp_envs.robots.catalog import robot_model
from gnn_mp_envs.robots.checkers import Checker, checker_name, make_checker
from gnn_mp_envs.robots.geometry import Obstacle, quat_mul, yaw_quaternion
from gnn_mp_envs.robots.problem import JointSpaceProblem
from gnn_mp_envs.robots.render import check_camera, render_robot
from gnn_mp_envs.robots.world import RobotWorld
from gnn_mp_envs.tasks.base import SPLIT_SEEDS, Task, check_keys
from gnn_mp_envs.tasks.mbm.data import INVALID_PROBLEMS, SCENES, SPHERE_INVALID_PROBLEMS, MBMRecord, scene_records

#: BiRRT extension length (rad, joint-space L2 over the seven joints).
STEP_SIZE = 1.0
#: Collision-checking resolution along edges (rad, joint-space L2).
RESOLUTION = 0.01
#: The held-out-scenes variant: train on the other five, test on these two.
HELD_OUT_SCENES = ("bookshelf_thin", "cage")
TRAIN_SCENES = tuple(s for s in SCENES if s not in HELD_OUT_SCENES)
#: ``scene=`` values: one scene, all seven, the five training scenes or the two held-out ones.
SCENE_SETS: dict[str, tuple[str, ...]] = {"all": SCENES, "train": TRAIN_SCENES, "test": HELD_OUT_SCENES,
                                          **{s: (s,) for s in SCENES}}
#: Split -> positions ``[first, last)`` of the problems within each scene (file ``k + 1`` is position ``k``).
SPLIT_POSITIONS = {"train": (0, 60), "val": (60, 70), "test": (70, 100)}
#: Problems left out because their start or goal is in collision (or out of the joint limits) under
#: the shipped robot model, as ``(scene, file) -> reason``. Measured over all 700: none
#: (tests/test_mbm.py re-checks every one). A problem listed here is skipped with this note.
EXCLUDED: dict[tuple[str, int], str] = {}
#: Perturbed training problems: whole-scene rotation about the robot's base axis (rad) and shift (m).
PERTURB_YAW = 0.25
PERTURB_SHIFT = (0.05, 0.05, 0.03)
PERTURB_TRIES = 20
#: Camera of the images, for a scene straight ahead (+x): eye and target; turned about the base
#: axis toward each scene's obstacles, so the view is over the robot's shoulder into the scene.
CAMERA_EYE = (-0.8, -0.75, 1.35)
CAMERA_TARGET = (0.6, 0.0, 0.3)


class MBMProblem(JointSpaceProblem):
    """A problem in one MotionBenchMaker scene (``family``: the scene's name; ``mbm_file``:
    the problem's file number in MBM, 0 for perturbed copies and problems given by hand)."""

    task = "panda-mbm"

    def __init__(self, world: RobotWorld, obstacles: tuple[Obstacle, ...], start: Any, goal: Any, checker: Checker,
                 step_size: float = STEP_SIZE, resolution: float = RESOLUTION, family: str | None = None,
                 mbm_file: int = 0, task: str = "panda-mbm") -> None:
        super().__init__(world, obstacles, start, goal, step_size, checker, resolution, task=task, family=family)
        self.mbm_file = int(mbm_file)


class MBMTask(Task):
    """MotionBenchMaker's problems of one robot (:attr:`robot`) in ``scene`` (one of :data:`SCENES`,
    ``"all"``, ``"train"``: the five training scenes, ``"test"``: the held-out ``bookshelf_thin``
    and ``cage``), checked by ``checker`` (a name of :data:`~gnn_mp_envs.robots.checkers.CHECKERS`; None: the
    default, the sphere checker).

    ``problem(split, i)`` walks the scenes round-robin: problem ``i`` is the ``i // n``-th problem
    of the split in scene ``i % n`` (n scenes), so any prefix covers every scene. Splits take
    positions 0-59 / 60-69 / 70-99 of each scene's 100 problems. Split ``train`` continues past
    MBM's own problems with perturbed copies of them (the whole scene and the start/goal poses
    rotated about the robot's base and shifted, goals re-solved by IK); ``val`` and ``test`` hold
    MBM's problems only.
    """

    name = "panda-mbm"
    #: The robot (its data file and model): ``"panda"``, ``"ur5"`` or ``"fetch"``.
    robot = "panda"
    #: ``[is_box, is_cylinder, is_sphere, size (3; box half extents, cylinder radius and height,
    #: sphere radius; zero-padded), position (3), quaternion x, y, z, w (w >= 0)]``.
    obstacle_width = 13
    max_obstacles = 21
    planners = ("birrt", "rrt")

    def __init__(self, scene: str = "all", step_size: float = STEP_SIZE, resolution: float = RESOLUTION,
                 render_size: tuple[int, int] = (480, 360), checker: str | None = None,
                 camera: tuple | None = None) -> None:
        if scene not in SCENE_SETS:
            raise ValueError(f"unknown {self.name} scene {scene!r}; known: {', '.join(SCENE_SETS)}")
        self.scene = scene
        self.scenes = SCENE_SETS[scene]
        self.step_size = float(step_size)
        self.resolution = float(resolution)
        self.render_size = (int(render_size[0]), int(render_size[1]))
        #: The images' camera (eye, target, up; None: over the robot's shoulder into each scene, :meth:`view`).
        self.camera = None if camera is None else check_camera(camera)
        checker = checker_name(checker)           # refused before the simulator starts
        self.world = RobotWorld(robot_model(self.robot))
        #: The planner's collision checker (:mod:`gnn_mp_envs.robots.checkers`).
        self.checker = make_checker(checker, self.world)
        self._order: dict[str, list[MBMRecord]] = {}

    def excluded(self) -> dict[tuple[str, int], str]:
        """Problems left out, ``(scene, file) -> why``: those whose start or goal is invalid under the
        shipped robot model for either checker (:data:`EXCLUDED`, ``data.INVALID_PROBLEMS``,
        ``data.SPHERE_INVALID_PROBLEMS``), so that both checkers plan the same problems."""
        return {**(EXCLUDED if self.robot == "panda" else {}), **INVALID_PROBLEMS.get(self.robot, {}),
                **SPHERE_INVALID_PROBLEMS.get(self.robot, {})}

    # ------------------------------------------------------------------ problems
    def split_records(self, split: str) -> list[MBMRecord]:
        """MBM's problems of ``split`` in this task's scenes, round-robin over the scenes (excluded ones left out)."""
        if split not in SPLIT_POSITIONS:
            raise ValueError(f"unknown split {split!r}; known: {sorted(SPLIT_POSITIONS)}")
        if split not in self._order:
            first, last = SPLIT_POSITIONS[split]
            excluded = self.excluded()
            per_scene = [[r for r in scene_records(s, self.robot)[first:last] if (s, r.file) not in excluded]
                         for s in self.scenes]
            self._order[split] = [records[k] for k in range(max(map(len, per_scene)))
                                  for records in per_scene if k < len(records)]
        return self._order[split]

    def num_problems(self, split: str) -> int | None:
        """How many problems ``split`` holds (None: unbounded, the training split's perturbed copies)."""
        return None if split == "train" else len(self.split_records(split))

    def problem(self, split: str, index: int) -> MBMProblem:
        records = self.split_records(split)
        if index < 0:
            raise ValueError(f"problem index must be >= 0, got {index}")
        if index < len(records):
            return self._mbm_problem(records[index])
        if split != "train":
            raise ValueError(f"split {split!r} of {self.name} scene {self.scene!r} has {len(records)} problems "
                             f"(indices 0..{len(records) - 1}), got index {index}")
        rng = np.random.default_rng([SPLIT_SEEDS[split], int(index)])
        return self.perturbed(records[index % len(records)], rng)

    def sample_problem(self, rng: np.random.Generator) -> MBMProblem:
        """A perturbed copy of a random training problem."""
        records = self.split_records("train")
        return self.perturbed(records[int(rng.integers(len(records)))], rng)

    def _mbm_problem(self, record: MBMRecord) -> MBMProblem:
        return MBMProblem(self.world, record.obstacles, record.start, record.goal, self.checker, self.step_size,
                          self.resolution, family=record.scene, mbm_file=record.file, task=self.name)

    def perturbed(self, record: MBMRecord, rng: np.random.Generator) -> MBMProblem:
        """``record``'s scene rotated about the robot's base axis by up to :data:`PERTURB_YAW` and
        shifted by up to :data:`PERTURB_SHIFT`, with the goal (and, where MBM's starts are poses in
        the scene rather than the fixed ready pose, the start) moved along: the same hand pose
        relative to the scene, re-solved by IK from the old configuration turned by the yaw. Where IK
        does not converge (poses near the joint limits), later draws rotate only, which joint 1
        follows exactly. Redrawn until start and goal are valid; the unperturbed problem after
        :data:`PERTURB_TRIES` failures."""
        world = self.world
        fixed_start = len({r.start for r in scene_records(record.scene, self.robot)}) == 1
        for attempt in range(PERTURB_TRIES):
            yaw = float(rng.uniform(-PERTURB_YAW, PERTURB_YAW))
            shift = rng.uniform(-1.0, 1.0, 3) * np.asarray(PERTURB_SHIFT)
            if attempt >= PERTURB_TRIES // 2:
                shift[:] = 0.0
            c, s = math.cos(yaw), math.sin(yaw)
            rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            turn = yaw_quaternion(yaw)

            def moved(q: tuple[float, ...]) -> np.ndarray | None:
                turned = np.array(q, dtype=np.float64)
                turned[0] += yaw
                if not shift.any():
                    return turned if world.low[0] <= turned[0] <= world.high[0] else None
                position, orientation = world.flange_pose(np.asarray(q))
                return world.pose_ik(rot @ position + shift, quat_mul(turn, orientation), turned)

            goal = moved(record.goal)
            start = np.array(record.start) if fixed_start else moved(record.start)
            if goal is None or start is None:
                continue
            obstacles = tuple(Obstacle(o.kind, o.size, tuple(rot @ np.asarray(o.position) + shift),
                                       orientation=tuple(quat_mul(turn, np.asarray(o.quaternion()))))
                              for o in record.obstacles)
            problem = MBMProblem(world, obstacles, start, goal, self.checker, self.step_size, self.resolution,
                                 family=record.scene, task=self.name)
            if problem.is_state_valid(np.stack([problem.start, problem.goal])).all():
                return problem
        return self._mbm_problem(record)

    def state_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.world.low.copy(), self.world.high.copy()

    def make_problem(self, spec: Any) -> Problem:
        """A Problem, or a dict ``{"start", "goal"[, "obstacles"]}`` with obstacles as :class:`Obstacle`
        or dicts ``{"kind", "size", "position"[, "yaw"][, "orientation"]}`` (default: no obstacles)."""
        if isinstance(spec, dict):
            check_keys(spec, ("start", "goal", "obstacles"), f"a {self.name} problem dict")
            obstacles = []
            for o in spec.get("obstacles", ()):
                if isinstance(o, dict):
                    check_keys(o, ("kind", "size", "position", "yaw", "orientation"), f"a {self.name} obstacle dict")
                    try:
                        o = Obstacle(str(o["kind"]), o["size"], o["position"], o.get("yaw", 0.0),
                                     o.get("orientation"))
                    except KeyError as e:
                        raise InvalidProblemError(f"a {self.name} obstacle needs 'kind', 'size' and 'position' "
                                                  f"(missing {e})") from None
                obstacles.append(o)
            if "start" not in spec or "goal" not in spec:
                raise InvalidProblemError(f"a {self.name} problem dict needs 'start' and 'goal'")
            spec = MBMProblem(self.world, tuple(obstacles), spec["start"], spec["goal"], self.checker, self.step_size,
                              self.resolution, task=self.name)
        elif isinstance(spec, JointSpaceProblem) and spec.world is not self.world:
            raise InvalidProblemError(f"the {self.name} problem belongs to another {type(self).__name__} "
                                      "(pybullet client)")
        if isinstance(spec, Problem) and len(self.obstacle_rows(spec)) > self.max_obstacles:
            raise InvalidProblemError(f"a {self.name} problem has at most {self.max_obstacles} obstacles")
        return super().make_problem(spec)

    def obstacle_rows(self, problem: Problem) -> np.ndarray:
        rows = []
        for ob in problem.obstacles:
            q = np.asarray(ob.quaternion(), dtype=np.float64)
            q = -q if q[3] < 0 else q
            rows.append([ob.kind == "box", ob.kind == "cylinder", ob.kind == "sphere",
                         *ob.size, *([0.0] * (3 - len(ob.size))), *ob.position, *q])
        return np.asarray(rows, dtype=np.float64).reshape(-1, self.obstacle_width)

    def render_rgb(self, problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
        """TinyRenderer image: the robot at the start (and, faded, at the goal), the scene, hand
        positions of (up to 2000) tree nodes and, on success, the hand's trace along the path."""
        if not isinstance(problem, JointSpaceProblem):
            raise TypeError(f"expected a {self.name} problem, got {type(problem).__name__}")
        return render_robot(self.world, problem, tree, path, *self.render_size,
                            camera=self.camera or self.view(problem))

    @staticmethod
    def view(problem: JointSpaceProblem) -> tuple:
        """Eye, target and up of the problem's image: :data:`CAMERA_EYE` / :data:`CAMERA_TARGET`
        turned about the base axis toward the centre of the obstacles."""
        centre = np.mean([o.position for o in problem.obstacles], axis=0) if problem.obstacles else np.ones(3)
        a = math.atan2(centre[1], centre[0])
        c, s = math.cos(a), math.sin(a)
        turn = lambda x, y, z: (c * x - s * y, s * x + c * y, z)   # noqa: E731
        return turn(*CAMERA_EYE), turn(*CAMERA_TARGET), (0.0, 0.0, 1.0)

    def close(self) -> None:
        self.world.close()


class PandaMBMTask(MBMTask):
    """MotionBenchMaker's Franka Panda problems (seven joints; pybullet_data's Panda, fingers open)."""

    name = "panda-mbm"
    robot = "panda"


class UR5MBMTask(MBMTask):
    """MotionBenchMaker's UR5 problems (six joints; VAMP's UR5 with a Robotiq FT-300 and 2F-85)."""

    name = "ur5-mbm"
    robot = "ur5"


class FetchMBMTask(MBMTask):
    """MotionBenchMaker's Fetch problems (the torso's lift and seven arm joints; base fixed)."""

    name = "fetch-mbm"
    robot = "fetch"
