"""gnn-mp-envs: sampling-based motion planning as Gymnasium environments.

Importing the package registers ``GNNMP/Maze2DRRT-v0``, ``GNNMP/Maze2DBiRRT-v0``,
``GNNMP/PendulumRRT-v0`` and ``GNNMP/ArmBiRRT-v0``. This package never imports torch;
learned samplers live in ``agents``.
"""

from gnn_mp_envs.registration import ENVIRONMENTS, TASK_ENV_IDS, register_envs

__version__ = "0.1.0"

register_envs()

__all__ = ["ENVIRONMENTS", "TASK_ENV_IDS", "register_envs", "__version__"]
