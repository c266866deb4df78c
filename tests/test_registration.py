"""Tasks register from outside the package; the rollout helper and the path's node indices."""

from __future__ import annotations

import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

from agents.samplers import load_sampler
from gnn_mp_envs.registration import TASK_SPECS, task_spec
from gnn_mp_envs.rollout import rollout, run_steps
from tests import tiny_task  # noqa: F401  (registers "tiny" and its env ids)
from train import benchmark as bm


def test_an_outside_task_runs_through_gym_make():
    env = gym.make("Tiny/TinyRRT-v0", split="test")
    assert env.unwrapped.max_nodes == 400
    sampler = load_sampler("uniform", bounds=(env.action_space.low, env.action_space.high), seed=0)
    record = rollout(env, sampler.act, seed=0, options={"index": 0})
    assert record.success and record.nodes_expanded <= 400


def test_an_outside_task_runs_through_the_benchmark():
    report = bm.run_benchmark(bm.BenchmarkArgs(task="tiny", samplers=["uniform", "goal-bias"], problems=3,
                                               progress=False))
    assert report["env_id"] == "Tiny/TinyRRT-v0" and report["max_nodes"] == 400
    assert all(r["success"] for rs in report["runs"].values() for r in rs)


def test_the_cli_imports_an_outside_task_in_every_worker(tmp_path):
    out = tmp_path / "tiny.json"
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, "benchmark", "--import", "tests.tiny_task", "--task", "tiny",
                             "--samplers", "uniform", "--problems", "2", "--workers", "2", "--no-progress",
                             "--json", str(out)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert [r["problem"] for r in json.loads(out.read_text())["runs"]["uniform"]] == [0, 1]


def test_builtin_specs_know_their_facts():
    assert task_spec("pendulum").env_id == "GNNMP/PendulumRRT-v0" and task_spec("pendulum").max_nodes == 20000
    assert task_spec("arm").benchmark_scene == "test"
    from gnn_mp_envs.tasks.arm import SCENE_FAMILIES, TRAIN_FAMILIES
    assert set(task_spec("arm").scenes) == set(SCENE_FAMILIES) | {"train"}
    assert set(TRAIN_FAMILIES) < set(SCENE_FAMILIES)
    with pytest.raises(ValueError, match="known: .*maze2d"):
        task_spec("nope")
    assert {"maze2d", "pendulum", "arm", "tiny"} <= set(TASK_SPECS)


@pytest.mark.parametrize("env_id", ["GNNMP/Maze2DRRT-v0", "GNNMP/Maze2DBiRRT-v0", "GNNMP/PendulumRRT-v0"])
def test_path_nodes_are_the_path_through_the_tree(env_id):
    env = gym.make(env_id, split="test", copy_observations=False)
    sampler = load_sampler("uniform", bounds=(env.action_space.low, env.action_space.high), seed=1)
    record = rollout(env, sampler.act, seed=1, options={"index": 2})
    assert record.success
    tree = env.unwrapped.planner.tree
    nodes = np.asarray(record.path_nodes)
    np.testing.assert_array_equal(tree.states[nodes], env.unwrapped.planner.solution.states)
    # Consecutive path nodes are tree edges (parent -> child), except where BiRRT's two trees meet.
    linked = [tree.parent[b] == a or tree.parent[a] == b for a, b in zip(nodes[:-1], nodes[1:])]
    assert sum(not x for x in linked) == (1 if "BiRRT" in env_id else 0)
    assert nodes[0] == 0 and (nodes[-1] == 1 if "BiRRT" in env_id else True)


def test_run_steps_stops_where_asked_and_times_the_env():
    env = gym.make("GNNMP/Maze2DRRT-v0", split="test")
    obs, _ = env.reset(seed=0, options={"index": 0})
    sampler = load_sampler("uniform", bounds=(env.action_space.low, env.action_space.high), seed=0)
    result = run_steps(env, sampler.act, obs, max_steps=7)
    assert result.steps == 7 and result.info["iterations"] == 7
    assert 0 < result.env_time_s <= result.wall_time_s
    stopped = run_steps(env, sampler.act, result.observation, on_step=lambda o, info, done: info["iterations"] >= 10)
    assert stopped.steps == 3


