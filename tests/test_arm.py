"""The 6-DoF arm task and GNNMP/ArmBiRRT-v0: API checkers, determinism, collision checking
(scene, table, self-collision), path validity, problem generation, client lifecycle."""

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

from gnn_mp_envs.core.planners import make_planner
from gnn_mp_envs.core.problem import InvalidProblemError, Problem
from gnn_mp_envs.robots.catalog import XARM6_HIGH as JOINT_HIGH
from gnn_mp_envs.robots.catalog import XARM6_LOW as JOINT_LOW
from gnn_mp_envs.robots.geometry import Obstacle
from gnn_mp_envs.tasks.arm import ArmProblem, ArmTask
from gnn_mp_envs.tasks.arm.scenes import SCENE_FAMILIES, sample_scene
from tests.helpers import run_uniform

ENV_ID = "GNNMP/ArmBiRRT-v0"
#: Forearm folded down so the wrist presses into the base and first link: self-collision only.
FOLDED = np.array([-1.87, 0.63, 0.05, -1.38, 1.25, 2.62])
HOME = np.array([0.0, -0.3, -0.6, 0.0, 0.9, 0.0])


@pytest.fixture(scope="module")
def task():
    t = ArmTask("test")
    yield t
    t.close()


def make_env(max_nodes=200, scene="test", **kw):
    return gym.make(ENV_ID, max_nodes=max_nodes, task_kwargs={"scene": scene}, **kw)


def run_episode(env, seed, rng_seed=0, max_steps=100_000):
    return run_uniform(env, seed=seed, rng_seed=rng_seed, max_steps=max_steps)


# ---------------------------------------------------------------------- API checkers
def test_gymnasium_checker():
    env = make_env()
    try:
        gym_check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()


def test_sb3_checker():
    from stable_baselines3.common.env_checker import check_env
    env = make_env()
    try:
        check_env(env.unwrapped, warn=False)
    finally:
        env.close()


def test_torchrl_specs():
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs
    env = GymEnv(ENV_ID, max_nodes=200, task_kwargs={"scene": "test"})
    try:
        check_env_specs(env, seed=0)
    finally:
        env.close()


def test_spaces_are_the_joint_limits():
    env = make_env()
    try:
        np.testing.assert_allclose(env.action_space.low, JOINT_LOW.astype(np.float32))
        np.testing.assert_allclose(env.action_space.high, JOINT_HIGH.astype(np.float32))
        assert env.unwrapped.max_nodes == 200
        assert gym.spec(ENV_ID).kwargs["max_nodes"] == 5000
    finally:
        env.close()


# ---------------------------------------------------------------------- determinism
def test_same_seed_same_observations():
    env_a, env_b = make_env(1000), make_env(1000)
    try:
        obs_a, info_a, _ = run_episode(env_a, seed=5, max_steps=60)
        obs_b, info_b, _ = run_episode(env_b, seed=5, max_steps=60)
        for k in obs_a:
            np.testing.assert_array_equal(obs_a[k], obs_b[k])
        assert info_a["collision_checks"] == info_b["collision_checks"]
        obs_c, _, _ = run_episode(env_a, seed=6, max_steps=5)
        assert not np.array_equal(obs_a["goal"], obs_c["goal"])
    finally:
        env_a.close()
        env_b.close()


def test_problems_are_reproducible_across_tasks(task):
    other = ArmTask("test")
    try:
        for i in range(3):
            a, b = task.problem("test", i), other.problem("test", i)
            np.testing.assert_array_equal(a.start, b.start)
            np.testing.assert_array_equal(a.goal, b.goal)
            assert a.obstacles == b.obstacles
    finally:
        other.close()


# ---------------------------------------------------------------------- validity
def test_solved_path_is_collision_free_at_checker_resolution():
    env = make_env(20000)
    try:
        for seed in (0, 1):
            _, info, terminated = run_episode(env, seed=seed)
            assert terminated and info["is_success"]
            path = info["path"]
            problem = env.unwrapped.problem
            np.testing.assert_array_equal(path[0], problem.start)
            np.testing.assert_allclose(path[-1], problem.goal)
            before = problem.collision_checks
            assert problem.path_valid(path)
            assert problem.collision_checks > before  # it really re-checked
            # Every edge within one step, and every interpolated state valid (uncounted).
            for a, b in zip(path[:-1], path[1:]):
                assert np.linalg.norm(b - a) <= problem.step_size + 1e-9
                n = int(np.ceil(np.linalg.norm(b - a) / problem.resolution))
                states = a + (b - a) * (np.arange(n + 1) / n)[:, None]
                assert problem.is_state_valid(states).all()
            assert info["path_length"] == pytest.approx(
                float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))))
    finally:
        env.close()


