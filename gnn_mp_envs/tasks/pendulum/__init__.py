"""Pendulum: a torque-limited swing-up planned with kinodynamic RRT.

Modules: :mod:`~gnn_mp_envs.tasks.pendulum.task` (the dynamics, the problem, the family and its
scene families), :mod:`~gnn_mp_envs.tasks.pendulum.ompl_setup` (OMPL's control-space setup, imported
only by the OMPL runner's subprocess, never here).
"""

from gnn_mp_envs.tasks.pendulum.task import (
    EDGE_DURATION,
    GOAL_ANGLE_TOLERANCE,
    GOAL_SPEED_TOLERANCE,
    GRAVITY,
    INTEGRATION_STEPS,
    LENGTH,
    MASS,
    MAX_SPEED,
    MAX_TORQUE,
    NUM_CONTROLS,
    SCENE_FAMILIES,
    VELOCITY_WEIGHT,
    PendulumProblem,
    PendulumTask,
    compiled_steer_loop,
    integrate,
    render_pendulum,
    rollout,
    wrap_angle,
)

__all__ = ["EDGE_DURATION", "GOAL_ANGLE_TOLERANCE", "GOAL_SPEED_TOLERANCE", "GRAVITY", "INTEGRATION_STEPS", "LENGTH",
           "MASS", "MAX_SPEED", "MAX_TORQUE", "NUM_CONTROLS", "SCENE_FAMILIES", "VELOCITY_WEIGHT", "PendulumProblem",
           "PendulumTask", "compiled_steer_loop", "integrate", "render_pendulum", "rollout", "wrap_angle"]
