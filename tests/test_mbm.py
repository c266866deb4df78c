"""MotionBenchMaker's Panda problems: the shipped file against problems transcribed by hand from
VAMP's YAML files, the robot model, the splits, validity of all 700 problems, and the env."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from gnn_mp_envs.robots import catalog
from gnn_mp_envs.robots.model import model_dir
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
    from tests.helpers import assert_problem_equals_yaml
    assert_problem_equals_yaml(json.loads(mbm_data.DATA_FILE.read_text()), "panda", scene, file, start, goal,
                               objects)


def test_moveit_primitives_become_obstacles():
    """Box dimensions are full lengths (half extents here), cylinders are [height, radius] in MoveIt."""
    box = mbm_data.obstacle("box", [0.7, 0.7, 0.04], [1, 2, 3, 0, 0, 0, 1])
    assert box.size == (0.35, 0.35, 0.02) and box.position == (1, 2, 3) and box.quaternion() == (0, 0, 0, 1)
    can = mbm_data.obstacle("cylinder", [0.12, 0.03], [0, 0, 0, 0, 0, 0.6, 0.8])
    assert can.size == (0.03, 0.12) and can.quaternion() == (0, 0, 0.6, 0.8)
    assert mbm_data.obstacle("sphere", [0.1], [0, 0, 0, 0, 0, 0, 1]).size == (0.1,)


def test_the_panda_model_matches_the_urdf_joint_names():
    from gnn_mp_envs.robots.world import import_pybullet
    p = import_pybullet()
    import pybullet_data
    cid = p.connect(p.DIRECT)
    try:
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        robot = p.loadURDF(catalog.PANDA_URDF, useFixedBase=True, physicsClientId=cid)
        names = [p.getJointInfo(robot, j, physicsClientId=cid)[1].decode() for j in catalog.PANDA_JOINTS]
        assert names == [f"panda_joint{k}" for k in range(1, 8)]
        assert {n: p.getJointInfo(robot, j, physicsClientId=cid)[1].decode()
                for n, j in catalog.PANDA_FINGERS.items()} == {n: n for n in catalog.PANDA_FINGERS}
        assert p.getJointInfo(robot, catalog.PANDA_HAND, physicsClientId=cid)[12].decode() == "panda_hand"
    finally:
        p.disconnect(cid)
    model = catalog.panda_model()
    assert model.low[3] == -3.1416 and model.high[3] == 0.0873     # MBM's URDF, not pybullet_data's 0.0
    assert dict(model.held_joints) == {9: 0.065, 10: 0.065}
    assert len(model.allowed_collisions) == 34 and ("panda_hand", "panda_link7") in model.allowed_collisions


# ---------------------------------------------------------------------- the task

@pytest.fixture(scope="module")
def task():
    from gnn_mp_envs.tasks.mbm import PandaMBMTask
    t = PandaMBMTask("all")
    yield t
    t.close()


def test_every_start_and_goal_is_valid_under_the_shipped_model(task):
    """All 700 problems are kept (EXCLUDED is empty): start and goal inside the limits and free."""
    from gnn_mp_envs.tasks.mbm import EXCLUDED
    assert EXCLUDED == {}
    count = 0
    for split in ("train", "val", "test"):
        for i in range(len(task.split_records(split))):
            problem = task.problem(split, i)
            assert problem.is_state_valid(np.stack([problem.start, problem.goal])).all(), (split, i)
            count += 1
    assert count == 700


def test_splits_walk_the_scenes_round_robin(task):
    from gnn_mp_envs.tasks.mbm import PandaMBMTask
    assert [task.num_problems(s) for s in ("val", "test")] == [70, 210] and task.num_problems("train") is None
    assert len(task.split_records("train")) == 420
    firsts = [task.problem("test", i) for i in range(8)]
    assert [p.family for p in firsts] == list(mbm_data.SCENES) + ["table_pick"]
    assert [p.mbm_file for p in firsts] == [71] * 7 + [72]
    assert task.problem("val", 69).mbm_file == 70 and task.problem("train", 419).mbm_file == 60
    cage = PandaMBMTask("cage")
    try:
        assert [cage.problem("test", i).mbm_file for i in (0, 29)] == [71, 100]
        with pytest.raises(ValueError, match="has 30 problems"):
            cage.problem("test", 30)
        held_out = PandaMBMTask("test")
        assert {held_out.problem("test", i).family for i in range(60)} == {"bookshelf_thin", "cage"}
        seen = PandaMBMTask("train")
        assert {seen.problem("train", i).family for i in range(300)} == set(mbm_data.SCENES) - {"bookshelf_thin", "cage"}
        held_out.close()
        seen.close()
    finally:
        cage.close()


def test_perturbed_training_problems_move_the_goal_with_the_scene(task):
    """Training problems past MBM's own are rigidly moved copies: the goal's hand pose relative to the
    scene's first object is the template's (re-solved by IK), start and goal are valid."""
    from gnn_mp_envs.tasks.mbm.task import PERTURB_SHIFT, PERTURB_YAW
    from scipy.spatial.transform import Rotation
    records = task.split_records("train")
    for index in (420, 421, 425):
        problem = task.problem("train", index)
        template = records[index % len(records)]
        assert problem.family == template.scene and problem.mbm_file == 0
        assert problem.is_state_valid(np.stack([problem.start, problem.goal])).all()

        def hand_in_object(q, obstacle):
            position, quat = task.world.flange_pose(q)
            frame = Rotation.from_quat(obstacle.quaternion())
            return frame.inv().apply(position - np.asarray(obstacle.position)), (frame.inv() * Rotation.from_quat(quat))

        moved, moved_rot = hand_in_object(problem.goal, problem.obstacles[0])
        kept, kept_rot = hand_in_object(np.asarray(template.goal), template.obstacles[0])
        np.testing.assert_allclose(moved, kept, atol=2e-3)
        assert (moved_rot.inv() * kept_rot).magnitude() < 2e-2
        shift = np.asarray(problem.obstacles[0].position) - np.asarray(template.obstacles[0].position)
        assert 0 < np.abs(shift).max() <= np.hypot(*template.obstacles[0].position[:2]) * PERTURB_YAW + max(PERTURB_SHIFT)


def test_the_fine_path_check_catches_what_the_planners_resolution_skips(task):
    """A hand-made edge that passes through a thin wall between its two checked ends: the planner's
    check (one state per resolution step) and the path re-check at that resolution pass it, the
    independent check at 10x finer resolution does not."""
    from gnn_mp_envs.robots.geometry import Obstacle
    from gnn_mp_envs.tasks.mbm import MBMProblem
    middle = np.array([0, -0.785, 0, -2.356, 0, 1.571, 0.785])
    a, b = middle.copy(), middle.copy()
    a[0], b[0] = -0.8, 0.8                                             # the hand swings past x = 0.31 m
    wall = Obstacle("box", (0.03, 0.003, 0.03), tuple(task.world.flange_pose(middle)[0]))   # 6 mm thick
    problem = MBMProblem(task.world, (wall,), a, b, task.checker, step_size=2.0, resolution=2.0)
    assert problem.is_state_valid(np.stack([a, b])).all()
    assert not problem.is_state_valid(middle[None]).all()
    assert problem.check_motion(a, b)                                  # n = 1: only b is checked
    assert problem.path_valid(np.stack([a, b]))
    assert not problem.path_valid(np.stack([a, b]), refine=10)


@pytest.mark.parametrize("checker, free_at", [("pybullet", 0.0025), ("spheres", 0.008)])
def test_the_padding_is_a_margin_of_the_planner_only(task, checker, free_at):
    """A state 0.5 mm from an obstacle collides for the planner (pybullet: a 1 mm margin; spheres:
    that margin and the spheres' overshoot) but not for the exact check; farther away (pybullet:
    2.5 mm; spheres: beyond the margin plus the largest overshoot, 8 mm) it is free for both."""
    from gnn_mp_envs.robots.checkers import make_checker
    from gnn_mp_envs.robots.geometry import Obstacle
    from gnn_mp_envs.tasks.mbm import MBMProblem
    world = task.world
    q = np.array([0, -0.785, 0, -2.356, 0, 1.571, 0.785])
    hand = world.flange_pose(q)[0]

    def slab(z: float) -> Obstacle:
        return Obstacle("box", (0.15, 0.15, 0.01), (hand[0], hand[1], z))

    def clearance(z: float) -> float:
        """The robot's distance to the slab at height z (getClosestPoints, the oracle)."""
        world.load((slab(z),))
        world.set_config(q)
        points = world.p.getClosestPoints(world.robot, world.obstacle_bodies[0], 0.05, physicsClientId=world.client)
        return min((c[8] for c in points), default=0.05)

    for target, planner_free in ((0.0005, False), (free_at, True)):
        low, high = hand[2] - 0.4, hand[2]                             # free below, touching above
        for _ in range(40):
            z = (low + high) / 2
            low, high = (z, high) if clearance(z) > target else (low, z)
        problem = MBMProblem(world, (slab(low),), q, q + 0.1, make_checker(checker, world))
        assert abs(clearance(low) - target) < 1e-4
        assert problem.is_state_valid(q[None]).all() == planner_free
        assert problem.is_state_valid_exact(q[None]).all()


