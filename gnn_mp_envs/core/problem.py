"""The problem protocol: everything the planner core needs to know about a task.

A problem owns its state space (dimension, sampling bounds, distance), how to extend
toward a target (straight line for geometric problems, integrated dynamics for
kinodynamic ones), its validity checks and its goal test. Every state checked for
validity increments ``collision_checks``, so planners and samplers can be compared by
the work they cause, not only by wall time.

The planners in :mod:`gnn_mp_envs.core.planners` never look inside a problem beyond
this interface: adding a task means writing one subclass, not a new planner or env.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from gnn_mp_envs.utils.compiled import lazy_njit


#: The independent re-check of returned paths (``path_valid(..., refine=...)``) interpolates edges this
#: many times finer than the planner's collision-checking resolution.
PATH_CHECK_REFINE = 10
#: Steering refuses motions shorter than this (the problem's distance): a zero-length edge adds nothing.
ZERO_LENGTH = 1e-12



def verdict(value: Any) -> bool:
    """A check's answer as a bool that is True only for a real True (``bool`` or numpy's): a
    task's ``path_valid`` returning NaN, None, a string or an array counts as invalid, not as
    Python's truthy ``bool(nan)``."""
    return isinstance(value, (bool, np.bool_)) and bool(value)


#: The control of a geometric edge: one shared, read-only empty array (no allocation per edge).
NO_CONTROL = np.zeros(0)
NO_CONTROL.setflags(write=False)


class Edge(NamedTuple):
    """The outcome of one successful extension: the new state and how it was reached (a named
    tuple: one is made per planner iteration, and a frozen dataclass costs several times more)."""

    state: np.ndarray
    cost: float
    control: np.ndarray = NO_CONTROL


def _nearest_row_loop(states: np.ndarray, x: np.ndarray, weights: np.ndarray, periodic: np.ndarray
                      ) -> tuple[int, float]:
    """Index and distance of the row of ``states`` nearest ``x`` under the weighted metric
    ``sqrt(sum_c (w_c d_c)^2)`` (``d_c`` wrapped into [-pi, pi) where ``periodic``), in one loop:
    the operations, in order, of the numpy metrics it stands for (difference, wrap, weights, sum of
    squares over the coordinates in order, square root), so the same floats; numpy's argmin rule
    (the first NaN, else the first minimum). Compiled by numba when it is installed: the pendulum's
    scan of 600 rows took 53 us in numpy passes and takes 9 us here."""
    best, best_d, nan_seen = -1, 0.0, False
    for j in range(states.shape[0]):
        acc = 0.0
        for c in range(x.shape[0]):
            v = states[j, c] - x[c]
            if periodic[c]:
                a = v + math.pi
                # a % (2 pi) is a itself on (0, 2 pi), the common case (fmod is exact); else the modulo
                v = (a if 0.0 < a < 2 * math.pi else a % (2 * math.pi)) - math.pi
            v = v * weights[c]
            acc += v * v
        d = math.sqrt(acc)
        if d != d:
            if not nan_seen:
                nan_seen, best, best_d = True, j, d
        elif not nan_seen and (best < 0 or d < best_d):
            best, best_d = j, d
    return best, best_d


#: :func:`_nearest_row_loop` compiled (numba), or None without numba.
compiled_nearest_row = lazy_njit(_nearest_row_loop)


def _nearest_node_loop(states: np.ndarray, k: int, x: np.ndarray, weights: np.ndarray, periodic: np.ndarray,
                       index: np.ndarray) -> int:
    """``index[j]`` of the row ``j`` of ``states[:k]`` nearest ``x`` (:func:`_nearest_row_loop`): a small
    tree's nearest node in one compiled call, without the slice and the lookup in Python."""
    return index[_nearest_row_loop(states[:k], x, weights, periodic)[0]]


#: :func:`_nearest_node_loop` compiled (numba, calling the compiled :func:`_nearest_row_loop`), or None
#: without numba.
compiled_nearest_node = lazy_njit(_nearest_node_loop, calls={"_nearest_row_loop": compiled_nearest_row})


class InvalidProblemError(ValueError):
    """A problem that cannot be planned: wrong dimension, start or goal invalid."""


