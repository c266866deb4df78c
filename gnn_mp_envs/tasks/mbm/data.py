"""MotionBenchMaker's Panda problems as shipped in ``dataset/panda_problems.json`` (made by
``tools/mbm_convert.py`` from VAMP's copy of the problems; source, commit and licences in
``dataset/README.md``), and the Panda :class:`~gnn_mp_envs.tasks.arm.world.RobotModel` they are planned with.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from gnn_mp_envs.tasks.arm.scenes import Obstacle
from gnn_mp_envs.tasks.arm.world import RobotModel

DATA_FILE = Path(__file__).resolve().parent / "dataset" / "panda_problems.json"
#: The seven Panda scenes, in MotionBenchMaker's order.
SCENES = ("table_pick", "table_under_pick", "box", "bookshelf_small", "bookshelf_tall", "bookshelf_thin", "cage")
#: pybullet_data's ``franka_panda/panda.urdf``: the same collision meshes as MotionBenchMaker's
#: Panda (robowflex_resources, via VAMP: identical files); pybullet collides their convex hulls.
PANDA_URDF = "franka_panda/panda.urdf"
#: pybullet joint indices of panda_joint1..7 and of the two finger joints; the flange link
#: (``panda_hand``). tests/test_mbm.py checks the names behind these indices.
PANDA_JOINTS = (0, 1, 2, 3, 4, 5, 6)
PANDA_FINGERS = {"panda_finger_joint1": 9, "panda_finger_joint2": 10}
PANDA_HAND = 8
#: The planner's safety margin (m): contacts closer than this count as collisions, so that edges
#: checked every RESOLUTION rad do not graze obstacles between their checked states (docs/mbm.md); the
#: independent path check uses none. pybullet reports positive-distance contacts only up to about
#: 1 mm (for a box against the hand's hull), which bounds the margin; every MBM start and goal keeps
#: at least 1.94 mm.
PANDA_PADDING = 0.001


@dataclass(frozen=True)
class MBMRecord:
    """One MotionBenchMaker problem as shipped: scene, file number (``sceneNNNN.yaml``), start,
    goal (7 joint angles each) and the scene's obstacles."""

    scene: str
    file: int
    start: tuple[float, ...]
    goal: tuple[float, ...]
    obstacles: tuple[Obstacle, ...]


def obstacle(kind: str, dimensions: list[float], pose: list[float]) -> Obstacle:
    """An :class:`Obstacle` from a MoveIt primitive (box: full lengths; cylinder: height, radius;
    sphere: radius) and a pose ``[x, y, z, qx, qy, qz, qw]``."""
    if kind == "box":
        size = tuple(d / 2 for d in dimensions)
    elif kind == "cylinder":
        size = (dimensions[1], dimensions[0])
    else:
        size = (dimensions[0],)
    return Obstacle(kind, size, tuple(pose[:3]), orientation=tuple(pose[3:]))


@lru_cache(maxsize=1)
def load_document(path: Path = DATA_FILE) -> dict[str, Any]:
    """The shipped JSON document (read once per process)."""
    if not path.exists():
        raise FileNotFoundError(f"the MotionBenchMaker data file {path} is missing: reinstall gnn-mp-envs "
                                "or regenerate it with `python -m tools.mbm_convert` (see dataset/README.md)")
    return json.loads(path.read_text())


@lru_cache(maxsize=None)
def scene_records(scene: str) -> tuple[MBMRecord, ...]:
    """The scene's 100 problems, in file order."""
    if scene not in SCENES:
        raise ValueError(f"unknown MotionBenchMaker scene {scene!r}; known: {', '.join(SCENES)}")
    data = load_document()["scenes"][scene]
    layout = data["objects"]
    return tuple(MBMRecord(scene, int(p["file"]), tuple(p["start"]), tuple(p["goal"]),
                           tuple(obstacle(kind, dims, pose) for (_, kind, dims), pose in zip(layout, p["poses"])))
                 for p in data["problems"])


@lru_cache(maxsize=1)
def panda_model() -> RobotModel:
    """The Panda as MotionBenchMaker plans it: its URDF's joint limits, fingers held open at the
    problems' 6.5 cm each, and self-collision off for the link pairs of the scenes' allowed-collision
    matrix (= the SRDF's disabled pairs); plus the planner's 1 mm safety margin."""
    robot = load_document()["robot"]
    held = tuple((PANDA_FINGERS[name], float(v)) for name, v in robot["held_joints"].items())
    return RobotModel(PANDA_URDF, PANDA_JOINTS, tuple(robot["lower"]), tuple(robot["upper"]), PANDA_HAND,
                      held_joints=held, allowed_collisions=tuple(tuple(p) for p in robot["allowed_collisions"]),
                      padding=PANDA_PADDING, table=False)
