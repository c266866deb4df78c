"""MotionBenchMaker's Panda, UR5 and Fetch problems as shipped in ``dataset/<robot>_problems.json``
(made by ``tools/mbm_convert.py`` from VAMP's copy of the problems; source, commit and licences in
``dataset/README.md``), and the :class:`~gnn_mp_envs.tasks.arm.world.RobotModel` each robot is planned
with: the Panda is pybullet_data's, the UR5 and the Fetch are VAMP's URDFs shipped (collision meshes
only) under ``robots/<robot>/`` (source, changes, data facts, validity and licences in the README
and LICENSES.md there).
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from gnn_mp_envs.tasks.arm.scenes import Obstacle
from gnn_mp_envs.tasks.arm.world import RobotModel

DATA_FILE = Path(__file__).resolve().parent / "dataset" / "panda_problems.json"
#: The robots whose MotionBenchMaker problems ship, and their data files.
ROBOTS = ("panda", "ur5", "fetch")
DATA_FILES = {robot: DATA_FILE.with_name(f"{robot}_problems.json") for robot in ROBOTS}
#: The shipped UR5 and Fetch models (URDF and collision meshes; see robots/<robot>/README.md).
ROBOTS_DIR = Path(__file__).resolve().parent / "robots"
#: The seven Panda scenes, in MotionBenchMaker's order (the UR5's and the Fetch's are the same seven).
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

#: VAMP's UR5 (with a Robotiq FT-300 sensor and 2F-85 gripper) and Fetch, as shipped here.
UR5_URDF = ROBOTS_DIR / "ur5" / "ur5.urdf"
FETCH_URDF = ROBOTS_DIR / "fetch" / "fetch.urdf"
#: pybullet joint indices of the planned joints, in the data's order (UR5: shoulder_pan_joint ..
#: wrist_3_joint; Fetch: torso_lift_joint, shoulder_pan_joint .. wrist_roll_joint), and the
#: end-effector link, VAMP's attachment frame (UR5: ``robotiq_85_base_link``; Fetch:
#: ``gripper_link``). tests/test_mbm_robots.py checks the names behind these indices.
UR5_JOINTS = (1, 2, 3, 4, 5, 6)
UR5_EE = 11
FETCH_JOINTS = (0, 4, 5, 6, 7, 8, 9, 10)
FETCH_EE = 11
#: The requests' non-planned joints and their start-state values, which VAMP's URDFs realise as
#: fixed joints at these very values (the Robotiq's joints at 0; the Fetch's head at 0 and fingers
#: at 0.05 m: VAMP's finger joints sit at 0.065425 = 0.015425 + 0.05 from the gripper) or leave out
#: with their links (the Fetch's wheels; ``bellows_link`` has no collision geometry there): nothing
#: for pybullet to hold. The models refuse data whose held joints say otherwise.
UR5_HELD = {f"robotiq_85_{side}_{part}_joint": 0.0 for side in ("left", "right")
            for part in ("inner_knuckle", "finger_tip", "knuckle")}
FETCH_HELD = {"l_wheel_joint": 0.0, "r_wheel_joint": 0.0, "bellows_joint": 0.05, "head_pan_joint": 0.0,
              "head_tilt_joint": 0.0, "l_gripper_finger_joint": 0.05, "r_gripper_finger_joint": 0.05}
#: Links VAMP added to carry a second collision shape of a link (joined to it by a fixed joint at
#: the identity): the scenes' allowed-collision matrix does not know them, so they take their
#: link's allowed pairs (as VAMP's own fetch.srdf lists them). Without this the Fetch's
#: ``torso_lift_link_collision_2`` sphere touches ``shoulder_pan_link`` in every configuration.
FETCH_LINK_ALIASES = {"torso_lift_link_collision_2": "torso_lift_link"}
#: The Fetch's roll joints are continuous in its own URDF (robowflex_resources, fetch_description),
#: which MoveIt bounds to [-pi, pi]; VAMP's URDF writes +-3.14159, which 146 of the problems' start
#: and goal values exceed by up to 2.7e-6 rad (MBM's goals sit at +-pi exactly). The model plans
#: these joints in [-pi, pi].
FETCH_CONTINUOUS = ("upperarm_roll_joint", "forearm_roll_joint", "wrist_roll_joint")

#: Problems whose start or goal is invalid under the shipped model (out of the joint limits, or a
#: contact within the 1 mm padding), as ``robot -> {(scene, file): why}`` (contacts: the link pairs
#: and their pybullet distance). Measured over all 700 of each robot with pybullet 3.2.7;
#: tests/test_mbm_robots.py re-checks that exactly these are invalid. The Panda has none (see
#: ``task.EXCLUDED``); the UR5's are contacts closer than 1 mm; the Fetch's come from VAMP's coarser
#: collision shapes (the 0.2 m head sphere, the torso's added sphere, its convex base) and contacts
#: closer than 1 mm (see robots/fetch/README.md).
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


@lru_cache(maxsize=1)
def panda_model() -> RobotModel:
    """The Panda as MotionBenchMaker plans it: its URDF's joint limits, fingers held open at the
    problems' 6.5 cm each, and self-collision off for the link pairs of the scenes' allowed-collision
    matrix (= the SRDF's disabled pairs); plus the planner's 1 mm safety margin."""
    robot = load_document()["robot"]
    held = tuple((PANDA_FINGERS[name], float(v)) for name, v in robot["held_joints"].items())
    return RobotModel(PANDA_URDF, PANDA_JOINTS, tuple(robot["lower"]), tuple(robot["upper"]), PANDA_HAND,
                      held_joints=held, allowed_collisions=tuple(tuple(p) for p in robot["allowed_collisions"]),
                      padding=PANDA_PADDING, table=False, spheres="panda")


def urdf_links(urdf: Path) -> tuple[str, ...]:
    """The link names of a URDF file, in its order."""
    return tuple(link.get("name") for link in ET.parse(urdf).getroot().iter("link"))


def allowed_collisions(robot: str, aliases: dict[str, str] | None = None) -> tuple[tuple[str, str], ...]:
    """The link pairs of ``robot``'s allowed-collision matrix that its shipped URDF has both links of
    (the UR5's matrix names ``box_link``, the Fetch's ``bellows_link2``, ``estop_link``,
    ``laser_link`` and the wheels, which VAMP's models leave out), plus, for each ``alias -> link``
    of ``aliases``, ``link``'s pairs with ``alias`` in its place (sorted, no duplicates)."""
    if robot == "panda":
        return tuple(tuple(p) for p in load_document("panda")["robot"]["allowed_collisions"])
    links = set(urdf_links(UR5_URDF if robot == "ur5" else FETCH_URDF))
    pairs = [tuple(p) for p in load_document(robot)["robot"]["allowed_collisions"]]
    for alias, link in (aliases or {}).items():
        pairs += [tuple(alias if x == link else x for x in p) for p in pairs if link in p]
    return tuple(sorted({tuple(sorted(p)) for p in pairs if p[0] != p[1] and set(p) <= links}))


def _vamp_model(robot: str, urdf: Path, joints: tuple[int, ...], ee_link: int, held: dict[str, float],
                aliases: dict[str, str] | None = None, continuous: tuple[str, ...] = ()) -> RobotModel:
    """The RobotModel of a robot shipped under ``robots/``: the data's joint limits (``continuous``
    joints: [-pi, pi]), no joints to hold (the URDF has the data's held joints fixed at their
    values, see :data:`UR5_HELD`), self-collision off for :func:`allowed_collisions`, and the
    planner's 1 mm safety margin."""
    doc = load_document(robot)["robot"]
    if doc["held_joints"] != held:
        raise ValueError(f"{robot}: the data holds {doc['held_joints']}, but the shipped URDF fixes {held}")
    if not urdf.exists():
        raise FileNotFoundError(f"the {robot} model {urdf} is missing: reinstall gnn-mp-envs or regenerate it "
                                f"with `python -m tools.mbm_convert --robot {robot} --robot-files`")
    low, high = list(doc["lower"]), list(doc["upper"])
    for name in continuous:
        k = doc["joints"].index(name)
        low[k], high[k] = -math.pi, math.pi
    return RobotModel(str(urdf), joints, tuple(low), tuple(high), ee_link,
                      allowed_collisions=allowed_collisions(robot, aliases), padding=PANDA_PADDING, table=False,
                      spheres=robot)


@lru_cache(maxsize=1)
def ur5_model() -> RobotModel:
    """The UR5 as MotionBenchMaker plans it (VAMP's model: the UR5 on a fixed base 0.9144 m above
    the data's frame, Robotiq FT-300 and 2F-85 fixed open; the forearm's mesh collided as it is,
    not as its convex hull): its URDF's joint limits (+-pi, one turn), self-collision off for the
    allowed-collision matrix's pairs, the planner's 1 mm safety margin."""
    return _vamp_model("ur5", UR5_URDF, UR5_JOINTS, UR5_EE, UR5_HELD)


@lru_cache(maxsize=1)
def fetch_model() -> RobotModel:
    """The Fetch as MotionBenchMaker plans it (VAMP's model: base fixed, head and fingers fixed):
    the torso's lift (m) and the seven arm joints within its URDF's limits (the roll joints in
    [-pi, pi], see :data:`FETCH_CONTINUOUS`), self-collision off for the allowed-collision matrix's
    pairs (with :data:`FETCH_LINK_ALIASES`), the planner's 1 mm safety margin."""
    return _vamp_model("fetch", FETCH_URDF, FETCH_JOINTS, FETCH_EE, FETCH_HELD, FETCH_LINK_ALIASES,
                       FETCH_CONTINUOUS)