def test_self_collision_is_on(task):
    empty = ArmProblem(task.world, (), HOME, HOME, task.checker)
    assert empty.is_state_valid(HOME[None])[0]
    assert not empty.is_state_valid(FOLDED[None])[0]
    contacts = task.world.contacts(FOLDED)
    assert contacts and all(a == b == task.world.robot for a, b, *_ in contacts)
    # Adjacent links are never reported, even over many random configurations.
    rng = np.random.default_rng(0)
    robot_pairs = set()
    for q in rng.uniform(JOINT_LOW, JOINT_HIGH, (400, 6)):
        task.world.load(())
        robot_pairs |= {tuple(sorted((la, lb))) for a, b, la, lb, _ in task.world.contacts(q) if a == b}
    assert robot_pairs, "random configurations should include some self-collisions"
    assert all(abs(la - lb) > 1 for la, lb in robot_pairs)


def test_self_collision_flag_is_what_rejects_the_folded_arm():
    import pybullet_data
    cid = p.connect(p.DIRECT)
    try:
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        robot = p.loadURDF("xarm/xarm6_robot.urdf", useFixedBase=True, physicsClientId=cid)
        p.resetJointStatesMultiDof(robot, [1, 2, 3, 4, 5, 6], [[v] for v in FOLDED], physicsClientId=cid)
        p.performCollisionDetection(physicsClientId=cid)
        assert not [c for c in p.getContactPoints(bodyA=robot, physicsClientId=cid) if c[8] <= 0]
    finally:
        p.disconnect(cid)


def test_table_and_obstacles_collide(task):
    low_reach = np.array([0.0, 1.9, -0.5, 0.0, 0.0, 0.0])  # shoulder swung down into the table
    empty = ArmProblem(task.world, (), HOME, HOME, task.checker)
    assert not empty.is_state_valid(low_reach[None])[0]
    flange, _ = task.world.flange(HOME)
    block = (Obstacle("box", (0.05, 0.05, 0.05), tuple(flange)),)
    blocked = ArmProblem(task.world, block, HOME, HOME, task.checker)
    assert not blocked.is_state_valid(HOME[None])[0]
    assert empty.is_state_valid(HOME[None])[0]  # switching back restores the empty scene


def test_out_of_limits_is_invalid(task):
    empty = ArmProblem(task.world, (), HOME, HOME, task.checker)
    q = HOME.copy()
    q[2] = JOINT_HIGH[2] + 0.1
    assert not empty.is_state_valid(q[None])[0]


def test_stale_problem_keeps_its_own_scene(task):
    p0 = task.problem("test", 0)
    rng = np.random.default_rng(1)
    qs = rng.uniform(JOINT_LOW, JOINT_HIGH, (50, 6))
    before = p0.is_state_valid(qs)
    for i in range(1, 4):
        task.problem("test", i)  # moves/rebuilds the obstacle bodies
    np.testing.assert_array_equal(p0.is_state_valid(qs), before)


def test_check_motion_counts_like_the_base_class(task):
    """Sequentially (``bisection`` off) the fast edge check answers and counts as the base class;
    in the task's bisection order it answers the same and counts the states visited in that
    order up to the first invalid one (brute force)."""
    from gnn_mp_envs.robots.checkers import bisection_order
    problem = task.problem("test", 2)
    assert problem.bisection
    rng = np.random.default_rng(3)
    blocked = 0
    for _ in range(20):
        a = problem.start
        b = np.clip(a + rng.normal(0, 0.6, 6), JOINT_LOW, JOINT_HIGH)
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / problem.resolution)))
        valid = problem.is_state_valid(problem.interpolate(a, b, np.arange(1, n + 1) / n))
        visited = next((i + 1 for i, k in enumerate(bisection_order(n)) if not valid[k - 1]), n)
        problem.reset_counters()
        assert problem.check_motion(a, b) == bool(valid.all())
        assert problem.collision_checks == visited
        problem.bisection = False
        problem.reset_counters()
        fast = problem.check_motion(a, b)
        fast_count = problem.collision_checks
        problem.reset_counters()
        slow = Problem.check_motion(problem, a, b)
        del problem.bisection
        assert fast == slow == bool(valid.all())
        assert fast_count == problem.collision_checks
        blocked += not valid.all()
    assert 3 <= blocked <= 17


