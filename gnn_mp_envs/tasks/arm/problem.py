"""Joint-space planning problems of an arm (the xArm6, the Panda, the UR5, the Fetch): bounds,
straight-line steering and counted edge checks at :data:`RESOLUTION` against one scene of an
:class:`ArmWorld`, by one of :data:`CHECKERS`.

Each configuration checked counts one collision check; edges are interpolated every
:data:`RESOLUTION` rad (joint-space L2) and stop at the first invalid configuration.
"""

from __future__ import annotations

import collections
import functools
import math

import numpy as np

from gnn_mp_envs.core.problem import ZERO_LENGTH, Edge, Problem
from gnn_mp_envs.tasks.arm.scenes import Obstacle, Scene
from gnn_mp_envs.tasks.arm.world import CONTACT_DISTANCE, ArmWorld

#: RRT/BiRRT extension length in joint space (rad, L2 over the six joints).
STEP_SIZE = 0.4
#: Collision-checking resolution along edges (rad, joint-space L2). With the robot's padding it keeps
#: returned paths valid at the benchmark's 10x finer re-check (docs/arm.md).
RESOLUTION = 0.01
#: The planner's collision checkers: ``"spheres"``, the compiled sphere model that covers the
#: robot's collision geometry (:mod:`gnn_mp_envs.tasks.arm.spheres`), and ``"pybullet"``, contacts
#: of the convex hulls in pybullet. Returned paths are re-checked with pybullet either way.
CHECKERS = ("spheres", "pybullet")


@functools.lru_cache(maxsize=4096)
def bisection_order(n: int) -> tuple[int, ...]:
    """``1..n`` as OMPL's ``DiscreteMotionValidator`` visits an edge's states: ``n`` (the far end)
    first, then the middle of ``1..n-1``, then the middles of its halves, breadth first."""
    order, queue = [n], collections.deque([(1, n - 1)])
    while queue:
        lo, hi = queue.popleft()
        if lo > hi:
            continue
        mid = (lo + hi) // 2
        order.append(mid)
        queue.append((lo, mid - 1))
        queue.append((mid + 1, hi))
    return tuple(order)


class ArmProblem(Problem):
    """Joint-space planning for the world's robot (bounds: its joint limits) in one scene of an
    :class:`ArmWorld`."""

    task = "arm"
    geometric = True

    def __init__(self, world: ArmWorld, scene: Scene | tuple[Obstacle, ...], start: np.ndarray,
                 goal: np.ndarray, step_size: float = STEP_SIZE, resolution: float = RESOLUTION,
                 checker: str = "pybullet") -> None:
        super().__init__(start, goal, low=world.low, high=world.high, step_size=step_size,
                         resolution=resolution)
        if checker not in CHECKERS:
            raise ValueError(f"checker must be one of {CHECKERS}, got {checker!r}")
        self.world = world
        self.scene = scene
        #: Which of :data:`CHECKERS` the planner's checks use.
        self.checker = checker
        # NaN fails both comparisons, so these bounds tests also reject non-finite states.
        self._low = self.low - 1e-12
        self._high = self.high + 1e-12
        self._low_tol = self._low.tolist()
        self._high_tol = self._high.tolist()
        # distance's metric (unweighted, no periodic joint), for the planner's compiled nearest scan
        self.nearest_metric = (np.ones(self.state_dim), np.zeros(self.state_dim, dtype=np.bool_))
        if checker == "spheres":     # build the checker and load the scene now, not in the first (timed) check
            world.sphere_checker(scene)

    @property
    def family(self) -> str | None:
        """The scene family the problem was drawn from (None: a problem given by hand); the
        benchmark reports results per family."""
        return self.scene.family if isinstance(self.scene, Scene) else None

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        return self.scene.obstacles if isinstance(self.scene, Scene) else tuple(self.scene)

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        s = np.asarray(states, dtype=np.float64).reshape(-1, self.state_dim)
        ok = self._in_bounds(s)
        if self.checker == "spheres":
            if ok.any():
                ok[ok] = self.world.sphere_checker(self.scene).valid(s[ok])
            return ok
        self.world.load(self.scene)
        collides = self.world.collides
        rows = s.tolist()
        for i in np.flatnonzero(ok).tolist():
            if collides(rows[i]):
                ok[i] = False
        return ok

    def is_state_valid_exact(self, states: np.ndarray) -> np.ndarray:
        """:meth:`is_state_valid` without the robot's padding: any penetration, and only that, is a collision."""
        s = np.asarray(states, dtype=np.float64).reshape(-1, self.state_dim)
        ok = self._in_bounds(s)
        self.world.load(self.scene)
        rows = s.tolist()
        for i in np.flatnonzero(ok).tolist():
            if self.world.collides(rows[i], CONTACT_DISTANCE):
                ok[i] = False
        return ok

    #: Order in which an edge's states are checked: True, ``b`` first, then by bisection (OMPL's
    #: ``DiscreteMotionValidator`` order), which meets a blocking obstacle in fewer checks; False, from
    #: ``a`` to ``b``. Either way the edge is valid only if every state is.
    bisection = True

    def check_motion(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Check of the states every ``resolution`` (``b`` included) that stops at the first
        invalid configuration, in :attr:`bisection` order; sequentially it counts exactly as
        :meth:`Problem.check_motion`. The sphere checker checks the whole edge in one compiled call.

        Plain Python floats: for the ~8 states of an edge this is faster than numpy, and
        ``a + (k / n) * (b - a)`` gives the same states as the base class.
        """
        self.edges_checked += 1
        if self.checker == "spheres":
            valid, checks = self.world.sphere_checker(self.scene).check_motion(a, b, self.resolution, self._low,
                                                                               self._high, self.bisection)
            self.collision_checks += checks
            return valid
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
        for k in (bisection_order(n) if self.bisection else range(1, n + 1)):
            self.collision_checks += 1
            t = k / n
            if k > limit or collides([x + t * v for x, v in zip(al, dl)]):
                return False
        return True

    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray:
        d = states - x  # plain joint-space L2 (no angle wrapping: the box is one turn per joint)
        return np.sqrt(np.einsum("...i,...i->...", d, d))

    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """:meth:`Problem.steer` without the generic vectorised helpers (same result); with the sphere
        checker, measuring, steering and the edge's check are one compiled call."""
        if self.checker == "spheres":
            x_new, dist, valid, checks = self.world.sphere_checker(self.scene).steer(
                x_from, x_to, self.step_size, self.resolution, self._low, self._high, self.bisection)
            if dist < ZERO_LENGTH:
                return None
            self.edges_checked += 1
            self.collision_checks += checks
            if not valid:
                return None
            return Edge(x_new, dist if dist <= self.step_size else self.step_size)
        d = x_to - x_from
        dist = math.sqrt(float(d @ d))
        if dist < ZERO_LENGTH:
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