class Problem:
    """Base class of planning problems.

    Subclasses set ``state_dim``, ``low``, ``high``, ``start`` and ``goal`` and implement
    :meth:`is_state_valid` (uncounted, may be vectorised) and :meth:`steer`. Geometric
    problems can rely on the straight-line :meth:`steer` defined here.
    """

    #: Name of the task family, used in observations, renders and logs.
    task: str = "problem"
    #: True when edges are straight lines in state space (BiRRT connect needs this).
    geometric: bool = True
    #: Dimension of the stored control per edge (0 for geometric problems).
    control_dim: int = 0

    def __init__(self, start: np.ndarray, goal: np.ndarray, low: np.ndarray, high: np.ndarray,
                 step_size: float, resolution: float, goal_tolerance: float = 1e-9) -> None:
        self.low = np.asarray(low, dtype=np.float64)
        self.high = np.asarray(high, dtype=np.float64)
        self.state_dim = int(self.low.shape[0])
        self.start = self._as_state(start, "start")
        self.goal = self._as_state(goal, "goal")
        self.step_size = float(step_size)
        self.resolution = float(resolution)
        self.goal_tolerance = float(goal_tolerance)
        self.collision_checks = 0
        self.edges_checked = 0

    # ------------------------------------------------------------------ state space
    def _as_state(self, x: Any, name: str) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.state_dim,):
            raise InvalidProblemError(
                f"{name} must have shape ({self.state_dim},), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise InvalidProblemError(f"{name} must be finite, got {x}")
        return x

    def sample_uniform(self, rng: np.random.Generator) -> np.ndarray:
        """A state drawn uniformly from the sampling bounds."""
        return rng.uniform(self.low, self.high)

    def difference(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``a - b`` in the state space (vectorised over leading axes; wraps angles)."""
        return a - b

    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Distance from each row of ``states`` to ``x`` (the planner's nearest-neighbour metric)."""
        d = self.difference(states, x)
        return np.sqrt(np.einsum("...i,...i->...", d, d))

    #: ``(weights, periodic)`` when :meth:`distance` is the weighted metric of :func:`_nearest_row_loop`
    #: (float per coordinate, bool per coordinate): :meth:`nearest_row` then runs that loop, compiled.
    #: None: numpy's argmin over :meth:`distance`.
    nearest_metric: tuple[np.ndarray, np.ndarray] | None = None

    def nearest_row(self, states: np.ndarray, x: np.ndarray) -> tuple[int, float]:
        """Index and distance of the row of ``states`` (at least one) nearest ``x`` under
        :meth:`distance`, the first of equals: the planner's nearest-neighbour scan."""
        loop = compiled_nearest_row() if self.nearest_metric is not None else None
        if loop is not None:
            return loop(states, x, *self.nearest_metric)
        d = self.distance(states, x)
        j = int(d.argmin())
        return j, float(d[j])

    def compiled_kernel(self) -> Any:
        """The compiled steering and checks the planner's compiled loop runs (a
        :class:`~gnn_mp_envs.core.loop.CompiledKernel`, current for this problem), or None: the Python
        planner (the default; a problem whose steer and checks are compiled overrides this)."""
        return None

    #: Periodic box sizes of the ``nn_embed`` coordinates for the k-d tree (None: none periodic).
    nn_boxsize: np.ndarray | None = None

    def nn_embed(self, states: np.ndarray) -> np.ndarray:
        """Coordinates in which Euclidean distance equals :meth:`distance` (for k-d trees)."""
        return states

    def interpolate(self, a: np.ndarray, b: np.ndarray, t: np.ndarray | float) -> np.ndarray:
        """States a fraction ``t`` of the way from ``a`` to ``b`` (geometric problems)."""
        t = np.asarray(t, dtype=np.float64)[..., None]
        return a + t * self.difference(b, a)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """Map a state into its canonical range (e.g. wrap angles); identity by default."""
        return x

    # ------------------------------------------------------------------ validity
    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        """Uncounted validity of each row of ``states``; subclasses implement this."""
        raise NotImplementedError

    def is_state_valid_exact(self, states: np.ndarray) -> np.ndarray:
        """Validity without a safety margin the planner's checks may add (default: :meth:`is_state_valid`);
        the independent re-check of returned paths (``path_valid(..., refine=...)``) uses it."""
        return self.is_state_valid(states)

    def check_state(self, x: np.ndarray) -> bool:
        """Counted validity check of one state."""
        self.collision_checks += 1
        return bool(self.is_state_valid(x[None])[0])

    def check_motion(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Counted check of the straight segment ``a -> b`` (``a`` assumed valid).

        States are checked at ``resolution`` spacing including ``b``; each one counts.
        """
        self.edges_checked += 1
        n = max(1, int(np.ceil(float(self.distance(b[None], a)[0]) / self.resolution)))
        states = self.interpolate(a, b, np.arange(1, n + 1) / n)
        valid = self.is_state_valid(states)
        # Count only what a sequential checker would have looked at.
        bad = np.flatnonzero(~valid)
        self.collision_checks += int(bad[0]) + 1 if bad.size else n
        return not bad.size

    # ------------------------------------------------------------------ extension
    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """Extend from ``x_from`` toward ``x_to`` by at most ``step_size``; None if blocked."""
        d = float(self.distance(x_to, x_from))
        if d < ZERO_LENGTH:
            return None
        x_new = x_to if d <= self.step_size else self.interpolate(x_from, x_to, self.step_size / d)
        x_new = self.normalize(np.asarray(x_new, dtype=np.float64))
        if not self.check_motion(x_from, x_new):
            return None
        return Edge(x_new, min(d, self.step_size))

    def edge_valid(self, x_from: np.ndarray, x_to: np.ndarray, control: np.ndarray) -> bool:
        """Re-check a stored edge (used to validate returned paths; counted)."""
        return self.check_motion(x_from, x_to)

    # ------------------------------------------------------------------ goal
    def in_goal(self, x: np.ndarray) -> bool:
        """True when ``x`` satisfies the goal."""
        return float(self.distance(x[None], self.goal)[0]) <= self.goal_tolerance

    def goal_connection(self, x: np.ndarray) -> Edge | None:
        """A checked edge from ``x`` straight to the goal when it is within one step.

        Geometric problems try this after every new node; kinodynamic problems return None
        and rely on :meth:`in_goal`.
        """
        if not self.geometric:
            return None
        d = float(self.distance(self.goal[None], x)[0])
        if d > self.step_size or not self.check_motion(x, self.goal):
            return None
        return Edge(self.goal.copy(), d)

    # ------------------------------------------------------------------ bookkeeping
    def validate(self) -> None:
        """Raise :class:`InvalidProblemError` when start or goal is out of bounds or invalid."""
        for name, x in (("start", self.start), ("goal", self.goal)):
            if np.any(x < self.low - 1e-9) or np.any(x > self.high + 1e-9):
                raise InvalidProblemError(
                    f"{name} {x} lies outside the bounds [{self.low}, {self.high}]")
            if not bool(self.is_state_valid(x[None])[0]):
                raise InvalidProblemError(f"{name} {x} is in collision / invalid")
        if self.in_goal(self.start):
            raise InvalidProblemError(f"start {self.start} already satisfies the goal {self.goal}: "
                                      "nothing to plan")

    def reset_counters(self) -> None:
        self.collision_checks = 0
        self.edges_checked = 0

    def path_valid(self, states: np.ndarray, controls: np.ndarray | None = None, refine: int = 1) -> bool:
        """Re-check a whole path: endpoints, and every edge at the checker's resolution.

        ``refine > 1`` (geometric problems): instead of the planner's own edge check, every edge is
        interpolated ``refine`` times finer than ``resolution`` (both ends included) and the states
        go through the uncounted :meth:`is_state_valid_exact`: an independent check that catches
        what the planner's resolution skips over. Kinodynamic edges are re-simulated either way."""
        if len(states) < 1:
            return False
        if not np.allclose(states[0], self.start) or not self.in_goal(states[-1]):
            return False
        if controls is None:
            controls = np.zeros((len(states), self.control_dim))
        if refine > 1 and self.geometric:
            step = self.resolution / refine
            for a, b in zip(states[:-1], states[1:]):
                n = max(1, int(np.ceil(float(self.distance(b[None], a)[0]) / step)))
                if not self.is_state_valid_exact(self.interpolate(a, b, np.arange(n + 1) / n)).all():
                    return False
            return True
        return all(self.edge_valid(states[i], states[i + 1], controls[i + 1])
                   for i in range(len(states) - 1))