def test_check_state_counts_one(task):
    problem = task.problem("test", 0)
    problem.reset_counters()
    problem.check_state(problem.start)
    problem.check_state(FOLDED)
    assert problem.collision_checks == 2


# ---------------------------------------------------------------------- problems
@pytest.mark.parametrize("scene", ["train-a", "train-b", "test"])
def test_problems_are_valid_and_blocked(scene):
    t = ArmTask(scene)
    try:
        for i in range(5):
            pr = t.problem("train", i)
            pr.validate()
            assert pr.scene.family == scene
            assert not pr.straight_line_free(), "the straight joint-space segment must be blocked"
        assert t.unblocked_problems == 0
    finally:
        t.close()


def test_scene_families_differ():
    rng = np.random.default_rng(0)
    kinds = {f: {o.kind for _ in range(5) for o in sample_scene(f, rng).obstacles} for f in SCENE_FAMILIES}
    assert kinds["train-a"] == kinds["train-b"] == {"box"}
    assert "cylinder" in kinds["test"]
    layouts = {f: SCENE_FAMILIES[f]["layout"] for f in SCENE_FAMILIES}
    assert [layouts[f] for f in ("train-a", "train-b", "test")] == ["crevice", "shelf", "cubby"]
    # the validation and out-of-distribution kinds have layouts of their own
    for kind in ("pillars", "tall-clutter", "shelves", "bins"):
        assert layouts[kind] == kind
    assert "cylinder" in kinds["pillars"]
    with pytest.raises(ValueError):
        ArmTask("kitchen")


def test_train_mixture_draws_both_training_families():
    t = ArmTask("train")
    try:
        families = {t.problem("train", i).scene.family for i in range(8)}
        assert families == {"train-a", "train-b"}
    finally:
        t.close()


def test_invalid_given_problem_raises():
    env = make_env()
    try:
        good = env.unwrapped.task.problem("test", 0)
        obs, _ = env.reset(options={"problem": {"start": good.start, "goal": good.goal,
                                                "obstacles": list(good.obstacles)}})
        np.testing.assert_allclose(obs["start"], good.start.astype(np.float32))
        with pytest.raises(InvalidProblemError):
            env.reset(options={"problem": {"start": FOLDED, "goal": good.goal}})  # self-collision
        flange, _ = env.unwrapped.task.world.flange(good.goal)
        box = {"kind": "box", "size": (0.06, 0.06, 0.06), "position": tuple(flange)}
        with pytest.raises(InvalidProblemError):
            env.reset(options={"problem": {"start": good.start, "goal": good.goal,
                                           "obstacles": list(good.obstacles) + [box]}})
        with pytest.raises(InvalidProblemError):
            env.reset(options={"problem": {"start": good.start}})
        with pytest.raises(InvalidProblemError):
            env.reset(options={"problem": {"start": np.zeros(5), "goal": good.goal}})
    finally:
        env.close()


# ---------------------------------------------------------------------- lifecycle, render
def test_close_disconnects_the_client():
    env = make_env()
    client = env.unwrapped.task.client
    assert p.isConnected(client)
    env.reset(seed=0)
    env.close()
    assert not p.isConnected(client)
    env.close()  # idempotent


def test_each_task_has_its_own_client():
    a, b = ArmTask("train-a"), ArmTask("train-a")
    try:
        assert a.client != b.client
    finally:
        a.close()
        b.close()
    assert not p.isConnected(a.client) and not p.isConnected(b.client)