# ---------------------------------------------------------------------- the environment

def test_the_environment_follows_the_arm_envs_interface():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import gnn_mp_envs  # noqa: F401
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import plan_problem
    env = gym.make("GNNMP/PandaMBM-v0", split="test", render_mode="rgb_array", disable_env_checker=True)
    base = env.unwrapped
    try:
        with warnings.catch_warnings():      # the checker's generic advice on unbounded boxes and [-1, 1] actions
            warnings.simplefilter("ignore", UserWarning)
            check_env(base, skip_render_check=True)
        model = catalog.panda_model()
        np.testing.assert_allclose(env.action_space.low, np.float32(model.low))
        np.testing.assert_allclose(env.action_space.high, np.float32(model.high))
        assert env.observation_space["obstacles"].shape == (21, 1 + 13)     # presence flag + 13 features
        for seed in range(5):                       # a reset without an index stays inside the 210 problems
            obs, _ = env.reset(seed=seed)
            assert base.problem.mbm_file in range(71, 101)
        record = plan_problem(base, load_sampler("uniform", task="panda-mbm", seed=0), 0, seed=0)
        assert record.success and base.problem.family == "table_pick" and base.problem.mbm_file == 71
        obs = base._observation()
        rows = obs["obstacles"][: len(base.problem.obstacles)]
        assert (rows[:, 0] == 1).all() and not obs["obstacles"][len(rows):].any()
        assert rows[:, 1:4].sum(axis=1).tolist() == [1.0] * len(rows)                    # one kind each
        assert (rows[:, 13] >= 0).all()                                                  # w >= 0
        image = env.render()
        assert image.shape == (360, 480, 3) and image.std() > 10
    finally:
        env.close()


