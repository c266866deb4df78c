"""MotionBenchMaker's UR5 and Fetch problems and robot models: the shipped files against problems
transcribed by hand from VAMP's YAML files, the shipped URDFs and meshes, the models' pybullet joint
indices, and the validity of every start and goal under the models."""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from gnn_mp_envs.robots import catalog
from gnn_mp_envs.robots.model import model_dir
from gnn_mp_envs.tasks.mbm import data as mbm_data

ROOT = Path(__file__).resolve().parents[1]
COMMIT = "f6de6a72e0725ba08e0829f0a34261a3f465aed7"
UR5_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
              "wrist_3_joint"]
FETCH_JOINTS = ["torso_lift_joint", "shoulder_pan_joint", "shoulder_lift_joint", "upperarm_roll_joint",
                "elbow_flex_joint", "forearm_roll_joint", "wrist_flex_joint", "wrist_roll_joint"]
UR5_START = [1.57, -1.5707, 0, -1.5707, -1.57, 3.14]
FETCH_START = [0.1, 1.32, 1.4, -0.2, 1.72, 0, 1.66, 0]
Q_CAGE_UR5 = [0, 0, 0.6380427775893096, 0.77000091815927]
Q_CAGE_FETCH = [0, 0, -0.02831026111195342, 0.9995991842312463]

#: Transcribed by hand from resources/<robot>/problems.tar.bz2 of KavrakiLab/vamp at f6de6a7
#: (problems/<scene>_<robot>/sceneNNNN.yaml and requestNNNN.yaml): robot, scene, file, start, goal
#: (the planned joints in the data's order) and some objects as (id, MoveIt primitive, dimensions,
#: position, orientation x y z w), each the primitive's pose.
HAND_TRANSCRIBED = [
    ("ur5", "cage", 1, UR5_START,
     [-0.3349380838432033, -0.4823709650391223, 1.189500896897532, -2.274744097118824, -1.570496963693504,
      -0.1431679786383009],
     [("Cube1", "box", [0.07000000000000001, 0.07000000000000001, 0.07000000000000001],
       [0.2087649192765714, 0.7522271298442013, 0.6171387767074634], Q_CAGE_UR5),
      ("side_cap", "box", [0.65, 0.65, 0.04], [0.2180550606731833, 0.8013564823010672, 1.247138776707463],
       Q_CAGE_UR5)]),
    ("ur5", "table_pick", 1, UR5_START,
     [1.438775553350176, -0.6875404909857841, 1.43409606187095, -0.7445397051423589, 1.589182367635896,
      -3.14159265], []),
    ("fetch", "cage", 1, FETCH_START,
     [1.700843516125748e-07, 0.1937382712775019, 0.3573123458617245, 0.8657411677842958, -1.036554743356585,
      -0.8525239685941394, 1.923056168585155, -0.5284443936080681],
     [("Cube1", "box", [0.07000000000000001, 0.07000000000000001, 0.07000000000000001],
       [0.7298060401336944, -0.08467611731757765, 0.4267144635133688], Q_CAGE_FETCH),
      ("side_cap", "box", [0.65, 0.65, 0.04], [0.7797258930452717, -0.08750600870886588, 1.056714463513369],
       Q_CAGE_FETCH)]),
    ("fetch", "table_under_pick", 80,
     [0, 0.2707418459076945, 0.9126814570944698, -0.8858067483552456, 1.459638845123143, 1.168697485648399,
      -1.269309888317707, 1.055340333668202],
     [0.3522057176123183, 0.1459368285190437, 0.694125084292199, -1.161530226854013, 1.397158138795542,
      0.9575618961357351, -1.031577886733012, 1.068610294086935],
     [("Can1", "cylinder", [0.12, 0.03], [0.7034026278129373, -0.4228947998531539, 0.7553689805471593],
       [0, 0, -0.2876990607150038, 0.9577208624978911])]),
]