def test_render_draws_arm_scene_and_path():
    env = make_env(20000, render_mode="rgb_array")
    try:
        _, info, terminated = run_episode(env, seed=0)
        assert terminated
        img = env.render()
        assert img.shape == (360, 480, 3) and img.dtype == np.uint8
        assert img.std() > 10
        green = (img[..., 1] > 150) & (img[..., 0] < 60) & (img[..., 2] < 100)
        assert green.sum() > 50  # the flange trace of the path
    finally:
        env.close()


def test_the_render_legend_covers_only_its_corner():
    """The legend of the arm render's colours is drawn into the top-left corner
    and leaves every other pixel of the TinyRenderer image as it was (same size, no resampling)."""
    from gnn_mp_envs.robots.render import with_legend
    img = np.random.default_rng(0).integers(0, 256, (360, 480, 3), dtype=np.uint8)
    out = with_legend(img)
    assert out.shape == img.shape and out.dtype == np.uint8
    changed = (out != img).any(-1)
    rows, cols = np.nonzero(changed)
    assert changed.sum() > 2000                         # a legend box with five entries was drawn
    assert rows.max() < 360 // 4 and cols.max() < 480 // 3


# ---------------------------------------------------------------------- statistics
def test_uniform_birrt_solves_heldout_arm_problems():
    """Uniform BiRRT solves >= 90% of held-out test-scene problems within 20,000
    nodes (10 problems here; python -m tools.bench_arm measures 50)."""
    t = ArmTask("test")
    try:
        solved = 0
        for i in range(10):
            problem = t.problem("test", i)
            planner = make_planner("birrt", problem, 20000)
            rng = np.random.default_rng(i)
            while not planner.solved and not planner.tree.full and planner.iterations < 80000:
                planner.step(problem.sample_uniform(rng))
            if planner.solved:
                solved += 1
                assert problem.path_valid(planner.solution.states)
        assert solved >= 9
    finally:
        t.close()


# ---------------------------------------------------------------------- resources
def _rss_mb() -> float:
    import os
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.slow
def test_memory_stays_flat_over_many_resets():
    """Random obstacle sizes make new pybullet shapes, which pybullet never frees; the world
    rebuilds its client instead (1,000 resets within 10 MB; 26 MB before the fix)."""
    env = make_env(max_nodes=50, scene="train")
    world = env.unwrapped.task.world
    for i in range(50):
        env.reset(seed=i)
    before = _rss_mb()
    for i in range(50, 1050):
        env.reset(seed=i)
    assert _rss_mb() - before < 10.0
    assert world.rebuilds > 0 and len(world._pool) <= 64
    env.close()


def test_env_deep_copies_and_pickles_with_its_own_simulator():
    import copy
    import pickle
    env = make_env(max_nodes=300)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.step(rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32))
    clones = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    action = rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
    reference = env.step(action)
    for clone in clones:
        assert clone.unwrapped.task.world.client != env.unwrapped.task.world.client
        assert clone.unwrapped.problem.world is clone.unwrapped.task.world
        obs, _, _, _, info = clone.step(action)
        for key in obs:
            np.testing.assert_array_equal(obs[key], reference[0][key])
        assert info["collision_checks"] == reference[4]["collision_checks"]
        clone.close()
    env.close()


def test_a_typo_in_an_arm_problem_dict_is_refused():
    from gnn_mp_envs.core.problem import InvalidProblemError
    env = gym.make("GNNMP/ArmBiRRT-v0", disable_env_checker=True)
    try:
        q = np.zeros(6)
        with pytest.raises(InvalidProblemError, match="unknown key.*'obstacle'"):
            env.reset(options={"problem": {"start": q, "goal": q + 0.5, "obstacle": []}})
        with pytest.raises(InvalidProblemError, match="unknown key.*'sise'"):
            env.reset(options={"problem": {"start": q, "goal": q + 0.5,
                                           "obstacles": [{"kind": "box", "sise": [0.1] * 3, "position": [0.5] * 3}]}})
    finally:
        env.close()


