"""MotionBenchMaker (Chamzas et al., RA-L 2022) on a Franka Panda: the field's standard
manipulation problems, planned in joint space with BiRRT (or RRT) as the task ``panda-mbm``.

Seven scenes of 100 problems each (``table_pick``, ``table_under_pick``, ``box``,
``bookshelf_small``, ``bookshelf_tall``, ``bookshelf_thin``, ``cage``), shipped as
``dataset/panda_problems.json`` (source, commit, licences and the regenerate command in
``dataset/README.md``). The robot is pybullet_data's Panda with MotionBenchMaker's facts: its URDF's
joint limits, fingers held at 6.5 cm, and the allowed-collision matrix of the scenes; the UR5 and the
Fetch (``ur5-mbm``, ``fetch-mbm``) likewise. The robots, their world and checkers are
:mod:`gnn_mp_envs.robots`'. See docs/mbm.md.

Modules: :mod:`~gnn_mp_envs.tasks.mbm.data` (the shipped problems),
:mod:`~gnn_mp_envs.tasks.mbm.task` (scenes, splits, perturbed training problems).
"""

from gnn_mp_envs.tasks.mbm.data import SCENES, MBMRecord, scene_records
from gnn_mp_envs.tasks.mbm.task import (
    EXCLUDED,
    HELD_OUT_SCENES,
    RESOLUTION,
    SCENE_SETS,
    SPLIT_POSITIONS,
    STEP_SIZE,
    TRAIN_SCENES,
    FetchMBMTask,
    MBMProblem,
    MBMTask,
    PandaMBMTask,
    UR5MBMTask,
)

__all__ = ["EXCLUDED", "HELD_OUT_SCENES", "RESOLUTION", "SCENES", "SCENE_SETS", "SPLIT_POSITIONS", "STEP_SIZE",
           "TRAIN_SCENES", "FetchMBMTask", "MBMProblem", "MBMRecord", "MBMTask", "PandaMBMTask", "UR5MBMTask",
           "scene_records"]