#: The UR5's table_pick objects carry an object pose as well as the primitive's (MoveIt >= Noetic);
#: the data stores their composition. Transcribed from table_pick_ur5/scene0001.yaml: id, primitive,
#: dimensions, object pose (position, orientation), primitive pose (position, orientation).
UR5_TABLE_PICK_1_OBJECTS = [
    ("Can1", "cylinder", [0.12, 0.03],
     [-0.06371788662107358, -0.1102475820769556, 0.08705641176758652],
     [0, 0, 0.9972514405491772, 0.07409159414259425],
     [0.85, 0, 0.8], [0, 0, 0, 1]),
    ("table_top", "box", [1.2, 2, 0.04],
     [-0.08882545052091238, -0.0838528117056479, 0.08705641176758652],
     [0, 0, 0.9972514405491772, 0.07409159414259424],
     [1.05, 0, 0.7], [0, 0, 0, 1]),
]


def _rotation(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _doc(robot):
    return json.loads(mbm_data.DATA_FILES[robot].read_text())


# ---------------------------------------------------------------------- the data

@pytest.mark.parametrize("robot", ["ur5", "fetch"])
def test_the_data_files_ship_and_name_their_source(robot):
    path = mbm_data.DATA_FILES[robot]
    assert path == ROOT / "gnn_mp_envs" / "tasks" / "mbm" / "dataset" / f"{robot}_problems.json" and path.exists()
    doc = _doc(robot)
    assert doc["format"] == "gnn-mp-envs MotionBenchMaker problems, version 1"
    assert doc["source"]["commit"] == COMMIT
    assert set(doc["source"]["sha256"]) == {f"resources/{robot}/problems.tar.bz2", f"resources/{robot}/{robot}.urdf"}
    assert doc["source"]["regenerate"].endswith(f"--robot {robot}")
    assert list(doc["scenes"]) == list(mbm_data.SCENES) == list(mbm_data.robot_scenes(robot))
    joints = UR5_JOINTS if robot == "ur5" else FETCH_JOINTS
    assert doc["robot"]["name"] == robot and doc["robot"]["joints"] == joints
    for scene in doc["scenes"].values():
        assert [p["file"] for p in scene["problems"]] == list(range(1, 101))
        for p in scene["problems"]:
            assert len(p["start"]) == len(p["goal"]) == len(joints) and len(p["poses"]) == len(scene["objects"])
            assert all(len(pose) == 7 for pose in p["poses"])
    import tomllib
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    data = pyproject["tool"]["setuptools"]["package-data"]
    assert {"dataset/*.json"} <= set(data["gnn_mp_envs.tasks.mbm"])
    assert {"models/*/*.urdf", "models/*/*.md", "models/*/*.json", "models/*/*.npz", "models/*/meshes/**/*.stl",
            "models/*/meshes/**/*.STL"} <= set(data["gnn_mp_envs.robots"])


def test_the_robots_facts():
    ur5, fetch = _doc("ur5")["robot"], _doc("fetch")["robot"]
    assert ur5["lower"] == [-3.14159265] * 6 and ur5["upper"] == [3.14159265] * 6
    assert fetch["lower"] == [0.0, -1.6056, -1.221, -3.14159, -2.251, -3.14159, -2.16, -3.14159]
    assert fetch["upper"] == [0.38615, 1.6056, 1.518, 3.14159, 2.251, 3.14159, 2.16, 3.14159]
    # every non-planned joint of the requests' start states, in their order, at its (constant) value
    assert ur5["held_joints"] == {"robotiq_85_left_inner_knuckle_joint": 0.0, "robotiq_85_left_finger_tip_joint": 0.0,
                                  "robotiq_85_left_knuckle_joint": 0.0, "robotiq_85_right_inner_knuckle_joint": 0.0,
                                  "robotiq_85_right_finger_tip_joint": 0.0, "robotiq_85_right_knuckle_joint": 0.0}
    assert list(fetch["held_joints"].items()) == [
        ("l_wheel_joint", 0.0), ("r_wheel_joint", 0.0), ("bellows_joint", 0.05), ("head_pan_joint", 0.0),
        ("head_tilt_joint", 0.0), ("l_gripper_finger_joint", 0.05), ("r_gripper_finger_joint", 0.05)]
    assert ur5["held_joints"] == catalog.UR5_HELD and fetch["held_joints"] == catalog.FETCH_HELD
    assert len(ur5["allowed_collisions"]) == 90 and ["base_link", "box_link"] in ur5["allowed_collisions"]
    assert len(fetch["allowed_collisions"]) == 134
    assert ["shoulder_pan_link", "torso_lift_link"] in fetch["allowed_collisions"]
    for robot in (ur5, fetch):
        pairs = [tuple(p) for p in robot["allowed_collisions"]]
        assert pairs == sorted(pairs) and all(a < b for a, b in pairs)


@pytest.mark.parametrize("robot,scene,file,start,goal,objects", HAND_TRANSCRIBED, ids=lambda v: str(v)[:20])
def test_shipped_problems_equal_the_yaml(robot, scene, file, start, goal, objects):
    from tests.helpers import assert_problem_equals_yaml
    assert_problem_equals_yaml(_doc(robot), robot, scene, file, start, goal, objects)


def test_object_poses_are_composed_with_the_primitive_poses():
    """UR5 table_pick: world pose = object pose * primitive pose (as MoveIt and VAMP compose them)."""
    doc = _doc("ur5")
    shipped = doc["scenes"]["table_pick"]["problems"][0]
    layout = doc["scenes"]["table_pick"]["objects"]
    for oid, kind, dims, obj_p, obj_q, prim_p, prim_q in UR5_TABLE_PICK_1_OBJECTS:
        k = [row[0] for row in layout].index(oid)
        assert layout[k][1:] == [kind, dims]
        expected = np.array(obj_p) + _rotation(obj_q) @ np.array(prim_p)
        assert np.allclose(shipped["poses"][k][:3], expected, rtol=0, atol=1e-12)
        assert shipped["poses"][k][3:] == obj_q        # the primitive is not turned within its object
    assert "composition" in doc["units"]["poses"] and "composition" not in _doc("fetch")["units"]["poses"]
    # the table of scene 1 really is in front of the robot's base (0.9144 m above the data's frame)
    top = shipped["poses"][[row[0] for row in layout].index("table_top")]
    assert 0.75 < top[2] < 0.8 and 1.0 < math.hypot(top[0], top[1]) < 1.2


def test_the_converters_pose_composition_and_urdf_edit():
    from tools import mbm_convert as conv
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = rng.normal(size=7), rng.normal(size=7)
        a[3:] /= np.linalg.norm(a[3:])
        b[3:] /= np.linalg.norm(b[3:])
        c = conv.compose(a.tolist(), b.tolist())
        assert np.allclose(c[:3], a[:3] + _rotation(a[3:]) @ b[:3], atol=1e-12)
        assert np.allclose(_rotation(c[3:]), _rotation(a[3:]) @ _rotation(b[3:]), atol=1e-12)
    urdf = ('<?xml version="1.0" ?>\n<robot name="r">\n  <link name="a">\n    <visual>\n'
            '      <geometry><box size="1 1 1"/></geometry>\n    </visual>\n    <collision>\n'
            '      <geometry><mesh filename="package://meshes/a.stl" '
            'scale="1 2 3"/></geometry>\n    </collision>\n  </link>\n  <link name="b"/>\n'
            '  <joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>\n</robot>\n')
    edited = conv.collision_urdf(urdf, "fetch")
    tree = ET.fromstring(edited)
    assert tree.find(".//visual") is None and tree.find("link[@name='b']/inertial") is not None
    assert ET.tostring(tree.find("link[@name='a']/collision")) == ET.tostring(ET.fromstring(urdf).find(
        "link[@name='a']/collision"))
    assert conv.mesh_paths(edited) == ["meshes/a.stl"]


@pytest.mark.skipif(not os.environ.get("VAMP_GIT_DIR"), reason="set VAMP_GIT_DIR to VAMP's git directory")
@pytest.mark.parametrize("args", [["--robot", "ur5"], ["--robot", "fetch"], ["--robot", "ur5", "--robot-files"],
                                  ["--robot", "fetch", "--robot-files"], []])
def test_the_converter_reproduces_the_shipped_files(args):
    run = subprocess.run([sys.executable, "-m", "tools.mbm_convert", "--vamp", os.environ["VAMP_GIT_DIR"], "--check",
                          *args], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


# ---------------------------------------------------------------------- the robot files

@pytest.mark.parametrize("robot", ["ur5", "fetch"])
def test_the_robot_files_ship_collision_meshes_only(robot):
    folder = model_dir(robot)
    urdf = folder / f"{robot}.urdf"
    assert urdf == (catalog.UR5_URDF if robot == "ur5" else catalog.FETCH_URDF)
    tree = ET.parse(urdf).getroot()
    assert tree.find(".//visual") is None
    assert all(link.find("inertial") is not None for link in tree.iter("link"))   # pybullet loads it silently
    meshes = {m.get("filename").removeprefix("package://") for m in tree.iter("mesh")}
    assert meshes and all((folder / m).is_file() for m in meshes)
    shipped = {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}
    assert shipped == meshes | {f"{robot}.urdf", "README.md", "LICENSES.md", "robot.json", f"{robot}.npz"}  # no visual mesh
    concave = [link.get("name") for link in tree.iter("link") if link.find("collision[@concave]") is not None]
    assert concave == (["forearm_link"] if robot == "ur5" else [])
    assert f"{COMMIT[:12]}" in urdf.read_text().split("\n", 3)[1 if robot == "ur5" else 0]
    # the README's table names every shipped file with its size and sha256
    readme = (folder / "README.md").read_text()
    rows = {m.group(1): (int(m.group(2)), m.group(3)) for m in
            re.finditer(r"^\| `([^`]+)`(?: \(shipped, edited\))? \| (\d+) \| `([0-9a-f]{64})` \|$", readme, re.M)
            if "(VAMP's)" not in m.group(0)}
    assert set(rows) == meshes | {f"{robot}.urdf"}
    for rel, (size, sha) in rows.items():
        data = (folder / rel).read_bytes()
        assert (len(data), hashlib.sha256(data).hexdigest()) == (size, sha), rel
    licences = (folder / "LICENSES.md").read_text()
    assert "Apache" in licences and ("CC BY-NC-SA 4.0" in licences if robot == "fetch" else "BSD" in licences)


def _pybullet_names(urdf):
    from gnn_mp_envs.robots.world import import_pybullet
    p = import_pybullet()
    cid = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(urdf), useFixedBase=True, physicsClientId=cid)
        info = [p.getJointInfo(body, j, physicsClientId=cid)
                for j in range(p.getNumJoints(body, physicsClientId=cid))]
        root = p.getBodyInfo(body, physicsClientId=cid)[0].decode()
        shapes = sum(len(p.getCollisionShapeData(body, j, physicsClientId=cid)) for j in range(-1, len(info)))
    finally:
        p.disconnect(cid)
    return root, [(i[1].decode(), i[2], i[12].decode()) for i in info], shapes


@pytest.mark.parametrize("robot", ["ur5", "fetch"])
def test_the_models_indices_name_the_planned_joints(robot):
    import pybullet
    model = catalog.ur5_model() if robot == "ur5" else catalog.fetch_model()
    root, joints, shapes = _pybullet_names(model.urdf)
    assert Path(model.urdf).is_absolute() and Path(model.urdf).exists()
    assert root == ("offset_link" if robot == "ur5" else "base_link")
    assert [joints[j][0] for j in model.joints] == (UR5_JOINTS if robot == "ur5" else FETCH_JOINTS)
    movable = [name for name, kind, _ in joints if kind != pybullet.JOINT_FIXED]
    assert movable == (UR5_JOINTS if robot == "ur5" else FETCH_JOINTS)   # nothing else moves: nothing to hold
    assert model.held_joints == ()
    assert joints[model.ee_link][2] == ("robotiq_85_base_link" if robot == "ur5" else "gripper_link")
    assert shapes == (18 if robot == "ur5" else 15)              # every collision element of the URDF loaded
    # the data's held joints are fixed in the URDF (or left out with their links)
    fixed = {j.get("name") for j in ET.parse(model.urdf).getroot().iter("joint") if j.get("type") == "fixed"}
    held = _doc(robot)["robot"]["held_joints"]
    left_out = {"l_wheel_joint", "r_wheel_joint"} if robot == "fetch" else set()
    assert set(held) - left_out <= fixed
    assert model.padding == catalog.PANDA_PADDING and model.table is None


def test_the_models_limits_and_allowed_pairs():
    ur5, fetch = catalog.ur5_model(), catalog.fetch_model()
    assert ur5.low == tuple(_doc("ur5")["robot"]["lower"]) and ur5.high == tuple(_doc("ur5")["robot"]["upper"])
    assert fetch.low == (0.0, -1.6056, -1.221, -math.pi, -2.251, -math.pi, -2.16, -math.pi)
    assert fetch.high == (0.38615, 1.6056, 1.518, math.pi, 2.251, math.pi, 2.16, math.pi)
    assert len(ur5.allowed_collisions) == 88 and not any("box_link" in p for p in ur5.allowed_collisions)
    links = set(catalog.urdf_links(catalog.FETCH_URDF))
    assert len(fetch.allowed_collisions) == 72 and all(set(p) <= links for p in fetch.allowed_collisions)
    assert ("shoulder_pan_link", "torso_lift_link_collision_2") in fetch.allowed_collisions
    assert {p for p in fetch.allowed_collisions if "torso_lift_link_collision_2" in p} == {
        tuple(sorted((other, "torso_lift_link_collision_2"))) for a, b in fetch.allowed_collisions
        if "torso_lift_link" in (a, b) for other in {a, b} - {"torso_lift_link"}}
    assert catalog.ur5_model() is ur5                                    # built once


def test_loading_the_robots_prints_nothing(capfd):
    from gnn_mp_envs.robots.world import RobotWorld
    capfd.readouterr()
    for model in (catalog.ur5_model(), catalog.fetch_model()):
        RobotWorld(model).close()
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_the_loader_api():
    assert mbm_data.ROBOTS == ("panda", "ur5", "fetch")
    assert mbm_data.load_document("ur5") is mbm_data.load_document("ur5")
    assert mbm_data.load_document() is mbm_data.load_document("panda")
    assert mbm_data.scene_records("cage") is mbm_data.scene_records("cage", "panda")
    assert all(r.robot == "panda" and len(r.start) == 7 for r in mbm_data.scene_records("cage"))
    assert all(len(r.start) == 6 for r in mbm_data.scene_records("box", "ur5"))
    assert all(len(r.goal) == 8 for r in mbm_data.scene_records("box", "fetch"))
    with pytest.raises(ValueError, match="unknown MotionBenchMaker robot"):
        mbm_data.scene_records("cage", "baxter")
    with pytest.raises(ValueError, match="unknown MotionBenchMaker robot"):
        mbm_data.load_document("baxter")
    with pytest.raises(ValueError, match="unknown MotionBenchMaker scene"):
        mbm_data.scene_records("kitchen", "ur5")


# ---------------------------------------------------------------------- validity

@pytest.mark.parametrize("robot", ["ur5", "fetch"])
def test_every_start_and_goal_is_valid_except_the_listed(robot):
    """Within the model's limits and no contact within the 1 mm padding, for every problem except
    exactly those of ``INVALID_PROBLEMS`` (at least 95 % valid)."""
    from gnn_mp_envs.robots.world import RobotWorld
    model = catalog.ur5_model() if robot == "ur5" else catalog.fetch_model()
    world = RobotWorld(model)
    invalid = set()
    try:
        for scene in mbm_data.robot_scenes(robot):
            for record in mbm_data.scene_records(scene, robot):
                world.load(record.obstacles)
                for q in (np.asarray(record.start), np.asarray(record.goal)):
                    if np.any(q < world.low) or np.any(q > world.high) or world.collides(q):
                        invalid.add((scene, record.file))
    finally:
        world.close()
    assert invalid == set(mbm_data.INVALID_PROBLEMS[robot])
    assert len(invalid) <= 35
