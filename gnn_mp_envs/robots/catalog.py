"""The robots: the xArm6 on its table (the arm task's) and the Panda, the UR5 and the Fetch as
MotionBenchMaker plans them. Each is a :class:`~gnn_mp_envs.robots.model.RobotModel`, made by a
function of :data:`ROBOTS` (:func:`robot_model` by name); each robot's files are in ``models/<robot>/``
with its README and licences. The Panda and the xArm6 are pybullet_data's; the UR5 and the Fetch are
VAMP's URDFs shipped here (collision meshes only). ``robot.json`` holds a robot's planned joints and
limits, held joints and allowed-collision pairs (MotionBenchMaker's, also in its problem files).

Adding a robot: its files in ``models/<name>/``, a function here returning its RobotModel, an entry in
:data:`ROBOTS`, and ``python -m tools.spherize --robot <name>`` for its sphere model.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gnn_mp_envs.robots.geometry import Obstacle
from gnn_mp_envs.robots.model import RobotModel, model_dir

# ---------------------------------------------------------------------- the xArm6 on its table
#: pybullet_data's xArm6.
XARM6_URDF = "xarm/xarm6_robot.urdf"
#: pybullet joint indices of the six revolute joints (index 0 is the fixed world joint).
XARM6_JOINTS = (1, 2, 3, 4, 5, 6)
#: The link whose frame is the tool flange.
XARM6_EE_LINK = 6
#: Planning limits: the URDF limits, with the +-2 pi joints 1, 4 and 6 cut to one turn
#: (every orientation once; the configuration space stays a box). Joint 4 spans
#: [-pi/2, 3 pi/2] so that both wrist postures (joint 4 near 0 and near pi, which IK
#: returns about equally often) lie inside the box rather than on its boundary.
XARM6_LOW = np.array([-np.pi, -2.059, -3.927, -0.5 * np.pi, -1.69297, -np.pi])
XARM6_HIGH = np.array([np.pi, 2.0944, 0.19198, 1.5 * np.pi, np.pi, np.pi])
#: The table the xArm6 stands on: a box whose upper face is z = 0; [xmin, ymin, xmax, ymax] and thickness.
TABLE_EXTENT = (-0.55, -0.8, 0.9, 0.8)
TABLE_THICKNESS = 0.04
XARM6_TABLE = Obstacle("box", ((TABLE_EXTENT[2] - TABLE_EXTENT[0]) / 2, (TABLE_EXTENT[3] - TABLE_EXTENT[1]) / 2,
                               TABLE_THICKNESS / 2),
                       ((TABLE_EXTENT[0] + TABLE_EXTENT[2]) / 2, (TABLE_EXTENT[1] + TABLE_EXTENT[3]) / 2,
                        -TABLE_THICKNESS / 2))
#: The arm task's xArm6 on the table.
XARM6 = RobotModel(XARM6_URDF, XARM6_JOINTS, tuple(XARM6_LOW.tolist()), tuple(XARM6_HIGH.tolist()), XARM6_EE_LINK,
                   padding=0.001, table=XARM6_TABLE, spheres="xarm6")


def xarm6_model() -> RobotModel:
    """The xArm6 on the arm task's table (:data:`XARM6`)."""
    return XARM6


# ---------------------------------------------------------------------- MotionBenchMaker's robots
#: pybullet_data's ``franka_panda/panda.urdf``: the same collision meshes as MotionBenchMaker's
#: Panda (robowflex_resources, via VAMP: identical files); pybullet collides their convex hulls.
PANDA_URDF = "franka_panda/panda.urdf"
#: pybullet joint indices of panda_joint1..7 and of the two finger joints; the flange link
#: (``panda_hand``). tests/test_robots.py checks the names behind these indices.
PANDA_JOINTS = (0, 1, 2, 3, 4, 5, 6)
PANDA_FINGERS = {"panda_finger_joint1": 9, "panda_finger_joint2": 10}
PANDA_HAND = 8
#: The planner's safety margin (m): contacts closer than this count as collisions, so that edges
#: checked every 0.01 rad do not graze obstacles between their checked states (docs/mbm.md); the
#: independent path check uses none. pybullet reports positive-distance contacts only up to about
#: 1 mm (for a box against the hand's hull), which bounds the margin; every MBM start and goal keeps
#: at least 1.94 mm.
PANDA_PADDING = 0.001

#: VAMP's UR5 (with a Robotiq FT-300 sensor and 2F-85 gripper) and Fetch, as shipped here.
UR5_URDF = model_dir("ur5") / "ur5.urdf"
FETCH_URDF = model_dir("fetch") / "fetch.urdf"
#: pybullet joint indices of the planned joints, in the data's order (UR5: shoulder_pan_joint ..
#: wrist_3_joint; Fetch: torso_lift_joint, shoulder_pan_joint .. wrist_roll_joint), and the
#: end-effector link, VAMP's attachment frame (UR5: ``robotiq_85_base_link``; Fetch:
#: ``gripper_link``). tests/test_robots.py checks the names behind these indices.
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

