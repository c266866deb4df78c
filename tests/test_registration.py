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
