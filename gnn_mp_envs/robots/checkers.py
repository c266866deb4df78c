"""Collision checkers of a robot's joint-space problems: one object, chosen once by name where a task
is made, that the problem calls for every check (as OMPL's ``StateValidityChecker`` and
``MotionValidator`` are objects a ``SpaceInformation`` holds).

:data:`CHECKERS` names them, the default first: ``"spheres"``, the compiled sphere model that covers
the robot's collision geometry (:class:`~gnn_mp_envs.robots.spheres.checker.SphereCollisionChecker`),
and ``"pybullet"``, contacts of the convex hulls in pybullet (:class:`PybulletChecker`). Returned
paths are re-checked with pybullet's exact contacts either way. :func:`checker_name` is the one place
a name is checked.

Every check counts as the planner counts: each configuration looked at is one collision check; an
edge's states lie every ``resolution`` (joint-space L2) from its start, ``b`` included, and are looked
at in the problem's order (``bisection``: ``b`` first, then by bisection, OMPL's
``DiscreteMotionValidator`` order; else from ``a`` to ``b``) until the first invalid one.
"""

from __future__ import annotations

import collections
import functools
import math
from typing import Any, Protocol

import numpy as np

from gnn_mp_envs.core.problem import ZERO_LENGTH
from gnn_mp_envs.robots.spheres.kernel import joint_distance
from gnn_mp_envs.utils.imports import import_entry

#: Checker name -> ``"module:class"`` (imported on first use: the sphere checker compiles with numba);
#: the first is the default.
CHECKERS: dict[str, str] = {"spheres": "gnn_mp_envs.robots.spheres.checker:SphereCollisionChecker",
                            "pybullet": "gnn_mp_envs.robots.checkers:PybulletChecker"}


class Checker(Protocol):
    """What a joint-space problem asks of its collision checker. ``scene`` is the problem's (a
    :class:`~gnn_mp_envs.robots.geometry.Scene` or a tuple of obstacles): a checker loads it when it
    differs from the one it holds. Joint limits are the problem's: states given to :meth:`valid` are
    inside them, and edges are checked against ``low``, ``high``."""

    #: The checker's name in :data:`CHECKERS`.
    name: str

    def prepare(self, scene: Any) -> None:
        """Build what the first check of ``scene`` needs now (outside a timed planning loop)."""

    def valid(self, scene: Any, states: np.ndarray) -> np.ndarray:
        """Whether each row of ``states`` ``(n, dof)`` is collision-free (uncounted)."""

    def check_motion(self, scene: Any, a: np.ndarray, b: np.ndarray, resolution: float, low: np.ndarray,
                     high: np.ndarray, bisection: bool) -> tuple[bool, int]:
        """The edge ``a -> b`` (``a`` valid): ``(valid, states looked at)``."""

    def steer(self, scene: Any, a: np.ndarray, target: np.ndarray, step: float, resolution: float,
              low: np.ndarray, high: np.ndarray, bisection: bool) -> tuple[np.ndarray, float, bool, int]:
        """From ``a`` toward ``target`` by at most ``step`` (joint-space L2), then :meth:`check_motion` of
        that edge: ``(x_new, |target - a|, valid, states looked at)``; below :data:`ZERO_LENGTH` nothing
        is checked: ``(x_new undefined, distance, False, 0)``."""

    def compiled_kernel(self, scene: Any, step: float, resolution: float, low: np.ndarray, high: np.ndarray,
                        bisection: bool) -> Any:
        """The compiled planning loop's kernel for ``scene`` (a :class:`~gnn_mp_envs.core.loop.CompiledKernel`),
        or None: the checker has no compiled steer and check (the Python planner runs)."""


def checker_name(name: str | None) -> str:
    """``name`` if it is one of :data:`CHECKERS` (None: the default, the first); else a one-line ValueError."""
    if name is None:
        return next(iter(CHECKERS))
    if name not in CHECKERS:
        raise ValueError(f"unknown collision checker {name!r}; known: {', '.join(CHECKERS)}")
    return name


def make_checker(name: str | None, world: Any) -> Checker:
    """The checker called ``name`` (None: the default) of ``world``'s robot
    (a :class:`~gnn_mp_envs.robots.world.RobotWorld`)."""
    return import_entry(CHECKERS[checker_name(name)])(world)


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


class PybulletChecker:
    """Contacts of the robot's convex hulls in pybullet, with the robot model's padding
    (:meth:`RobotWorld.collides <gnn_mp_envs.robots.world.RobotWorld.collides>`): one configuration per
    simulator call, in plain Python floats (for the ~8 states of an edge faster than numpy, and
    ``a + (k / n) * (b - a)`` gives the states of :meth:`Problem.check_motion
    <gnn_mp_envs.core.problem.Problem.check_motion>`)."""

    name = "pybullet"

    def __init__(self, world: Any) -> None:
        self.world = world

    def prepare(self, scene: Any) -> None:
        """Nothing to build: :meth:`RobotWorld.load` is a no-op for the scene it holds."""

    def valid(self, scene: Any, states: np.ndarray) -> np.ndarray:
        self.world.load(scene)
        collides = self.world.collides
        return np.array([not collides(row) for row in np.asarray(states).tolist()], dtype=bool)

    def check_motion(self, scene: Any, a: np.ndarray, b: np.ndarray, resolution: float, low: np.ndarray,
                     high: np.ndarray, bisection: bool) -> tuple[bool, int]:
        al, bl = a.tolist(), b.tolist()
        dl = [y - x for x, y in zip(al, bl)]
        n = max(1, math.ceil(math.sqrt(sum(v * v for v in dl)) / resolution))
        lo, hi = low.tolist(), high.tolist()
        limit = n
        if not all(l <= v <= h for v, l, h in zip(bl, lo, hi)):
            # a is valid and the box convex: the states leave it once, somewhere before b.
            limit = next(k for k in range(1, n + 1)
                         if not all(l <= x + (k / n) * v <= h for x, v, l, h in zip(al, dl, lo, hi))) - 1
        self.world.load(scene)
        collides = self.world.collides
        checks = 0
        for k in (bisection_order(n) if bisection else range(1, n + 1)):
            checks += 1
            t = k / n
            if k > limit or collides([x + t * v for x, v in zip(al, dl)]):
                return False, checks
        return True, checks

    def compiled_kernel(self, scene: Any, step: float, resolution: float, low: np.ndarray, high: np.ndarray,
                        bisection: bool) -> None:
        """None: pybullet's checks run from Python (the Python planner)."""
        return None

    def steer(self, scene: Any, a: np.ndarray, target: np.ndarray, step: float, resolution: float,
              low: np.ndarray, high: np.ndarray, bisection: bool) -> tuple[np.ndarray, float, bool, int]:
        dist = joint_distance(target, a)
        if dist < ZERO_LENGTH:
            return a, dist, False, 0
        x_new = np.array(target, dtype=np.float64) if dist <= step else a + (step / dist) * (target - a)
        valid, checks = self.check_motion(scene, a, x_new, resolution, low, high, bisection)
        return x_new, dist, valid, checks