@lru_cache(maxsize=None)
def robot_facts(robot: str) -> dict[str, Any]:
    """``models/<robot>/robot.json``: planned joints and limits, held joints, allowed-collision pairs."""
    path = model_dir(robot) / "robot.json"
    if not path.exists():
        raise FileNotFoundError(f"the robot file {path} is missing: reinstall gnn-mp-envs")
    return json.loads(path.read_text())


@lru_cache(maxsize=1)
def panda_model() -> RobotModel:
    """The Panda as MotionBenchMaker plans it: its URDF's joint limits, fingers held open at the
    problems' 6.5 cm each, and self-collision off for the link pairs of the scenes' allowed-collision
    matrix (= the SRDF's disabled pairs); plus the planner's 1 mm safety margin."""
    robot = robot_facts("panda")
    held = tuple((PANDA_FINGERS[name], float(v)) for name, v in robot["held_joints"].items())
    return RobotModel(PANDA_URDF, PANDA_JOINTS, tuple(robot["lower"]), tuple(robot["upper"]), PANDA_HAND,
                      held_joints=held, allowed_collisions=tuple(tuple(p) for p in robot["allowed_collisions"]),
                      padding=PANDA_PADDING, spheres="panda")


def urdf_links(urdf: Path) -> tuple[str, ...]:
    """The link names of a URDF file, in its order."""
    return tuple(link.get("name") for link in ET.parse(urdf).getroot().iter("link"))


def allowed_collisions(robot: str, aliases: dict[str, str] | None = None) -> tuple[tuple[str, str], ...]:
    """The link pairs of ``robot``'s allowed-collision matrix that its shipped URDF has both links of
    (the UR5's matrix names ``box_link``, the Fetch's ``bellows_link2``, ``estop_link``,
    ``laser_link`` and the wheels, which VAMP's models leave out), plus, for each ``alias -> link``
    of ``aliases``, ``link``'s pairs with ``alias`` in its place (sorted, no duplicates)."""
    if robot == "panda":
        return tuple(tuple(p) for p in robot_facts("panda")["allowed_collisions"])
    links = set(urdf_links(UR5_URDF if robot == "ur5" else FETCH_URDF))
    pairs = [tuple(p) for p in robot_facts(robot)["allowed_collisions"]]
    for alias, link in (aliases or {}).items():
        pairs += [tuple(alias if x == link else x for x in p) for p in pairs if link in p]
    return tuple(sorted({tuple(sorted(p)) for p in pairs if p[0] != p[1] and set(p) <= links}))


def _vamp_model(robot: str, urdf: Path, joints: tuple[int, ...], ee_link: int, held: dict[str, float],
                aliases: dict[str, str] | None = None, continuous: tuple[str, ...] = ()) -> RobotModel:
    """The RobotModel of a robot shipped under ``models/``: the data's joint limits (``continuous``
    joints: [-pi, pi]), no joints to hold (the URDF has the data's held joints fixed at their
    values, see :data:`UR5_HELD`), self-collision off for :func:`allowed_collisions`, and the
    planner's 1 mm safety margin."""
    doc = robot_facts(robot)
    if doc["held_joints"] != held:
        raise ValueError(f"{robot}: robot.json holds {doc['held_joints']}, but the shipped URDF fixes {held}")
    if not urdf.exists():
        raise FileNotFoundError(f"the {robot} model {urdf} is missing: reinstall gnn-mp-envs or regenerate it "
                                f"with `python -m tools.mbm_convert --robot {robot} --robot-files`")
    low, high = list(doc["lower"]), list(doc["upper"])
    for name in continuous:
        k = doc["joints"].index(name)
        low[k], high[k] = -math.pi, math.pi
    return RobotModel(str(urdf), joints, tuple(low), tuple(high), ee_link,
                      allowed_collisions=allowed_collisions(robot, aliases), padding=PANDA_PADDING,
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


#: Robot name -> the function making its RobotModel.
ROBOTS: dict[str, Callable[[], RobotModel]] = {"xarm6": xarm6_model, "panda": panda_model, "ur5": ur5_model,
                                                "fetch": fetch_model}


def robot_model(name: str) -> RobotModel:
    """The RobotModel of robot ``name`` (one of :data:`ROBOTS`)."""
    if name not in ROBOTS:
        raise ValueError(f"unknown robot {name!r}; known: {', '.join(ROBOTS)}")
    return ROBOTS[name]()