def test_importing_pybullet_prints_nothing_on_stdout_or_stderr():
    """pybullet's C module prints its build time on a file descriptor at import (this build: 2); the
    arm world silences it, so a table or JSON piped from the CLI and its one-line errors stay clean."""
    import subprocess
    import sys
    code = ("import sys; sys.modules.pop('pybullet', None)\n"
            "from gnn_mp_envs.robots import XARM6, RobotWorld\n"
            "RobotWorld(XARM6); print('clean')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout == "clean\n" and "build time" not in result.stderr, result.stderr


def test_a_collision_answer_does_not_depend_on_the_queries_before_it():
    """Configurations on the collision boundary (bisected to ~1e-7 rad) get the same answer
    checked alone (after a far configuration) and at the end of a sweep arriving from the other
    side, and a grazing edge with valid ends gets the same answer in both directions (pybullet's
    persistent contacts must not leak between queries)."""
    from gnn_mp_envs.registration import make_task
    task = make_task("arm", scene="test", checker="pybullet")     # pybullet's contact history
    rng = np.random.default_rng(3)
    boundary = edges = 0
    for idx in range(2):
        prob = task.problem("test", idx)
        w, lo, hi = prob.world, prob.low, prob.high
        while boundary < 20 * (idx + 1):
            a, b = rng.uniform(lo, hi), rng.uniform(lo, hi)
            ca = w.collides(a)
            if ca == w.collides(b):
                continue
            free, hit = (b, a) if ca else (a, b)
            for _ in range(25):
                m = (free + hit) / 2
                if w.collides(m):
                    hit = m
                else:
                    free = m
            for q, other in ((free, hit), (hit, free)):
                w.collides((lo + hi) / 2)
                alone = w.collides(q)
                for s in np.linspace(0.0, 1.0, 5):
                    w.collides(other + (q - other) * s)
                assert w.collides(q) == alone
            boundary += 1
            for _ in range(10):                  # a short edge through the boundary region, both ends valid
                d = rng.normal(size=6)
                d *= 0.02 / np.linalg.norm(d)
                p0, p1 = free - d, free + d
                if not (w.collides(p0) or w.collides(p1)):
                    assert prob.check_motion(p0, p1) == prob.check_motion(p1, p0)
                    edges += 1
                    break
    task.close()
    assert boundary == 40 and edges > 0


def test_grazing_edges_get_one_answer_in_both_directions_and_state_by_state():
    """The history probe's procedure (../shared/probes/arm_checker_history.py --grazing): edges from a
    valid configuration to the last valid state before a contact (bisected to 1e-6 rad) get the
    same verdict checked forwards and backwards, and every state of the sweep the same answer as a
    fresh check of it after an unrelated configuration (pybullet's contact
    cache must not leak between queries)."""
    from gnn_mp_envs.registration import make_task
    task = make_task("arm", scene="test", checker="pybullet")     # pybullet's contact history
    edges = states = 0
    for i in range(5):                          # the probe's 5 problems x 200 grazing edges
        p = task.problem("test", i)
        w = p.world
        w.load(p.scene)
        rng = np.random.default_rng([9299, i])
        found = 0
        while found < 200:
            a = rng.uniform(p.low, p.high)
            if w.collides(a.tolist()):
                continue
            d = rng.normal(size=6)
            b = np.clip(a + p.step_size * d / np.linalg.norm(d), p.low, p.high)
            if not w.collides(b.tolist()):
                continue
            lo, hi = 0.0, 1.0
            while (hi - lo) * p.step_size > 1e-6:
                mid = 0.5 * (lo + hi)
                w.collides([0.0] * 6)
                if w.collides((a + mid * (b - a)).tolist()):
                    hi = mid
                else:
                    lo = mid
            b = a + lo * (b - a)
            w.collides([0.0] * 6)
            if w.collides(b.tolist()) or np.linalg.norm(b - a) < 2 * p.resolution:
                continue
            found += 1
            assert p.check_motion(a, b) == p.check_motion(b, a), (i, a.tolist(), b.tolist())
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / p.resolution)))
            w.collides([0.0] * 6)
            sweep = [w.collides((a + (k / n) * (b - a)).tolist()) for k in range(1, n + 1)]
            for k, answer in enumerate(sweep, 1):
                w.collides([0.0] * 6)
                assert w.collides((a + (k / n) * (b - a)).tolist()) == answer
            states += n
        edges += found
    task.close()
    assert edges == 1000 and states > 5000


