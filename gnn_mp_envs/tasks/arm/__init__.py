"""Arm: the seed paper's 6-DoF xArm6 on a table, planned in joint space with BiRRT (or RRT).

Each :class:`ArmTask` owns one :class:`~gnn_mp_envs.robots.world.RobotWorld` (a pybullet client in
``DIRECT`` mode, created in the constructor, disconnected by :meth:`ArmTask.close`) holding the robot
(:data:`~gnn_mp_envs.robots.catalog.XARM6`: ``xarm/xarm6_robot.urdf`` from ``pybullet_data``, fixed base
at the origin on the table top), the table and the obstacle bodies of the current scene.

Validity of a configuration: within the joint limits, no contact with the table or an obstacle, no
self-collision (adjacent links excluded), by the task's collision checker
(:mod:`gnn_mp_envs.robots.checkers`). Each configuration checked counts one collision check; edges
are interpolated every :data:`RESOLUTION` rad and stop at the first invalid configuration.

Problems come from the scene families of :mod:`gnn_mp_envs.tasks.arm.scenes`; goals are
inverse-kinematics solutions that put the tool inside the crevice / shelf / cubby, starts
are tool-down poses on the far side of the robot, and a problem whose straight joint-space
segment from start to goal is collision-free is rejected and redrawn.
"""

from gnn_mp_envs.tasks.arm.scenes import LAYOUTS, SCENE_FAMILIES, register_scene_family, sample_scene
from gnn_mp_envs.tasks.arm.task import RESOLUTION, STEP_SIZE, TRAIN_FAMILIES, ArmProblem, ArmTask, xarm6_ik

__all__ = ["LAYOUTS", "RESOLUTION", "SCENE_FAMILIES", "STEP_SIZE", "TRAIN_FAMILIES", "ArmProblem",
           "ArmTask", "register_scene_family", "sample_scene", "xarm6_ik"]
