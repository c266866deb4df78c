"""The robots' floor (``gnn_mp_envs.robots``): the checker chosen by name in one place, the problem
refusing states of another length before native code sees them, sphere model files checked on load,
and each robot's facts in one place."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from gnn_mp_envs.robots.checkers import CHECKERS, checker_name


def test_a_checker_name_is_checked_in_one_place():
    assert checker_name(None) == next(iter(CHECKERS)) == "spheres"
    assert [checker_name(n) for n in CHECKERS] == list(CHECKERS)
    with pytest.raises(ValueError, match="unknown collision checker 'fcl'; known: spheres, pybullet"):
        checker_name("fcl")
    from gnn_mp_envs.registration import make_task
    with pytest.raises(ValueError, match="unknown collision checker 'fcl'"):
        make_task("ur5-mbm", checker="fcl")


#: A problem method and its arguments, with ``a``/``b`` the problem's start and goal.
BAD_CALLS = {
    "steer, an 8-long target": "p.steer(p.start, np.zeros(8))",
    "steer, a 64-long start": "p.steer(np.zeros(64), p.goal)",
    "check_motion, two 8-long states": "p.check_motion(np.zeros(8), np.zeros(8))",
    "check_motion, a list of another length": "p.check_motion(p.start, [0.0] * 6)",
    "goal_connection, a 2-D state": "p.goal_connection(np.zeros((1, 7)))",
    "is_state_valid, 14 numbers": "p.is_state_valid(np.zeros(14))",
    "is_state_valid_exact, rows of 8": "p.is_state_valid_exact(np.zeros((3, 8)))",
}


@pytest.mark.parametrize("checker", list(CHECKERS))
def test_states_of_another_length_are_refused_in_one_line(checker):
    """With pybullet such states aborted or crashed the interpreter; with the spheres an 8-long target
    became a 7-long edge and check_motion answered. Run in a child process: a crash must fail, not kill."""
    code = ("import numpy as np\nfrom gnn_mp_envs.registration import make_task\n"
            f"t = make_task('panda-mbm', checker={checker!r})\np = t.problem('test', 0)\n"
            f"for name, call in {BAD_CALLS!r}.items():\n"
            "    try:\n        eval(call)\n    except ValueError as exc:\n"
            "        assert len(str(exc).splitlines()) == 1 and 'shape' in str(exc), exc\n"
            "    else:\n        raise SystemExit(f'{name}: answered')\n"
            "print(p.steer(p.start, p.goal) is not None or True)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, (run.returncode, run.stderr[-1500:])


# ---------------------------------------------------------------------- sphere model files
@pytest.fixture(scope="module")
def shipped():
    from gnn_mp_envs.robots.model import sphere_model_path
    path = sphere_model_path("ur5")
    with np.load(path, allow_pickle=False) as data:
        return path, {name: data[name] for name in data.files}


def _write(path, arrays):
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("damage, message", [
    ("integer nodes", "'nodes' must be a non-empty \\(n, 4\\) float array"),
    ("a NaN centre", "non-finite"),
    ("a zero radius", "radius must be > 0"),
    ("a child before its parent", "children must be rows after it"),
    ("a root outside the file", "'root_rows' must hold one row per link"),
    ("no meta", "not a sphere model \\(no meta\\)"),
    ("another format", "not a sphere model of this version"),
])
def test_a_sphere_model_file_that_breaks_the_format_is_refused_naming_it(tmp_path, shipped, damage, message):
    from gnn_mp_envs.robots.spheres.model import SphereModelError, load_sphere_model
    _, arrays = shipped
    arrays = {k: v.copy() for k, v in arrays.items()}
    if damage == "integer nodes":                     # loaded and answered before: 1,936 of 3,600 collisions free
        arrays["nodes"] = arrays["nodes"].astype(np.int64)
    elif damage == "a NaN centre":
        arrays["nodes"][5, 0] = np.nan
    elif damage == "a zero radius":
        arrays["nodes"][7, 3] = 0.0
    elif damage == "a child before its parent":
        inner = int(np.flatnonzero(arrays["child_count"] > 0)[3])
        arrays["first_child"][inner] = inner
    elif damage == "a root outside the file":
        arrays["root_rows"][0] = len(arrays["nodes"])
    elif damage == "no meta":
        del arrays["meta"]
    else:
        meta = json.loads(str(arrays["meta"]))
        arrays["meta"] = np.array(json.dumps({**meta, "format": "something else"}))
    path = _write(tmp_path / f"{damage.replace(' ', '_')}.npz", arrays)
    with pytest.raises(SphereModelError, match=message) as info:
        load_sphere_model(path)
    assert str(path) in str(info.value) and len(str(info.value).splitlines()) == 1


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 truncated", bytes(range(256)) * 7])
def test_an_empty_truncated_or_random_file_is_refused_naming_it(tmp_path, shipped, content):
    from gnn_mp_envs.robots.spheres.model import SphereModelError, load_sphere_model
    path = tmp_path / "model.npz"
    path.write_bytes(content or b"")
    if content == b"PK\x03\x04 truncated":
        path.write_bytes(shipped[0].read_bytes()[:5000])
    with pytest.raises(SphereModelError, match="unreadable sphere model") as info:
        load_sphere_model(path)
    assert str(path) in str(info.value) and len(str(info.value).splitlines()) == 1


def test_a_model_made_from_other_meshes_is_refused(tmp_path, shipped):
    from gnn_mp_envs.robots.catalog import ur5_model
    from gnn_mp_envs.robots.model import urdf_file
    from gnn_mp_envs.robots.spheres.checker import check_mesh_hashes
    from gnn_mp_envs.robots.spheres.model import SphereModelError, load_sphere_model
    from gnn_mp_envs.robots.urdf import read_urdf
    path, arrays = shipped
    robot = read_urdf(str(urdf_file(ur5_model().urdf)))
    check_mesh_hashes(load_sphere_model(path), robot, path)          # the shipped file: its meshes
    meta = json.loads(str(arrays["meta"]))
    mesh = next(iter(meta["mesh_sha256"]))
    meta["mesh_sha256"][mesh] = "0" * 64
    other = _write(tmp_path / "other.npz", {**arrays, "meta": np.array(json.dumps(meta))})
    with pytest.raises(SphereModelError, match=f"made from another {mesh}"):
        check_mesh_hashes(load_sphere_model(other), robot, other)


# ---------------------------------------------------------------------- the robots' facts
@pytest.mark.parametrize("robot", ["panda", "ur5", "fetch"])
def test_each_robots_facts_are_its_motionbenchmaker_data(robot):
    """``robot.json`` (the floor's) holds exactly the robot section of MotionBenchMaker's problems."""
    from gnn_mp_envs.robots.catalog import robot_facts
    from gnn_mp_envs.tasks.mbm.data import load_document
    assert robot_facts(robot) == load_document(robot)["robot"]


def test_the_catalogue_names_every_robot():
    from gnn_mp_envs.robots.catalog import ROBOTS, XARM6, robot_model
    assert list(ROBOTS) == ["xarm6", "panda", "ur5", "fetch"]
    assert robot_model("xarm6") is XARM6 and XARM6.table is not None
    assert all(robot_model(name).table is None for name in ("panda", "ur5", "fetch"))
    with pytest.raises(ValueError, match="unknown robot 'ur10e'"):
        robot_model("ur10e")