# ---------------------------------------------------------------------------- every per-task fact on the TaskSpec
@pytest.mark.parametrize("task", ["maze2d", "pendulum", "arm", "tiny"])
def test_spec_facts_agree_with_the_task_itself(task):
    """The facts a TaskSpec states for learned samplers are the task's own: bounds = the env's action
    box, the periodic coordinates are the ones ``normalize`` wraps, the metric weights are those of
    ``distance``, the step scale (where it names the extension) the problems' step size."""
    spec = task_spec(task)
    env = gym.make(spec.env_id, split="val", disable_env_checker=True)
    env.reset(seed=0, options={"index": 0})
    problem = env.unwrapped.problem
    low, high = spec.state_bounds()
    np.testing.assert_array_equal(low, env.action_space.low)
    np.testing.assert_array_equal(high, env.action_space.high)
    d = len(low)
    probe = problem.low + 1.25 * (problem.high - problem.low)          # a quarter period beyond the box
    wraps = ~np.isclose(problem.normalize(probe), probe)
    np.testing.assert_array_equal(wraps, spec.periodic_mask(d))
    weights = np.asarray(spec.metric_weights or [1.0] * d)
    for axis in range(d):
        step = np.zeros(d)
        step[axis] = 0.1
        a = (problem.low + problem.high) / 2
        assert problem.distance((a + step)[None], a)[0] == pytest.approx(0.1 * weights[axis])
    if spec.step_scale is not None and problem.geometric:
        assert spec.step_scale == pytest.approx(problem.step_size)
    assert spec.num_trees() == (2 if spec.planner() == "birrt" else 1)
    env.close()


