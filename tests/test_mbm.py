"""MotionBenchMaker's Panda problems: the shipped file against problems transcribed by hand from
VAMP's YAML files, the robot model, the splits, validity of all 700 problems, and the env."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gnn_mp_envs.tasks.mbm import data as mbm_data

READY = [0, -0.785, 0, -2.356, 0, 1.571, 0.785]

#: Transcribed by hand from resources/panda/problems.tar.bz2 of KavrakiLab/vamp at f6de6a7
#: (problems/<scene>_panda/sceneNNNN.yaml and requestNNNN.yaml): scene, file, start, goal, and
#: some objects as (id, MoveIt primitive, dimensions, position, orientation x y z w).
HAND_TRANSCRIBED = [
    ("cage", 1, READY,
     [-0.5545218656333819, 0.4202507223196937, 0.3286814744796756, -1.977673518937082, 2.8973,
      2.341192360593145, -2.31787312121598],
     [("Cube1", "box", [0.07000000000000001, 0.07000000000000001, 0.07000000000000001],
       [0.7444402652852363, -0.1411031622851692, 0.2599367587044526], [0, 0, -0.03996434360673529, 0.999201106504633]),
      ("side_cap", "box", [0.65, 0.65, 0.04],
       [0.7942805504092445, -0.1450964039204273, 0.8899367587044525], [0, 0, -0.03996434360673529, 0.999201106504633])]),
    ("table_pick", 7, READY,
     [-2.630164865386525, -1.538122228194436, -2.264932348755439, -0.1938887070021018, -2.821201674146463,
      2.892184245463948, -0.405988534536962],
     [("Can1", "cylinder", [0.12, 0.03],
       [0.7633661927728594, 0.5664091466271479, 0.2502855550186764], [0, 0, 0.2112475627080855, 0.9774325896193014]),
      ("Object3", "box", [0.02, 0.2, 0.4],
       [0.4731583023676676, 0.656578707912823, 0.3502855550186764], [0, 0, 0.7782563101294961, 0.627946745945563])]),
    ("box", 42, READY,
     [0.9987137610294305, 1.7628, 0.1107638748984727, -1.103880022475733, -0.3809541693789531, 2.843385772798973,
      -0.3395987908144282],
     [("side_cap", "box", [0.7, 0.7, 0.04], [0.3792575517860024, 0.5287411510072006, 0.3673575198456562],
       [-0.1676234273737219, 0.3442719969930371, 0.4043969892775955, 0.8305674287769351])]),
    ("bookshelf_thin", 100, READY,
     [-0.2400401173893378, 1.7628, -0.4128116577865446, -1.107556530816615, -2.341460317333905, 2.035417358245494,
      0.8986431840819701], []),
    ("table_under_pick", 3,
     [2.137633914213135, -1.641756633548923, -2.343675563220585, -1.172360708287675, 2.634932765874932,
      2.23285937444433, 0.234316505851879],
     [-0.3642155966063669, 1.426438818259459, -1.898782064225361, -0.04277618327782673, -1.791996074736754,
      3.328456016727361, 1.319386206654911], []),
]


def test_the_data_file_ships_and_names_its_source():
    assert mbm_data.DATA_FILE.exists(), "gnn_mp_envs/tasks/mbm/dataset/panda_problems.json is missing"
    doc = json.loads(mbm_data.DATA_FILE.read_text())
    assert doc["source"]["commit"] == "f6de6a72e0725ba08e0829f0a34261a3f465aed7"
    assert list(doc["scenes"]) == list(mbm_data.SCENES)
    assert all(len(s["problems"]) == 100 for s in doc["scenes"].values())
    assert all([p["file"] for p in s["problems"]] == list(range(1, 101)) for s in doc["scenes"].values())
    folder = mbm_data.DATA_FILE.parent
    for name in ("README.md", "LICENSE-MotionBenchMaker.txt", "LICENSE-VAMP.txt"):
        assert (folder / name).exists(), name
    import tomllib
    from pathlib import Path
    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert {"dataset/*.json", "dataset/*.md", "dataset/*.txt"} <= set(pyproject["tool"]["setuptools"]["package-data"]
                                                             ["gnn_mp_envs.tasks.mbm"])


@pytest.mark.parametrize("scene,file,start,goal,objects", HAND_TRANSCRIBED, ids=lambda v: str(v)[:20])
def test_shipped_problems_equal_the_yaml(scene, file, start, goal, objects):
    doc = json.loads(mbm_data.DATA_FILE.read_text())
    shipped = doc["scenes"][scene]["problems"][file - 1]
    assert shipped["file"] == file
    assert shipped["start"] == start and shipped["goal"] == goal       # exact: the YAML's floats
    layout = doc["scenes"][scene]["objects"]
    for oid, kind, dims, position, orientation in objects:
        k = [row[0] for row in layout].index(oid)
        assert layout[k][1:] == [kind, dims]
        assert shipped["poses"][k] == position + orientation
    record = mbm_data.scene_records(scene)[file - 1]
    assert record.start == tuple(start) and record.goal == tuple(goal)


def test_moveit_primitives_become_obstacles():
    """Box dimensions are full lengths (half extents here), cylinders are [height, radius] in MoveIt."""
    box = mbm_data.obstacle("box", [0.7, 0.7, 0.04], [1, 2, 3, 0, 0, 0, 1])
    assert box.size == (0.35, 0.35, 0.02) and box.position == (1, 2, 3) and box.quaternion() == (0, 0, 0, 1)
    can = mbm_data.obstacle("cylinder", [0.12, 0.03], [0, 0, 0, 0, 0, 0.6, 0.8])
    assert can.size == (0.03, 0.12) and can.quaternion() == (0, 0, 0.6, 0.8)
    assert mbm_data.obstacle("sphere", [0.1], [0, 0, 0, 0, 0, 0, 1]).size == (0.1,)


def test_the_panda_model_matches_the_urdf_joint_names():
    from gnn_mp_envs.tasks.arm.world import import_pybullet
    p = import_pybullet()
    import pybullet_data
    cid = p.connect(p.DIRECT)
    try:
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        robot = p.loadURDF(mbm_data.PANDA_URDF, useFixedBase=True, physicsClientId=cid)
        names = [p.getJointInfo(robot, j, physicsClientId=cid)[1].decode() for j in mbm_data.PANDA_JOINTS]
        assert names == [f"panda_joint{k}" for k in range(1, 8)]
        assert {n: p.getJointInfo(robot, j, physicsClientId=cid)[1].decode()
                for n, j in mbm_data.PANDA_FINGERS.items()} == {n: n for n in mbm_data.PANDA_FINGERS}
        assert p.getJointInfo(robot, mbm_data.PANDA_HAND, physicsClientId=cid)[12].decode() == "panda_hand"
    finally:
        p.disconnect(cid)
    model = mbm_data.panda_model()
    assert model.low[3] == -3.1416 and model.high[3] == 0.0873     # MBM's URDF, not pybullet_data's 0.0
    assert dict(model.held_joints) == {9: 0.065, 10: 0.065}
    assert len(model.allowed_collisions) == 34 and ("panda_hand", "panda_link7") in model.allowed_collisions
