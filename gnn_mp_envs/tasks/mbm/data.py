"""MotionBenchMaker's Panda, UR5 and Fetch problems as shipped in ``dataset/<robot>_problems.json``
(made by ``tools/mbm_convert.py`` from VAMP's copy of the problems; source, commit and licences in
``dataset/README.md``). The robots themselves are :mod:`gnn_mp_envs.robots.catalog`'s.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from gnn_mp_envs.robots.geometry import Obstacle

DATA_FILE = Path(__file__).resolve().parent / "dataset" / "panda_problems.json"
#: The robots whose MotionBenchMaker problems ship, and their data files.
ROBOTS = ("panda", "ur5", "fetch")
DATA_FILES = {robot: DATA_FILE.with_name(f"{robot}_problems.json") for robot in ROBOTS}
#: The seven Panda scenes, in MotionBenchMaker's order (the UR5's and the Fetch's are the same seven).
SCENES = ("table_pick", "table_under_pick", "box", "bookshelf_small", "bookshelf_tall", "bookshelf_thin", "cage")
#: Problems whose start or goal is invalid under the shipped model (out of the joint limits, or a
#: contact within the 1 mm padding), as ``robot -> {(scene, file): why}`` (contacts: the link pairs
#: and their pybullet distance). Measured over all 700 of each robot with pybullet 3.2.7;
#: tests/test_mbm_robots.py re-checks that exactly these are invalid. The Panda has none (see
#: ``task.EXCLUDED``); the UR5's are contacts closer than 1 mm; the Fetch's come from VAMP's coarser
#: collision shapes (the 0.2 m head sphere, the torso's added sphere, its convex base) and contacts
#: closer than 1 mm (see gnn_mp_envs/robots/models/fetch/README.md).
INVALID_PROBLEMS: dict[str, dict[tuple[str, int], str]] = {
    "panda": {},
    "ur5": {
        ("bookshelf_small", 22): "goal: wrist_3_link-forearm_link -0.2 mm",
        ("bookshelf_tall", 20): "goal: wrist_2_link-forearm_link +0.6 mm",
        ("bookshelf_tall", 58): "goal: wrist_2_link-forearm_link +0.3 mm",
        ("bookshelf_tall", 75): "goal: robotiq_85_right_finger_tip_link-obstacle +0.9 mm",
        ("bookshelf_tall", 92): "goal: wrist_2_link-forearm_link -0.9 mm",
        ("bookshelf_tall", 97): "goal: wrist_2_link-forearm_link +0.5 mm",
    },
    "fetch": {
        ("table_pick", 36): "goal: head_pan_link-upperarm_roll_link +0.8 mm",
        ("table_pick", 56): "goal: head_pan_link-upperarm_roll_link -2.1 mm",
        ("table_pick", 70): "goal: head_pan_link-upperarm_roll_link -5.4 mm",
        ("table_pick", 96): "goal: torso_lift_link_collision_2-shoulder_lift_link -0.1 mm",
        ("table_under_pick", 1): "goal: torso_lift_link_collision_2-shoulder_lift_link +0.9 mm, "
                                 "torso_lift_link_collision_2-upperarm_roll_link +1.0 mm",
        ("table_under_pick", 5): "start: torso_lift_link_collision_2-shoulder_lift_link -9.3 mm, "
                                 "torso_lift_link_collision_2-upperarm_roll_link -7.1 mm",
        ("table_under_pick", 8): "goal: torso_lift_link_collision_2-shoulder_lift_link -3.2 mm, "
                                 "torso_lift_link_collision_2-upperarm_roll_link -1.4 mm",
        ("table_under_pick", 11): "start: base_link-forearm_roll_link -1.6 mm",
        ("table_under_pick", 18): "start: torso_lift_link_collision_2-shoulder_lift_link -6.8 mm, "
                                  "torso_lift_link_collision_2-upperarm_roll_link -3.8 mm",
        ("table_under_pick", 48): "start: base_link-forearm_roll_link +0.8 mm; "
                                  "goal: torso_lift_link_collision_2-shoulder_lift_link +0.1 mm, "
                                  "torso_lift_link_collision_2-upperarm_roll_link +0.5 mm",
        ("table_under_pick", 60): "start: base_link-wrist_flex_link -1.6 mm, base_link-forearm_roll_link -0.1 mm",
        ("table_under_pick", 64): "start: base_link-elbow_flex_link +0.6 mm",
        ("bookshelf_small", 38): "goal: head_pan_link-upperarm_roll_link -3.9 mm",
        ("bookshelf_small", 45): "goal: head_pan_link-upperarm_roll_link +0.9 mm",
        ("bookshelf_small", 50): "goal: wrist_flex_link-obstacle +0.1 mm",
        ("bookshelf_small", 77): "goal: head_pan_link-upperarm_roll_link -0.8 mm, "
                                 "head_pan_link-elbow_flex_link -0.7 mm",
        ("bookshelf_small", 81): "goal: head_pan_link-upperarm_roll_link -29.7 mm",
        ("bookshelf_small", 84): "goal: head_pan_link-upperarm_roll_link -17.4 mm",
        ("bookshelf_small", 88): "goal: head_pan_link-upperarm_roll_link -19.0 mm",
        ("bookshelf_small", 91): "goal: head_pan_link-upperarm_roll_link -0.4 mm",
        ("bookshelf_small", 96): "goal: head_pan_link-upperarm_roll_link +0.3 mm",
        ("bookshelf_tall", 3): "goal: head_pan_link-upperarm_roll_link -15.1 mm",
        ("bookshelf_tall", 10): "goal: head_pan_link-upperarm_roll_link +0.9 mm",
        ("bookshelf_tall", 15): "goal: forearm_roll_link-obstacle -0.4 mm",
        ("bookshelf_tall", 24): "goal: head_pan_link-upperarm_roll_link -19.6 mm",
        ("bookshelf_tall", 29): "goal: head_pan_link-upperarm_roll_link -31.5 mm, "
                                "head_pan_link-elbow_flex_link +0.3 mm",
        ("bookshelf_tall", 75): "goal: head_pan_link-upperarm_roll_link -31.7 mm",
        ("bookshelf_tall", 82): "goal: head_pan_link-upperarm_roll_link -32.5 mm, "
                                "head_pan_link-elbow_flex_link -23.9 mm",
        ("bookshelf_tall", 97): "goal: head_pan_link-upperarm_roll_link +0.2 mm, "
                                "head_pan_link-elbow_flex_link +0.2 mm",
        ("bookshelf_thin", 31): "goal: forearm_roll_link-obstacle +0.8 mm",
        ("bookshelf_thin", 51): "goal: forearm_roll_link-obstacle -0.5 mm",
        ("bookshelf_thin", 73): "goal: r_gripper_finger_link-obstacle +0.6 mm, gripper_link-obstacle +0.8 mm",
    },
}


#: Problems valid for the pybullet checker whose start or goal the robot's sphere model (which reaches
#: a little beyond pybullet's shapes, docs/mbm.md) calls a collision, ``robot -> {(scene, file): why}``.
#: Left out for both checkers, so that both plan the same problems; tests/test_spheres.py re-checks
#: that exactly these (and :data:`INVALID_PROBLEMS`) are invalid under the sphere model.
SPHERE_INVALID_PROBLEMS: dict[str, dict[tuple[str, int], str]] = {
    "panda": {},
    "ur5": {
        ("bookshelf_tall", 18): "goal: within the sphere model's reach",
        ("bookshelf_thin", 36): "goal: within the sphere model's reach",
        ("bookshelf_thin", 76): "goal: within the sphere model's reach",
    },
    "fetch": {
        ("bookshelf_small", 8): "goal: within the sphere model's reach",
        ("bookshelf_small", 95): "goal: within the sphere model's reach",
        ("table_under_pick", 80): "start: within the sphere model's reach",
    },
}


@dataclass(frozen=True)
class MBMRecord:
    """One MotionBenchMaker problem as shipped: scene, file number (``sceneNNNN.yaml``), start,
    goal (the robot's planned joints: 7 for the Panda, 6 for the UR5, 8 for the Fetch) and the
    scene's obstacles; and the robot."""

    scene: str
    file: int
    start: tuple[float, ...]
    goal: tuple[float, ...]
    obstacles: tuple[Obstacle, ...]
    robot: str = "panda"


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


def _check_robot(robot: str) -> None:
    if robot not in ROBOTS:
        raise ValueError(f"unknown MotionBenchMaker robot {robot!r}; known: {', '.join(ROBOTS)}")


def load_document(robot: str | Path = "panda") -> dict[str, Any]:
    """The shipped JSON document of ``robot`` (one of :data:`ROBOTS`; or a path to such a file),
    read once per process."""
    if isinstance(robot, Path):
        return _read_document(robot)
    _check_robot(robot)
    return _read_document(DATA_FILES[robot])


@lru_cache(maxsize=None)
def _read_document(path: Path) -> dict[str, Any]:
    if not path.exists():
        extra = "" if path.name == "panda_problems.json" else f" --robot {path.name.split('_')[0]}"
        raise FileNotFoundError(f"the MotionBenchMaker data file {path} is missing: reinstall gnn-mp-envs "
                                f"or regenerate it with `python -m tools.mbm_convert{extra}` (see dataset/README.md)")
    return json.loads(path.read_text())


def robot_scenes(robot: str = "panda") -> tuple[str, ...]:
    """The scenes of ``robot``'s problems, in MotionBenchMaker's order (:data:`SCENES` for all three)."""
    return tuple(load_document(robot)["scenes"])


def scene_records(scene: str, robot: str = "panda") -> tuple[MBMRecord, ...]:
    """The scene's 100 problems for ``robot`` (default: the Panda), in file order (built once per process)."""
    return _scene_records(scene, robot)


@lru_cache(maxsize=None)
def _scene_records(scene: str, robot: str) -> tuple[MBMRecord, ...]:
    _check_robot(robot)
    scenes = SCENES if robot == "panda" else robot_scenes(robot)
    if scene not in scenes:
        raise ValueError(f"unknown MotionBenchMaker scene {scene!r}; known: {', '.join(scenes)}")
    data = load_document(robot)["scenes"][scene]
    layout = data["objects"]
    return tuple(MBMRecord(scene, int(p["file"]), tuple(p["start"]), tuple(p["goal"]),
                           tuple(obstacle(kind, dims, pose) for (_, kind, dims), pose in zip(layout, p["poses"])),
                           robot)
                 for p in data["problems"])
