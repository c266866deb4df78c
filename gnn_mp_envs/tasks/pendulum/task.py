"""Pendulum: a torque-limited swing-up planned with kinodynamic RRT.

State ``[theta, omega]``: ``theta`` is the angle from the downward vertical (0 hangs at
rest, pi is upright), wrapped to [-pi, pi); ``omega`` the angular velocity in rad/s.

Dynamics of a point mass on a massless rod::

    theta'' = -(g / l) sin(theta) + u / (m l^2),    |u| <= MAX_TORQUE

with the constants below. ``MAX_TORQUE`` is a fifth of ``m g l``: the pendulum cannot
lift itself past ~11.5 degrees statically, so every plan has to pump energy over
several swings. An edge applies one constant torque for ``EDGE_DURATION`` seconds,
integrated with RK4; steering tries ``NUM_CONTROLS`` torques evenly spread over the
limits and keeps the one whose end state is nearest the sample. A state is valid when
``|omega| <= MAX_SPEED``; every integrated state on the kept edge counts as one
collision (validity) check.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import Edge, InvalidProblemError, Problem
from gnn_mp_envs.utils.compiled import lazy_njit
from gnn_mp_envs.utils.render import draw_tree, figure, to_rgb
from gnn_mp_envs.tasks.base import Task, check_keys

GRAVITY = 9.81          # m/s^2
MASS = 1.0              # kg
LENGTH = 1.0            # m
MAX_TORQUE = 0.2 * MASS * GRAVITY * LENGTH  # N m  (1.962)
MAX_SPEED = 8.0         # rad/s, validity bound on |omega|
EDGE_DURATION = 0.2     # s per tree edge
INTEGRATION_STEPS = 10  # RK4 steps per edge (dt = 0.02 s)
NUM_CONTROLS = 5        # torques tried per extension
VELOCITY_WEIGHT = 0.4   # weight of omega in the nearest-neighbour metric (~ 2 pi / 16)
GOAL_ANGLE_TOLERANCE = 0.15   # rad
GOAL_SPEED_TOLERANCE = 0.5    # rad/s


def wrap_angle(theta: np.ndarray | float) -> np.ndarray:
    """Wrap to [-pi, pi] (pi itself only through float rounding just below -pi)."""
    return (np.asarray(theta) + np.pi) % (2 * np.pi) - np.pi


def integrate(theta: float, omega: float, torque: float, duration: float = EDGE_DURATION,
              steps: int = INTEGRATION_STEPS) -> tuple[list[float], list[float]]:
    """RK4-integrate one constant-torque edge from ``(theta, omega)`` (Python floats); returns the
    ``steps`` states' angles and velocities (angles not wrapped).

    Plain Python floats on purpose: for a handful of edges it is ~3x faster than numpy, whose
    per-call overhead dominates on 5-element arrays. Every edge of the planner, OMPL's propagator
    and the path re-check integrate through here, so they agree bit for bit.
    """
    h = duration / steps
    half, sixth = 0.5 * h, h / 6.0       # the factors of ``0.5 * h * k`` and ``h / 6.0 * (...)``, hoisted
    a = GRAVITY / LENGTH
    bu = 1.0 / (MASS * LENGTH ** 2) * torque
    sin = math.sin
    th, om = theta, omega
    thetas, omegas = [], []
    for _ in range(steps):
        k1t, k1w = om, bu - a * sin(th)
        k2t, k2w = om + half * k1w, bu - a * sin(th + half * k1t)
        k3t, k3w = om + half * k2w, bu - a * sin(th + half * k2t)
        k4t, k4w = om + h * k3w, bu - a * sin(th + h * k3t)
        th = th + sixth * (k1t + 2 * k2t + 2 * k3t + k4t)
        om = om + sixth * (k1w + 2 * k2w + 2 * k3w + k4w)
        thetas.append(th)
        omegas.append(om)
    return thetas, omegas


def rollout(theta: np.ndarray, omega: np.ndarray, torque: np.ndarray,
            duration: float = EDGE_DURATION, steps: int = INTEGRATION_STEPS) -> np.ndarray:
    """RK4-integrate a batch of constant-torque edges (:func:`integrate` each); returns states
    (steps, batch, 2). Angles are not wrapped."""
    out = [integrate(th, om, u, duration, steps)
           for th, om, u in zip(np.broadcast_to(theta, np.shape(torque)).tolist(),
                                np.broadcast_to(omega, np.shape(torque)).tolist(),
                                np.asarray(torque, dtype=np.float64).tolist())]
    return np.array(out, dtype=np.float64).reshape(len(out), 2, steps).transpose(2, 0, 1)


def _wrapped(theta: float) -> float:
    """:func:`wrap_angle` of one float (Python's ``%`` is numpy's floor modulo, bit for bit)."""
    return (theta + math.pi) % (2 * math.pi) - math.pi


def _steer_loop(th0: float, om0: float, tth: float, tom: float, controls: np.ndarray, steps: int
                ) -> tuple[int, int, bool, float, float]:
    """:meth:`PendulumProblem.steer`'s arithmetic in one loop, the same operations in the same order
    as :func:`integrate` and the steer's floats (compiled by numba: a steer's dozens of small
    operations cost more in numpy calls than in arithmetic; ``python -m tools.bench_env`` measures
    it, ``tests/test_envs.py`` holds the two to equality).
    Returns ``(best control, checks counted, valid, end angle wrapped, end speed)``."""
    h = EDGE_DURATION / steps
    half, sixth = 0.5 * h, h / 6.0
    a = GRAVITY / LENGTH
    inertia = 1.0 / (MASS * LENGTH ** 2)
    thetas, omegas = np.empty((controls.shape[0], steps)), np.empty((controls.shape[0], steps))
    best, best_d, nan_seen = -1, 0.0, False
    for c in range(controls.shape[0]):
        bu = inertia * controls[c]
        th, om = th0, om0
        for i in range(steps):
            k1t, k1w = om, bu - a * math.sin(th)
            k2t, k2w = om + half * k1w, bu - a * math.sin(th + half * k1t)
            k3t, k3w = om + half * k2w, bu - a * math.sin(th + half * k2t)
            k4t, k4w = om + h * k3w, bu - a * math.sin(th + h * k3t)
            th = th + sixth * (k1t + 2 * k2t + 2 * k3t + k4t)
            om = om + sixth * (k1w + 2 * k2w + 2 * k3w + k4w)
            thetas[c, i], omegas[c, i] = th, om
        dth = ((th - tth + math.pi) % (2 * math.pi) - math.pi) * 1.0
        dom = (om - tom) * VELOCITY_WEIGHT
        d = math.sqrt(dth * dth + dom * dom)
        if d != d:                       # np.argmin's rule: the first NaN, else the first minimum
            if not nan_seen:
                nan_seen, best = True, c
        elif not nan_seen and (best < 0 or d < best_d):
            best, best_d = c, d
    for i in range(steps):                # the kept edge's states, checked in order
        th, om = thetas[best, i], omegas[best, i]
        if not (math.isfinite(th) and math.isfinite(om) and abs(om) <= MAX_SPEED):
            return best, i + 1, False, 0.0, 0.0
    return best, steps, True, (th + math.pi) % (2 * math.pi) - math.pi, om


#: ``_steer_loop`` compiled (numba), or None without numba (the core install: the steer runs in
#: Python floats).
compiled_steer_loop = lazy_njit(_steer_loop)


class PendulumProblem(Problem):
    """Swing the pendulum from ``start`` to within tolerance of ``goal`` with torques of at most
    ``max_torque`` (N m; default :data:`MAX_TORQUE`)."""

    task = "pendulum"
    geometric = False
    control_dim = 1

    def __init__(self, start: np.ndarray, goal: np.ndarray, max_torque: float = MAX_TORQUE) -> None:
        super().__init__(start, goal, low=np.array([-np.pi, -MAX_SPEED]),
                         high=np.array([np.pi, MAX_SPEED]), step_size=EDGE_DURATION,
                         resolution=EDGE_DURATION / INTEGRATION_STEPS)
        # a number, not a string or a bool that float() would take ("0.5", True)
        if isinstance(max_torque, (bool, np.bool_)) or not isinstance(max_torque, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(float(max_torque)) and float(max_torque) > 0):
            raise InvalidProblemError(f"max_torque must be a finite number > 0, got {max_torque!r}")
        self.max_torque = float(max_torque)
        self.start = self.normalize(self.start)
        self.goal = self.normalize(self.goal)
        self._controls = np.linspace(-self.max_torque, self.max_torque, NUM_CONTROLS)
        self._control_list = self._controls.tolist()
        self._goal_floats = self.goal.tolist()
        self._weights = np.array([1.0, VELOCITY_WEIGHT])
        self.nearest_metric = (self._weights, np.array([True, False]))   # distance's metric, for nearest_row
        # theta is periodic; omega's box is far larger than its range, i.e. not periodic.
        self.nn_boxsize = np.array([2 * np.pi, 1e6])

    def normalize(self, x: np.ndarray) -> np.ndarray:
        x = np.array(x, dtype=np.float64, copy=True)
        x[..., 0] = wrap_angle(x[..., 0])
        return x

    def difference(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = np.asarray(a, dtype=np.float64) - b
        d[..., 0] = wrap_angle(d[..., 0])
        return d

    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray:
        d = np.asarray(states, dtype=np.float64) - x      # difference(states, x) * _weights, in place
        angle = d[..., 0]
        angle += np.pi
        np.remainder(angle, 2 * np.pi, out=angle)
        angle -= np.pi
        d *= self._weights
        return np.sqrt(np.einsum("...i,...i->...", d, d))

    def nn_embed(self, states: np.ndarray) -> np.ndarray:
        """``[theta + pi (periodic, 2 pi), VELOCITY_WEIGHT * (omega + 4 MAX_SPEED)]`` (non-negative)."""
        s = np.asarray(states, dtype=np.float64)
        return np.stack([np.mod(s[..., 0] + np.pi, 2 * np.pi),
                         VELOCITY_WEIGHT * (s[..., 1] + 4 * MAX_SPEED)], axis=-1)

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        s = np.asarray(states).reshape(-1, 2)
        return np.isfinite(s).all(axis=1) & (np.abs(s[:, 1]) <= MAX_SPEED)

    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """Integrate every torque of ``_controls``, keep the one whose end state is nearest ``x_to``
        (the first on ties), check its states in order. In plain floats: :meth:`distance` and
        :meth:`is_state_valid`'s answers, bit for bit, without building the five trajectories;
        compiled (:func:`_steer_loop`) when numba is installed, else :meth:`steer_python`."""
        loop = compiled_steer_loop()
        if loop is None:
            return self.steer_python(x_from, x_to)
        th0, om0 = x_from.tolist()
        tth, tom = x_to.tolist()
        best, checks, valid, th, om = loop(th0, om0, tth, tom, self._controls, INTEGRATION_STEPS)
        self.edges_checked += 1
        self.collision_checks += checks
        if not valid:
            return None
        return Edge(np.array([th, om]), EDGE_DURATION, np.array([self._control_list[best]]))

    def steer_python(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """:meth:`steer` in Python floats through :func:`integrate` (no numba; the tests' oracle)."""
        th0, om0 = x_from.tolist()
        tth, tom = x_to.tolist()
        w = VELOCITY_WEIGHT
        trajs, dists = [], []
        for u in self._control_list:
            thetas, omegas = integrate(th0, om0, u)
            dth = _wrapped(thetas[-1] - tth) * 1.0         # difference(ends, x_to) * _weights
            dom = (omegas[-1] - tom) * w
            trajs.append((thetas, omegas))
            dists.append(math.sqrt(dth * dth + dom * dom))
        nans = [c for c, d in enumerate(dists) if d != d]
        best = nans[0] if nans else dists.index(min(dists))     # np.argmin: the first NaN, else the first minimum
        thetas, omegas = trajs[best]
        self.edges_checked += 1
        isfinite = math.isfinite
        for i, (th, om) in enumerate(zip(thetas, omegas)):
            if not (isfinite(th) and isfinite(om) and abs(om) <= MAX_SPEED):
                self.collision_checks += i + 1
                return None
        self.collision_checks += len(thetas)
        return Edge(np.array([_wrapped(thetas[-1]), omegas[-1]]), EDGE_DURATION, np.array([self._control_list[best]]))

    def edge_valid(self, x_from: np.ndarray, x_to: np.ndarray, control: np.ndarray) -> bool:
        """Re-integrate the stored torque and check every state and the arrival point."""
        self.edges_checked += 1
        states = rollout(x_from[0], x_from[1], np.asarray(control, dtype=np.float64).reshape(1))[:, 0]
        self.collision_checks += len(states)
        arrived = np.allclose(self.difference(self.normalize(states[-1]), x_to), 0.0, atol=1e-6)
        return bool(arrived and self.is_state_valid(states).all())

    def in_goal(self, x: np.ndarray) -> bool:
        theta, omega = x.tolist()       # difference(x, goal) in floats
        return (abs(_wrapped(theta - self._goal_floats[0])) <= GOAL_ANGLE_TOLERANCE
                and abs(omega - self._goal_floats[1]) <= GOAL_SPEED_TOLERANCE)


#: Scene families: parameter ranges of the problem generator (angles in rad, velocities in
#: rad/s, torque in units of ``m g l``). ``angle_offset``: the goal angle is ``pi`` plus a draw
#: from it, with a random sign; ``goal_angle``: the goal angle itself, with a random sign;
#: ``start_angle`` / ``start_speed`` likewise (speed signs random). Roles as the maze2d scenes':
#: ``upright`` is the default (every split), ``mixed`` the training domain randomisation,
#: ``far-goal`` and ``lively`` validation kinds held out from training, the rest OOD test kinds.
SCENE_FAMILIES: dict[str, dict[str, Any]] = {
    "upright": {"role": "default"},
    "mixed": {"role": "train", "angle_offset": (0.0, 0.8), "goal_speed": (0.0, 1.5), "start_angle": (0.0, 0.5),
              "start_speed": (0.0, 1.0), "torque": (0.15, 0.3)},
    "far-goal": {"role": "val", "angle_offset": (0.8, 1.05)},
    "lively": {"role": "val", "start_angle": (0.5, 1.5), "start_speed": (1.0, 2.0), "torque": (0.3, 0.35)},
    "side-goal": {"role": "ood", "goal_angle": (1.2, 2.2)},
    "fast-goal": {"role": "ood", "goal_speed": (2.5, 4.5)},
    "moving-start": {"role": "ood", "start_angle": (0.0, np.pi), "start_speed": (2.0, 5.0)},
    "weak": {"role": "ood", "torque": (0.1, 0.13)},
    "strong": {"role": "ood", "torque": (0.4, 0.6)},
    "hang": {"role": "ood", "start_angle": (np.pi - 0.3, np.pi), "goal_angle": (0.0, 0.3), "goal_speed": (0.0, 0.5)},
}


class PendulumTask(Task):
    """Start hanging at rest; goal near upright with a small velocity, drawn per seed.

    Goal angle ``pi + U(-0.5, 0.5)`` (wrapped), goal velocity ``U(-1, 1)`` rad/s: the
    ``upright`` scene (the default). Other scenes (:data:`SCENE_FAMILIES`) draw other goals,
    moving starts and torque limits.
    """

    name = "pendulum"
    planners = ("rrt",)

    def __init__(self, scene: str = "upright") -> None:
        if scene not in SCENE_FAMILIES:
            raise ValueError(f"unknown pendulum scene {scene!r}; known: {', '.join(SCENE_FAMILIES)}")
        self.scene = scene

    def sample_problem(self, rng: np.random.Generator) -> PendulumProblem:
        if self.scene == "upright":
            goal = np.array([np.pi + rng.uniform(-0.5, 0.5), rng.uniform(-1.0, 1.0)])
            return PendulumProblem(np.zeros(2), goal)
        f = SCENE_FAMILIES[self.scene]

        def signed(r: tuple[float, float]) -> float:
            return float(rng.uniform(*r)) * (1.0 if rng.random() < 0.5 else -1.0)

        if "goal_angle" in f:
            goal_angle = signed(f["goal_angle"])
        else:
            goal_angle = np.pi + signed(f.get("angle_offset", (0.0, 0.5)))
        goal = np.array([goal_angle, signed(f.get("goal_speed", (0.0, 1.0)))])
        start = np.array([signed(f.get("start_angle", (0.0, 0.0))), signed(f.get("start_speed", (0.0, 0.0)))])
        torque = float(rng.uniform(*f.get("torque", (0.2, 0.2)))) * MASS * GRAVITY * LENGTH
        return PendulumProblem(start, goal, torque)

    def make_problem(self, spec: Any) -> Problem:
        if isinstance(spec, dict):
            check_keys(spec, ("start", "goal", "max_torque"), "a pendulum problem dict")
            try:
                spec = PendulumProblem(spec.get("start", np.zeros(2)), spec["goal"],
                                       spec.get("max_torque", MAX_TORQUE))
            except KeyError:
                raise InvalidProblemError("a pendulum problem dict needs a 'goal'") from None
        return super().make_problem(spec)

    def render_rgb(self, problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
        return render_pendulum(problem, tree, path)


def render_pendulum(problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
    """The tree in phase space (theta, omega), the goal box and the path."""
    from matplotlib.patches import Rectangle
    fig, ax = figure()
    draw_tree(ax, tree, wrap_period=2 * np.pi)
    g = problem.goal
    ax.add_patch(Rectangle((g[0] - GOAL_ANGLE_TOLERANCE, g[1] - GOAL_SPEED_TOLERANCE),
                           2 * GOAL_ANGLE_TOLERANCE, 2 * GOAL_SPEED_TOLERANCE,
                           color="tab:red", alpha=0.3))
    if path is not None:
        jumps = np.flatnonzero(np.abs(np.diff(path[:, 0])) > np.pi) + 1
        for piece in np.split(path, jumps):
            ax.plot(piece[:, 0], piece[:, 1], color="m", linewidth=2.0)
    ax.plot(*problem.start, "o", color="tab:green", markersize=8)
    ax.plot(*g, "*", color="tab:red", markersize=12)
    ax.set_xlim(-np.pi, np.pi)
    ax.set_ylim(-MAX_SPEED, MAX_SPEED)
    ax.set_xlabel("theta [rad]")
    ax.set_ylabel("omega [rad/s]")
    fig.tight_layout()
    return to_rgb(fig)
