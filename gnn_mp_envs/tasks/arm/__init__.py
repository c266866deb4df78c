"""Arm: a 6-DoF xArm6 on a table, planned in joint space with BiRRT (or RRT).

Each :class:`ArmTask` owns one pybullet client in ``DIRECT`` mode (created in the
constructor, disconnected by :meth:`ArmTask.close`) holding the robot
(``xarm/xarm6_robot.urdf`` from ``pybullet_data``, fixed base at the origin on the
table top), the table and the obstacle bodies of the current scene.

Validity of a configuration (:mod:`~gnn_mp_envs.tasks.arm.world`): within the joint limits, no
contact with the table or an obstacle, no self-collision (adjacent links excluded). Each
configuration checked counts one collision check; edges are interpolated every
:data:`RESOLUTION` rad (joint-space L2) and stop at the first invalid configuration.

Problems come from the scene families of :mod:`gnn_mp_envs.tasks.arm.scenes`; goals are
inverse-kinematics solutions that put the tool inside the crevice / shelf / cubby, starts
are tool-down poses on the far side of the robot, and a problem whose straight joint-space
segment from start to goal is collision-free is rejected and redrawn.

Modules: :mod:`~gnn_mp_envs.tasks.arm.world` (the pybullet client and collision check),
:mod:`~gnn_mp_envs.tasks.arm.problem` (joint-space problems), :mod:`~gnn_mp_envs.tasks.arm.task`
(the family), :mod:`~gnn_mp_envs.tasks.arm.render` (images), :mod:`~gnn_mp_envs.tasks.arm.scenes`
(scene families as data; :func:`register_scene_family` adds one by name).
"""

from gnn_mp_envs.tasks.arm.problem import RESOLUTION, STEP_SIZE, ArmProblem
from gnn_mp_envs.tasks.arm.render import CAMERA, render_arm
from gnn_mp_envs.tasks.arm.scenes import (LAYOUTS, SCENE_FAMILIES, EndEffectorTarget, Obstacle, Scene,
                                          register_scene_family, sample_scene)
from gnn_mp_envs.tasks.arm.task import TRAIN_FAMILIES, ArmTask
from gnn_mp_envs.tasks.arm.world import EE_LINK, JOINT_HIGH, JOINT_LOW, JOINTS, ArmWorld, tool_quaternion

__all__ = ["CAMERA", "EE_LINK", "JOINTS", "JOINT_HIGH", "JOINT_LOW", "LAYOUTS", "RESOLUTION", "SCENE_FAMILIES",
           "STEP_SIZE", "TRAIN_FAMILIES", "ArmProblem", "ArmTask", "ArmWorld", "EndEffectorTarget",
           "Obstacle", "Scene", "register_scene_family", "render_arm", "sample_scene", "tool_quaternion"]
