"""Robots: the floor under every robot task (the xArm6's ``arm``, MotionBenchMaker's ``panda-mbm``,
``ur5-mbm`` and ``fetch-mbm``). It imports no task.

- :mod:`~gnn_mp_envs.robots.geometry`: obstacles, end-effector targets, scenes, quaternions;
- :mod:`~gnn_mp_envs.robots.model` and :mod:`~gnn_mp_envs.robots.catalog`: :class:`RobotModel` and the
  robots (``models/<robot>/``: URDFs, collision meshes, sphere models, licences);
- :mod:`~gnn_mp_envs.robots.urdf`: a robot's kinematic tree and collision geometry from its URDF;
- :mod:`~gnn_mp_envs.robots.world`: :class:`RobotWorld`, the pybullet simulator and exact collision check;
- :mod:`~gnn_mp_envs.robots.checkers`: the :class:`Checker` protocol, :data:`CHECKERS` by name, the
  pybullet checker; :mod:`~gnn_mp_envs.robots.spheres`: the compiled sphere checker;
- :mod:`~gnn_mp_envs.robots.problem`: :class:`JointSpaceProblem`, a robot's planning problem in one scene;
- :mod:`~gnn_mp_envs.robots.render`: images of a problem and its tree.
"""

from gnn_mp_envs.robots.catalog import ROBOTS, XARM6, robot_model
from gnn_mp_envs.robots.checkers import CHECKERS, Checker, PybulletChecker, checker_name, make_checker
from gnn_mp_envs.robots.geometry import EndEffectorTarget, Obstacle, Scene, tool_quaternion
from gnn_mp_envs.robots.model import RobotModel
from gnn_mp_envs.robots.problem import RESOLUTION, JointSpaceProblem
from gnn_mp_envs.robots.render import CAMERA, render_robot
from gnn_mp_envs.robots.world import CONTACT_DISTANCE, RobotWorld

__all__ = ["CAMERA", "CHECKERS", "CONTACT_DISTANCE", "Checker", "EndEffectorTarget", "JointSpaceProblem", "Obstacle",
           "PybulletChecker", "RESOLUTION", "ROBOTS", "RobotModel", "RobotWorld", "Scene", "XARM6", "checker_name",
           "make_checker", "render_robot", "robot_model", "tool_quaternion"]
