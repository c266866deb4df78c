"""gnn-mp-envs: sampling-based motion planning as Gymnasium environments.

Importing the package registers ``GNNMP/Maze2DRRT-v0``, ``GNNMP/Maze2DBiRRT-v0``,
``GNNMP/PendulumRRT-v0`` and ``GNNMP/ArmBiRRT-v0`` (see :mod:`gnn_mp_envs.registration`,
where tasks defined elsewhere register too). This package never imports torch, ``agents``
or ``train``; learned samplers live in ``agents``.
"""

from gnn_mp_envs.registration import TASK_SPECS, TaskSpec, make_task, register_envs, register_task, task_spec

__version__ = "0.1.0"

register_envs()

__all__ = ["TASK_SPECS", "TaskSpec", "make_task", "register_envs", "register_task", "task_spec", "__version__"]