@pytest.fixture
def restored_scene_families():
    """Scene families registered by a test are gone after it (the shipped ones are asserted elsewhere)."""
    from gnn_mp_envs.registration import TASK_SPECS
    from gnn_mp_envs.tasks.arm.scenes import LAYOUTS
    saved = dict(SCENE_FAMILIES), dict(LAYOUTS), TASK_SPECS["arm"]
    yield
    for table, copy in zip((SCENE_FAMILIES, LAYOUTS), saved[:2]):
        table.clear()
        table.update(copy)
    TASK_SPECS["arm"] = saved[2]


def test_scene_families_are_added_by_name(restored_scene_families):
    """A family registered from outside the package (tests/arm_family.py: a shipped layout with other
    ranges, and a layout of its own) is planned by name everywhere: the task, gym.make, the benchmark."""
    import importlib

    import gymnasium as gym

    from gnn_mp_envs.tasks.arm import register_scene_family
    from tests import arm_family
    from train import benchmark as bm
    importlib.reload(arm_family)                    # registers (again: the fixture drops them after each test)
    scene = sample_scene("narrow-crevice", np.random.default_rng(1))
    assert 0.14 <= scene.meta["gap"] <= 0.16
    env = gym.make("GNNMP/ArmBiRRT-v0", scene="lone-wall", split="test", disable_env_checker=True)
    try:
        env.reset(options={"index": 0})
        assert env.unwrapped.task.scene == "lone-wall"
        assert [ob.kind for ob in env.unwrapped.problem.scene.obstacles] == ["box"]
    finally:
        env.close()
    report = bm.run_benchmark(bm.BenchmarkArgs(task="arm", scene="lone-wall", samplers=["uniform"], problems=2,
                                               progress=False))
    assert len(report["runs"]["uniform"]) == 2
    with pytest.raises(ValueError, match="already exists"):
        register_scene_family("lone-wall", {})
    with pytest.raises(ValueError, match="unknown layout"):
        register_scene_family("nowhere", {"layout": "spiral"})
    with pytest.raises(ValueError, match="failed on a first draw"):
        register_scene_family("broken", {"layout": "crevice"})          # no ranges for the crevice layout
    with pytest.raises(ValueError, match="'train'"):
        register_scene_family("train", dict(SCENE_FAMILIES["train-a"]))


def test_a_parked_tower_does_not_reach_the_next_problem():
    """An obstacle taller than 100 m, parked below the table between problems, reached the robot
    in the next problem (its start was 'in collision'); parked bodies now wait their own size below
    the table, so the next problem sees what a fresh world sees."""
    import gymnasium as gym
    start, goal = [0.0, 0.3, -0.6, 0.0, 0.3, 0.0], [1.0, 0.3, -0.6, 0.0, 0.3, 0.0]
    tower = {"kind": "box", "size": [0.05, 0.05, 120.0], "position": [2.0, 2.0, 0.0]}
    env = gym.make("GNNMP/ArmBiRRT-v0", disable_env_checker=True)
    try:
        env.reset(options={"problem": {"start": start, "goal": goal, "obstacles": [tower]}})
        env.reset(options={"problem": {"start": start, "goal": goal, "obstacles": []}})
        world = env.unwrapped.task.world
        assert world.contacts(np.array(start)) == []
    finally:
        env.close()


def test_tool_quaternion_is_scipys_rotation():
    """The arm's hand-written quaternion product stays (scipy's Rotation differs in the last bit for
    72% of orientations, and IK turns that into other goals: 0 of 90 arm problems kept their start
    and goal, so every arm counter would move); scipy is its oracle here."""
    from scipy.spatial.transform import Rotation

    from gnn_mp_envs.robots.geometry import tool_quaternion
    rng = np.random.default_rng(0)
    axes = [*rng.normal(size=(200, 3)), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)]
    for axis in axes:
        roll = float(rng.uniform(-np.pi, np.pi))
        q = Rotation.from_quat(tool_quaternion(tuple(axis), roll))
        z = np.asarray(axis) / np.linalg.norm(axis)
        np.testing.assert_allclose(q.apply([0.0, 0.0, 1.0]), z, atol=1e-12)           # the tool axis
        align, _ = Rotation.align_vectors([z], [[0.0, 0.0, 1.0]])
        expected = align * Rotation.from_euler("z", roll)
        assert (q.inv() * expected).magnitude() < 1e-9 or abs(z[2]) > 1 - 1e-9     # same rotation (off the poles)