def test_an_outside_task_trains_and_its_sampler_benchmarks(tmp_path):
    """A task registered from outside the package (tests/tiny_task.py, no edit of package source) is
    trained by ``gnn-mp train sampler`` into a run directory and benchmarked with the result."""
    run = tmp_path / "run"
    code = "import sys; from train.cli import main; sys.exit(main())"
    train = subprocess.run([sys.executable, "-c", code, "train", "sampler", "--import", "tests.tiny_task", "--task",
                            "tiny", "--model", "gnn", "--problems", "6", "--minutes", "0.05", "--dagger-rounds", "0",
                            "--eval-problems", "2", "--data-dir", str(tmp_path / "data"), "--out", str(run),
                            "--no-progress"], capture_output=True, text=True, timeout=600)
    assert train.returncode == 0, train.stderr[-2000:]
    for name in ("model.pt", "model.json", "config.json", "learning_curve.png"):
        assert (run / name).is_file(), name
    summary = json.loads(train.stdout)
    assert summary["run_dir"] == str(run) and summary["validation"]["gnn"]["problems"] == 2
    out = tmp_path / "tiny.json"
    bench = subprocess.run([sys.executable, "-c", code, "benchmark", "--import", "tests.tiny_task", "--task", "tiny",
                            "--samplers", "uniform,gnn", "--checkpoint", f"gnn={run / 'model.pt'}", "--problems", "3",
                            "--no-progress", "--json", str(out)], capture_output=True, text=True, timeout=600)
    assert bench.returncode == 0, bench.stderr[-2000:]
    runs = json.loads(out.read_text())["runs"]
    assert [r["problem"] for r in runs["gnn"]] == [0, 1, 2] and all(r["success"] for r in runs["gnn"])
    again = subprocess.run([sys.executable, "-c", code, "train", "sampler", "--import", "tests.tiny_task", "--task",
                            "tiny", "--out", str(run)], capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and "already holds a run" in again.stderr    # a finished run is not overwritten


def test_a_task_in_a_shipped_state_space_borrows_its_weights_with_weights_from():
    """Your own maps in maze2d's state space: with weights_from="maze2d" the
    shipped learned samplers load and plan there; without it they are refused in one line naming
    the remedy; a task with other state bounds cannot borrow them."""
    from pathlib import Path

    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problems, summarize
    from gnn_mp_envs.registration import TaskSpec, register_task
    from gnn_mp_envs.tasks.maze2d import Maze2DTask
    specs = [TaskSpec("own-maze", Maze2DTask, envs={"Own/OwnMazeRRT-v0": {"planner": "rrt"}}, weights_from="maze2d"),
             TaskSpec("own-maze-plain", Maze2DTask, envs={"Own/OwnMazePlainRRT-v0": {"planner": "rrt"}}),
             TaskSpec("tiny-borrowing", tiny_task.TinyTask, envs={"Tiny/TinyBorrowRRT-v0": {"planner": "rrt"}},
                      max_nodes=400, weights_from="maze2d")]
    try:
        for spec in specs:
            register_task(spec, replace=True)
        env = evaluation_env("own-maze", "test")
        for name in ("gnn", "cvae", "gnn-cvae", "rl-ppo"):
            row = summarize(plan_problems(load_sampler(name, task="own-maze", seed=0), env, range(2), 0))
            assert row["success_rate"] == 1.0, name
        shipped = Path(__file__).resolve().parents[1] / "agents" / "checkpoints" / "gnn_maze2d.pt"
        with pytest.raises(ValueError, match="weights_from='maze2d'"):
            load_sampler("gnn", task="own-maze-plain", checkpoint=str(shipped))
        with pytest.raises(ValueError, match="state bounds differ"):
            load_sampler("gnn", task="tiny-borrowing")
        with pytest.raises(ValueError, match="unknown task 'no-such'"):
            register_task(TaskSpec("x-task", Maze2DTask, envs={"X/X-v0": {}}, weights_from="no-such"))
    finally:                  # other tests enumerate the registered tasks
        for spec in specs:
            TASK_SPECS.pop(spec.name, None)
            for env_id in spec.envs:
                gym.registry.pop(env_id, None)


def test_same_bounds_is_the_one_comparison_of_state_boxes():
    """Hand-made cases: float32 rounding passes; another value, another dimension or a swapped pair fail."""
    from gnn_mp_envs.registration import same_bounds
    box = (np.zeros(2), np.ones(2))
    assert same_bounds(box, (np.zeros(2, np.float32), np.ones(2, np.float32)))
    assert same_bounds((np.array([-np.pi, -8.0]), np.array([np.pi, 8.0])),
                       (np.array([-np.pi, -8.0], np.float32), np.array([np.pi, 8.0], np.float32)))
    assert not same_bounds(box, (np.zeros(2), np.array([1.0, 1.01])))
    assert not same_bounds(box, (np.zeros(3), np.ones(3)))
    assert not same_bounds(box, (np.ones(2), np.zeros(2)))
    assert not same_bounds(box, (np.zeros(2), np.ones(3)))


def test_register_scene_adds_a_scene_to_the_spec_and_leaves_the_env_ids():
    """register_scene is the one way a task's module adds a scene family by name: the spec's scenes
    (and, on request, its validation or OOD scenes) grow; the Gymnasium entries stay the same objects."""
    from gnn_mp_envs.registration import register_scene
    before = task_spec("maze2d")
    entries = {env_id: gym.registry[env_id] for env_id in before.envs}
    try:
        assert register_scene("maze2d", "walls") is before                  # a known scene: unchanged
        spec = register_scene("maze2d", "my-walls", ood=True)
        assert task_spec("maze2d") is spec and spec.scenes == (*before.scenes, "my-walls")
        assert spec.ood_scenes == (*before.ood_scenes, "my-walls") and spec.validation_scenes == before.validation_scenes
        assert {env_id: gym.registry[env_id] for env_id in before.envs} == entries
        assert all(gym.registry[env_id] is entry for env_id, entry in entries.items())
        with pytest.raises(ValueError, match="unknown task"):
            register_scene("no-such-task", "x")
        with pytest.raises(ValueError, match="both"):
            register_scene("maze2d", "x", validation=True, ood=True)
        with pytest.raises(ValueError, match="non-empty name"):
            register_scene("maze2d", "")
    finally:
        TASK_SPECS["maze2d"] = before


def test_registry_entries_named_by_string_are_imported_once():
    """``"module:attribute"`` entries (task classes, encoders, priors, foreign checkpoint readers) are
    imported on first use and stored back; a malformed name is one ValueError."""
    import json

    from gnn_mp_envs.utils.imports import import_entry, resolved
    assert import_entry("json:dumps") is json.dumps
    registry = {"dumps": "json:dumps"}
    assert resolved(registry, "dumps") is json.dumps and registry["dumps"] is json.dumps
    for bad in ("json", "json:", ":dumps"):
        with pytest.raises(ValueError, match="module:attribute"):
            import_entry(bad)
