"""Joint-space planning problems of a robot: bounds (its joint limits), straight-line steering and
counted edge checks at a resolution against one scene of a :class:`RobotWorld`, by the collision
checker the problem holds (:mod:`gnn_mp_envs.robots.checkers`).

Each configuration checked counts one collision check; edges are interpolated every ``resolution``
rad (joint-space L2) and stop at the first invalid configuration.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import ZERO_LENGTH, Edge, Problem
from gnn_mp_envs.robots.checkers import Checker
from gnn_mp_envs.robots.geometry import Obstacle, Scene
from gnn_mp_envs.robots.spheres.kernel import joint_distance
from gnn_mp_envs.robots.world import CONTACT_DISTANCE, RobotWorld

#: Collision-checking resolution along edges (rad, joint-space L2), unless a task names another.
#: With the robots' padding it keeps returned paths valid at the benchmark's 10x finer re-check.
RESOLUTION = 0.01


#: The padded joint limits of the problems planned so far, by their limits' bytes (one entry per robot).
_PADDED: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}


def _padded_bounds(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(low - 1e-12, high + 1e-12)``, the same array objects for every problem of the same limits (never written:
    private to the problems): the checker's compiled kernel, which holds them, then serves problem after problem
    without being rebuilt."""
    key = low.tobytes() + high.tobytes()
    padded = _PADDED.get(key)
    if padded is None:
        padded = _PADDED.setdefault(key, (low - 1e-12, high + 1e-12))
    return padded


class JointSpaceProblem(Problem):
    """Joint-space planning for the world's robot (bounds: its joint limits) in one scene of a
    :class:`RobotWorld`, checked by ``checker``; ``task``: the task name results are reported under,
    ``family``: the scene family (default: the Scene's; None for obstacles given by hand)."""

    task = "robot"
    geometric = True
    #: Order in which an edge's states are checked: True, ``b`` first, then by bisection (OMPL's
    #: ``DiscreteMotionValidator`` order), which meets a blocking obstacle in fewer checks; False, from
    #: ``a`` to ``b``. Either way the edge is valid only if every state is.
    bisection = True

    def __init__(self, world: RobotWorld, scene: Scene | tuple[Obstacle, ...], start: np.ndarray,
                 goal: np.ndarray, step_size: float, checker: Checker, resolution: float = RESOLUTION,
                 task: str | None = None, family: str | None = None) -> None:
        super().__init__(start, goal, low=world.low, high=world.high, step_size=step_size,
                         resolution=resolution)
        self.world = world
        self.scene = scene
        #: The collision checker of the planner's checks (:mod:`gnn_mp_envs.robots.checkers`).
        self.checker = checker
        if task is not None:
            self.task = task
        self._family = family if family is not None else (scene.family if isinstance(scene, Scene) else None)
        self._shape = (self.state_dim,)
        # NaN fails both comparisons, so these bounds tests also reject non-finite states.
        self._low, self._high = _padded_bounds(self.low, self.high)
        # distance's metric (unweighted, no periodic joint), for the planner's compiled nearest scan
        self.nearest_metric = (np.ones(self.state_dim), np.zeros(self.state_dim, dtype=np.bool_))
        checker.prepare(scene)      # build the checker and load the scene now, not in the first (timed) check

    @property
    def family(self) -> str | None:
        """The scene family the problem was drawn from (None: a problem given by hand); the
        benchmark reports results per family."""
        return self._family

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        return self.scene.obstacles if isinstance(self.scene, Scene) else tuple(self.scene)

    def _state_arg(self, x: np.ndarray, name: str) -> np.ndarray:
        """``x`` as one float64 state of this robot, or a one-line ValueError: the checkers' native code
        (pybullet, the compiled kernel) must never see a state of another length."""
        if type(x) is np.ndarray and x.shape == self._shape and x.dtype == np.float64:
            return x
        x = np.asarray(x, dtype=np.float64)
        if x.shape != self._shape:
            raise ValueError(f"{name} must be one state of shape ({self.state_dim},) of this robot, "
                             f"got shape {x.shape}")
        return x

    def _states_arg(self, states: np.ndarray) -> np.ndarray:
        """``states`` (one state or rows of states) as ``(n, state_dim)`` float64, or a one-line ValueError."""
        s = np.asarray(states, dtype=np.float64)
        if s.ndim not in (1, 2) or s.shape[-1] != self.state_dim:
            raise ValueError(f"states must have shape ({self.state_dim},) or (n, {self.state_dim}) for this robot, "
                             f"got shape {s.shape}")
        return s.reshape(-1, self.state_dim)

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        s = self._states_arg(states)
        ok = self._in_bounds(s)
        if ok.any():
            ok[ok] = self.checker.valid(self.scene, s[ok])
        return ok

    def is_state_valid_exact(self, states: np.ndarray) -> np.ndarray:
        """:meth:`is_state_valid` by pybullet's contacts without the robot's padding: any penetration,
        and only that, is a collision (the re-check of returned paths, whatever the planner's checker)."""
        s = self._states_arg(states)
        ok = self._in_bounds(s)
        self.world.load(self.scene)
        rows = s.tolist()
        for i in np.flatnonzero(ok).tolist():
            if self.world.collides(rows[i], CONTACT_DISTANCE):
                ok[i] = False
        return ok

    def check_motion(self, a: np.ndarray, b: np.ndarray) -> bool:
        """The checker's edge check (the states every ``resolution``, ``b`` included, in
        :attr:`bisection` order, stopping at the first invalid one), counted; sequentially it counts
        exactly as :meth:`Problem.check_motion`. ``a`` is assumed valid for this checker and not tested
        (as OMPL's motion validators assume): a state pybullet calls free may be invalid for the sphere
        model's margin, so ``check_motion(a, b)`` and ``check_motion(b, a)`` may differ when one end is."""
        a, b = self._state_arg(a, "a"), self._state_arg(b, "b")
        self.edges_checked += 1
        valid, checks = self.checker.check_motion(self.scene, a, b, self.resolution, self._low, self._high,
                                                  self.bisection)
        self.collision_checks += checks
        return valid

    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray:
        d = states - x  # plain joint-space L2 (no angle wrapping: the box is one turn per joint)
        return np.sqrt(np.einsum("...i,...i->...", d, d))

    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """:meth:`Problem.steer` in one checker call (the sphere checker: one compiled call for measuring,
        steering and the edge's check), with the same result."""
        x_from, x_to = self._state_arg(x_from, "x_from"), self._state_arg(x_to, "x_to")
        x_new, dist, valid, checks = self.checker.steer(self.scene, x_from, x_to, self.step_size, self.resolution,
                                                        self._low, self._high, self.bisection)
        if dist < ZERO_LENGTH:
            return None
        self.edges_checked += 1
        self.collision_checks += checks
        if not valid:
            return None
        return Edge(x_new, dist if dist <= self.step_size else self.step_size)

    def compiled_kernel(self) -> Any:
        """The checker's compiled steer and checks for this problem's scene (None: the Python planner)."""
        return self.checker.compiled_kernel(self.scene, self.step_size, self.resolution, self._low, self._high,
                                            self.bisection)

    def goal_connection(self, x: np.ndarray) -> Edge | None:
        x = self._state_arg(x, "x")
        dist = joint_distance(self.goal, x)
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