def test_the_benchmark_refuses_more_problems_than_the_split_holds():
    from train.benchmark.args import BenchmarkArgs, BenchmarkError
    from train.benchmark.runs import run_benchmark
    with pytest.raises(BenchmarkError, match="split 'test' of panda-mbm scene 'cage' has 30 problems"):
        run_benchmark(BenchmarkArgs(task="panda-mbm", samplers=["uniform"], problems=31, scene="cage",
                                    progress=False))


def test_field_tables_count_solved_within_the_node_budget(tmp_path):
    """A hand-made report: a run over the node budget is not solved (one over the time budget is: the
    time is no part of success, the success-vs-time figure shows it); the per-scene table has a row
    per scene and sampler; the success-vs-time plot is written."""
    from train.benchmark.plots import plot_success_vs_time
    from train.benchmark.stats import sampler_summary
    from train.benchmark.tables import families_of, format_family_table, format_field_table

    def run(problem, family, success=True, nodes=50, wall=0.5, iterations=40):
        return {"problem": problem, "family": family, "success": success, "nodes_expanded": nodes, "edges": nodes,
                "collision_checks": 10 * nodes, "iterations": iterations, "path_length": 5.0 if success else None,
                "wall_time_s": wall}
    runs = {"uniform": [run(0, "cage"), run(1, "box", wall=11.0), run(2, "cage", nodes=6000), run(3, "box")],
            "gnn": [run(0, "cage"), run(1, "box"), run(2, "cage", success=False), run(3, "box", iterations=10)]}
    report = {"task": "panda-mbm", "problems": 4, "seed": 0, "max_nodes": 5000, "time_limit_s": 10.0,
              "results": {n: sampler_summary(r, 5000) for n, r in runs.items()}, "runs": runs}
    field = format_field_table(report)
    assert "solved = a path found within 5,000 nodes that passes the re-check" in field
    assert [line.split()[1] for line in field.splitlines()[3:5]] == ["3/4", "3/4"]
    assert families_of(report) == ["cage", "box"]
    rows = [line.split() for line in format_family_table(report).splitlines()[3:]]
    assert [(r[0], r[1], r[2], r[3]) for r in rows] == [("cage", "uniform", "1/2", "40"), ("cage", "gnn", "1/2", "40"),
                                                        ("box", "uniform", "2/2", "40"), ("box", "gnn", "2/2", "25")]
    plot_success_vs_time(report, tmp_path / "svt.png")
    assert (tmp_path / "svt.png").stat().st_size > 1000


def test_edges_are_checked_in_bisection_order_with_the_same_verdict(task):
    """MBM edges are checked as OMPL's DiscreteMotionValidator does (far end, then bisection): the
    verdict equals the state-by-state check of every interpolated state, and the count is the
    number of states visited in that order up to the first invalid one (brute force)."""
    from gnn_mp_envs.robots.checkers import bisection_order
    for n in range(1, 40):
        order = bisection_order(n)
        assert order[0] == n and sorted(order) == list(range(1, n + 1))
    problem = task.problem("test", 6)                                  # cage
    rng = np.random.default_rng(0)
    low, high = task.state_bounds()
    blocked = 0
    for _ in range(30):
        a = problem.start if rng.random() < 0.5 else problem.goal
        b = np.clip(a + rng.normal(0.0, 0.5, 7), low, high)
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / problem.resolution)))
        valid = problem.is_state_valid(problem.interpolate(a, b, np.arange(1, n + 1) / n))
        visited = next((i + 1 for i, k in enumerate(bisection_order(n)) if not valid[k - 1]), n)
        before = problem.collision_checks
        assert problem.check_motion(a, b) == bool(valid.all())
        assert problem.collision_checks - before == visited
        blocked += not valid.all()
    assert 5 <= blocked <= 25
