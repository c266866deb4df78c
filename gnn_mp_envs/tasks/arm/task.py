"""The arm task family: scenes drawn from a family, IK goals into the structure, starts on the
far side, and a straight start-goal motion that must be blocked."""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import InvalidProblemError, Problem
from gnn_mp_envs.tasks.arm.problem import RESOLUTION, STEP_SIZE, ArmProblem
from gnn_mp_envs.tasks.arm.render import render_arm
from gnn_mp_envs.tasks.arm.scenes import SCENE_FAMILIES, Obstacle, sample_scene, start_target
from gnn_mp_envs.tasks.arm.world import JOINT_HIGH, JOINT_LOW, ArmWorld
from gnn_mp_envs.tasks.base import Task, check_keys

#: Scene and start/goal draws before a problem generator gives up.
MAX_SCENE_TRIES = 50
START_TRIES = 10
#: The two training families; ``scene="train"`` draws one of them per problem.
TRAIN_FAMILIES = ("train-a", "train-b")


class ArmTask(Task):
    """xArm6 tabletop problems of one scene family (``train-a``, ``train-b``, ``train`` =
    either training family per problem, or the held-out ``test`` family)."""

    name = "arm"
    #: ``[is_box, is_cylinder, size (3; a cylinder's radius, height, 0), position (3), cos yaw, sin yaw]``.
    obstacle_width = 10
    max_obstacles = 12
    planners = ("birrt", "rrt")

    def __init__(self, scene: str = "train-a", step_size: float = STEP_SIZE,
                 resolution: float = RESOLUTION, require_blocked: bool = True,
                 render_size: tuple[int, int] = (480, 360)) -> None:
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
            check_keys(spec, ("start", "goal", "obstacles"), "an arm problem dict")
            for o in spec.get("obstacles", ()):
                if isinstance(o, dict):
                    check_keys(o, ("kind", "size", "position", "yaw"), "an arm obstacle dict")
            try:
                obstacles = tuple(o if isinstance(o, Obstacle) else
                                  Obstacle(str(o["kind"]), o["size"], o["position"], o.get("yaw", 0.0))
                                  for o in spec.get("obstacles", ()))
                spec = ArmProblem(self.world, obstacles, spec["start"], spec["goal"], self.step_size,
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
        return render_arm(self.world, problem, tree, path, *self.render_size)

    def close(self) -> None:
        self.world.close()
