"""The pendulum's OMPL control-space setup: what ``gnn-mp benchmark --samplers ompl-rrt,ompl-kpiece``
plans the pendulum with.

Named by the pendulum's ``TaskSpec.ompl_control_setup`` and imported only by the OMPL runner
(:mod:`gnn_mp_envs.baselines.ompl_runner`, an isolated subprocess): OMPL is imported inside
:func:`pendulum_setup`, and neither the pendulum task nor the environments import this module.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.baselines.ompl_runner import CONTROL_PLANNERS, OMPLSetup
from gnn_mp_envs.tasks.pendulum import task as pend


#: KPIECE1's projection of a pendulum state is (theta, omega); these are its grid cell sizes
#: (rad, rad/s): ~31 x 32 cells over [-pi, pi) x [-MAX_SPEED, MAX_SPEED].
PENDULUM_CELL_SIZES = (0.2, 0.5)
#: Threshold of the pendulum goal region and the smallest distance reported outside it, so
#: OMPL's ``distanceGoal(s) < threshold`` holds exactly when ``problem.in_goal(s)`` does.
GOAL_THRESHOLD, GOAL_MIN_OUTSIDE = 1e-9, 1e-6


def pendulum_setup(problem: Any, planner: str) -> OMPLSetup:
    """Control-based SimpleSetup for :class:`~gnn_mp_envs.tasks.pendulum.PendulumProblem`.

    * State space SO(2) x R (weights 1 and ``VELOCITY_WEIGHT``, as our distance), omega
      bounded by +-``MAX_SPEED``; SO(2) wraps theta to [-pi, pi) like ``wrap_angle``.
    * Control space R^1, torque bounded by +- the problem's ``max_torque``.
    * Propagation step ``EDGE_DURATION / INTEGRATION_STEPS`` (0.02 s) and control durations
      of exactly ``INTEGRATION_STEPS`` steps: every edge is one constant torque held for
      ``EDGE_DURATION`` (0.2 s), integrated with ``pendulum.rollout`` (RK4, the same 0.02 s
      step), and OMPL checks every 0.02 s state with ``problem.check_state``, as our steer
      does. (KPIECE1 splits an edge where it crosses projection cells, so its paths have
      shorter pieces, and it checks the goal at each piece's end.)
    * Goal: a ``GoalSampleableRegion`` whose ``distanceGoal`` is 0 inside the
      ``in_goal`` box and at least ``GOAL_MIN_OUTSIDE`` outside; samples are uniform in the
      box (used by the planners' default 5% goal bias).
    """
    from ompl import base as ob
    from ompl import control as oc
    from ompl import util as ou

    if planner not in CONTROL_PLANNERS:
        raise ValueError(f"OMPL planner {planner!r} is geometric-only; the {problem.task!r} problem is "
                         f"kinodynamic (control planners: {sorted(CONTROL_PLANNERS)})")
    dt = pend.EDGE_DURATION / pend.INTEGRATION_STEPS
    space = ob.CompoundStateSpace()
    theta_space, omega_space = ob.SO2StateSpace(), ob.RealVectorStateSpace(1)
    omega_bounds = ob.RealVectorBounds(1)
    omega_bounds.setLow(-pend.MAX_SPEED)
    omega_bounds.setHigh(pend.MAX_SPEED)
    omega_space.setBounds(omega_bounds)
    space.addSubspace(theta_space, 1.0)
    space.addSubspace(omega_space, pend.VELOCITY_WEIGHT)

    class PendulumProjection(ob.ProjectionEvaluator):
        """(theta, omega) on a grid of ``PENDULUM_CELL_SIZES`` (KPIECE1's discretisation)."""

        def getDimension(self) -> int:
            return 2

        def defaultCellSizes(self) -> None:
            sizes = ou.vectorDouble()
            for c in PENDULUM_CELL_SIZES:
                sizes.append(float(c))
            self.setCellSizes(sizes)

        def project(self, s: Any, projection: Any) -> None:
            projection[0] = s[0].value
            projection[1] = s[1][0]

    projection = PendulumProjection(space)
    space.registerDefaultProjection(projection)

    cspace = oc.RealVectorControlSpace(space, 1)
    torque_bounds = ob.RealVectorBounds(1)
    torque_bounds.setLow(-problem.max_torque)
    torque_bounds.setHigh(problem.max_torque)
    cspace.setBounds(torque_bounds)
    ss = oc.SimpleSetup(cspace)
    si = ss.getSpaceInformation()

    def as_array(s: Any) -> np.ndarray:
        return np.array([s[0].value, s[1][0]], dtype=np.float64)

    checker = ob.StateValidityCheckerFn(lambda s: problem.check_state(as_array(s)))
    ss.setStateValidityChecker(checker)

    # Edges = runs of propagation steps continuing from the previous result with the same torque.
    counter = {"edges": 0, "steps": 0, "run": 0, "last": None}

    def propagate(start: Any, control: Any, duration: float, result: Any) -> None:
        th, om, u = start[0].value, start[1][0], control[0]
        if counter["last"] != (th, om, u) or counter["run"] >= pend.INTEGRATION_STEPS:
            counter["edges"] += 1
            counter["run"] = 0
        steps = max(1, int(round(duration / dt)))
        x = pend.rollout(th, om, np.array([u]), duration, steps)[-1, 0]
        th_new, om_new = float(pend.wrap_angle(x[0])), float(x[1])
        result[0].value = th_new
        result[1][0] = om_new
        counter["steps"] += steps
        counter["run"] += steps
        counter["last"] = (th_new, om_new, u)

    propagator = oc.StatePropagatorFn(propagate)
    ss.setStatePropagator(propagator)
    si.setPropagationStepSize(dt)
    si.setMinMaxControlDuration(pend.INTEGRATION_STEPS, pend.INTEGRATION_STEPS)

    tolerance = np.array([pend.GOAL_ANGLE_TOLERANCE, pend.GOAL_SPEED_TOLERANCE])
    weights = np.array([1.0, pend.VELOCITY_WEIGHT])

    class PendulumGoal(ob.GoalSampleableRegion):
        """Satisfied exactly when ``problem.in_goal`` holds; samples uniformly in the goal box."""

        def __init__(self, si: Any) -> None:
            super().__init__(si)
            self.setThreshold(GOAL_THRESHOLD)
            self.rng = ou.RNG()

        def distanceGoal(self, s: Any) -> float:
            x = as_array(s)
            if problem.in_goal(x):
                return 0.0
            excess = np.maximum(np.abs(problem.difference(x, problem.goal)) - tolerance, 0.0) * weights
            return max(float(np.hypot(excess[0], excess[1])), GOAL_MIN_OUTSIDE)

        def sampleGoal(self, s: Any) -> None:
            th = problem.goal[0] + self.rng.uniformReal(-tolerance[0], tolerance[0])
            om = problem.goal[1] + self.rng.uniformReal(-tolerance[1], tolerance[1])
            s[0].value = float(pend.wrap_angle(th))
            s[1][0] = float(np.clip(om, -pend.MAX_SPEED, pend.MAX_SPEED))

        def maxSampleCount(self) -> int:
            return 2 ** 31 - 1

    goal = PendulumGoal(si)
    start = ob.State(space)
    start()[0].value = float(problem.start[0])
    start()[1][0] = float(problem.start[1])
    ss.setStartState(start)
    ss.setGoal(goal)
    plan = getattr(oc, CONTROL_PLANNERS[planner])(si)
    if planner == "kpiece":
        plan.setProjectionEvaluator(projection)
    ss.setPlanner(plan)

    def path_result(path: Any) -> dict[str, Any]:
        n = path.getStateCount()
        states = np.array([as_array(path.getState(k)) for k in range(n)])
        controls = np.array([path.getControl(k)[0] for k in range(path.getControlCount())], dtype=np.float64)
        durations = np.array([path.getControlDuration(k) for k in range(path.getControlCount())],
                             dtype=np.float64)
        return {"path_length": float(durations.sum()), "path": states.tolist(), "path_states": int(n),
                "controls": controls.tolist(), "durations": durations.tolist(),
                "goal_reached": bool(problem.in_goal(states[-1])),
                "path_valid": _control_path_valid(problem, states, controls, durations, dt)}

    def reset() -> None:
        counter.update(edges=0, steps=0, run=0, last=None)

    return OMPLSetup(ss, plan, f"control_{CONTROL_PLANNERS[planner]}", path_result,
                  lambda: {"edges_checked": counter["edges"], "propagation_steps": counter["steps"]}, reset,
                  [checker, propagator, projection, goal, as_array, propagate, space, cspace, start, counter])


def _control_path_valid(problem: Any, states: np.ndarray, controls: np.ndarray, durations: np.ndarray,
                        dt: float) -> bool:
    """Re-simulate a control path with the task's dynamics (uncounted): starts at the start,
    every edge arrives at the next state, every integrated state is valid, ends in the goal."""
    if len(states) < 1 or len(controls) != len(states) - 1 or not problem.in_goal(states[-1]):
        return False
    if not np.allclose(problem.difference(states[0], problem.start), 0.0, atol=1e-9):
        return False
    for i, (u, duration) in enumerate(zip(controls, durations)):
        steps = max(1, int(round(duration / dt)))
        traj = pend.rollout(states[i, 0], states[i, 1], np.array([u]), float(duration), steps)[:, 0]
        if not problem.is_state_valid(traj).all():
            return False
        if not np.allclose(problem.difference(problem.normalize(traj[-1]), states[i + 1]), 0.0, atol=1e-6):
            return False
    return True


__all__ = ["GOAL_MIN_OUTSIDE", "GOAL_THRESHOLD", "PENDULUM_CELL_SIZES", "pendulum_setup"]
