"""What a user takes away from a run: the returned paths (``gnn-mp benchmark --save-paths``), the
tree (``TreePlanningEnv.export_tree`` and ``agents.nn.graph.tree_data``), the success-vs-time figure
and the Planner Arena log of a ``--task`` run, and a benchmark without its re-check
(``--no-recheck``) that says so."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import gnn_mp_envs  # noqa: F401  (registers the ids)
from train import benchmark as bm
from train import cli

BENCH = ["benchmark", "--task", "maze2d", "--samplers", "uniform,goal-bias", "--problems", "3", "--seed", "3",
         "--max-nodes", "300", "--no-progress"]


def solved_rollout(env_id: str, index: int = 0, seed: int = 0, **kwargs):
    """A uniform rollout of problem ``index`` until solved; the env, last observation and info."""
    env = gym.make(env_id, split="test", **kwargs)
    obs, info = env.reset(seed=seed, options={"index": index})
    env.action_space.seed(seed)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        done = terminated or truncated
    assert info["is_success"], env_id
    return env, obs, info


def test_save_paths_stores_each_solved_runs_returned_path(tmp_path, capsys):
    """Every solved run's path in the JSON: from the problem's start into its goal, valid edge by edge
    under the problem's own checker, its length the run's path_length; an unsolved run's is null.
    Without --json the flag is refused in one line."""
    from gnn_mp_envs.registration import make_task
    out = tmp_path / "r.json"
    assert cli.main([*BENCH, "--json", str(out), "--save-paths"]) == 0
    report = json.loads(out.read_text())
    task = make_task("maze2d", scene="walls")
    runs = [r for rows in report["runs"].values() for r in rows]
    assert sum(r["success"] for r in runs) >= 3 and not all(r["success"] for r in runs)   # both kinds seen
    for r in runs:
        if not r["success"]:
            assert r["path"] is None and r["path_controls"] is None
            continue
        problem, path = task.problem("test", r["problem"]), np.array(r["path"])
        assert path.shape[1] == 2 and np.array_equal(path[0], problem.start) and problem.in_goal(path[-1])
        assert problem.path_valid(path) is True and r["path_controls"] is None
        assert np.linalg.norm(np.diff(path, axis=0), axis=1).sum() == pytest.approx(r["path_length"], rel=1e-9)
    capsys.readouterr()
    assert cli.main(BENCH[:-1] + ["--save-paths"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--save-paths" in err[0] and "--json" in err[0], err


def test_a_saved_kinodynamic_path_carries_the_controls_of_its_edges():
    """The pendulum's saved path: states and, row by row, the torque of the edge into each state
    (row 0 zeros): the env's own path_controls of the same run."""
    from train.benchmark.runs import run_episode
    record = run_episode("pendulum", {"split": "test", "max_nodes": 4000}, "goal-bias", 0, 0, keep_path=True)
    assert record["success"]
    env = gym.make("GNNMP/PendulumRRT-v0", split="test", max_nodes=4000)
    from agents.samplers import load_sampler
    from gnn_mp_envs.evaluation import plan_problem
    sampler = load_sampler("goal-bias", task="pendulum", seed=0)
    seen = {}
    plan_problem(env.unwrapped, sampler, 0, 0, on_step=lambda _o, i, done: seen.update(i) if done else None)
    assert np.array_equal(np.array(record["path"]), seen["path"])
    assert np.array_equal(np.array(record["path_controls"]), seen["path_controls"])
    assert np.array(record["path_controls"]).shape == (len(record["path"]), 1)


@pytest.mark.parametrize("env_id", ["GNNMP/Maze2DRRT-v0", "GNNMP/Maze2DBiRRT-v0", "GNNMP/PendulumRRT-v0"])
def test_the_exported_tree_is_the_observations_tree(env_id, tmp_path):
    """``export_tree()``: the observation's nodes and parents, edges parent -> child, the cost of a node
    its parent's plus the edge's (Euclidean for maze2d), the returned path's nodes and states those of
    the info, one root per tree; it survives ``np.savez``. With torch, ``tree_data`` gives the graph
    ``to_pyg`` gives for the observation."""
    env, obs, info = solved_rollout(env_id)
    tree = env.unwrapped.export_tree()
    n = int(obs["num_nodes"][0])
    assert tree["states"].shape == (n, env.unwrapped.state_dim) and tree["states"].dtype == np.float64
    assert np.array_equal(tree["states"].astype(np.float32), obs["nodes"][:n])
    assert np.array_equal(tree["parent"], obs["parent"][:n])
    assert np.array_equal(tree["tree_id"], obs["node_features"][:n, -1].astype(np.int64))
    children = np.flatnonzero(tree["parent"] >= 0)
    assert np.array_equal(tree["edges"], np.stack([tree["parent"][children], children], 1))
    roots = np.flatnonzero(tree["parent"] < 0)
    assert sorted(tree["tree_id"][roots]) == ([0, 1] if "BiRRT" in env_id else [0])
    assert np.array_equal(tree["path_nodes"], info["path_nodes"])
    assert np.array_equal(tree["states"][tree["path_nodes"]], info["path"])
    assert np.array_equal(tree["start"], info["path"][0]) and tree["controls"].shape[0] == n
    if "Maze2D" in env_id:
        step = np.linalg.norm(tree["states"][children] - tree["states"][tree["parent"][children]], axis=1)
        assert np.allclose(tree["cost"][children], tree["cost"][tree["parent"][children]] + step)
    else:
        assert tree["controls"].shape == (n, 1) and np.array_equal(tree["controls"][info["path_nodes"]],
                                                                    info["path_controls"])
    np.savez(tmp_path / "tree.npz", **tree)
    loaded = dict(np.load(tmp_path / "tree.npz"))
    assert loaded.keys() == tree.keys() and all(np.array_equal(loaded[k], tree[k]) for k in tree)
    pytest.importorskip("torch_geometric")
    import torch

    from agents.nn.graph import to_pyg, tree_data
    data, graph = tree_data(loaded), to_pyg(obs)
    assert data.num_nodes == n and torch.equal(data.edge_index, graph.edge_index)
    assert torch.equal(data.pos, torch.as_tensor(tree["states"])) and torch.equal(data.x, graph.pos)
    assert torch.equal(data.path_nodes, torch.as_tensor(info["path_nodes"]))
    with pytest.raises(ValueError, match="missing"):
        tree_data({"states": tree["states"]})


def test_export_tree_before_reset_is_one_clear_error():
    env = gym.make("GNNMP/Maze2DRRT-v0")
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.export_tree()


def test_no_recheck_announces_itself_and_marks_success_unverified(tmp_path, capsys, monkeypatch):
    """``--no-recheck`` says so on stderr before planning, never calls path_valid, heads the success
    column "success (unverified)", notes it under the table and writes ``"rechecked": false`` with no
    verdicts; the default run says when its re-check runs (how many paths) and writes
    ``"rechecked": true``."""
    from gnn_mp_envs.tasks.maze2d.task import Maze2DProblem
    calls = []
    path_valid = Maze2DProblem.path_valid
    monkeypatch.setattr(Maze2DProblem, "path_valid", lambda self, *a, **k: calls.append(1) or path_valid(self, *a, **k))
    out = tmp_path / "r.json"
    assert cli.main([*BENCH, "--json", str(out), "--no-recheck"]) == 0
    captured = capsys.readouterr()
    report = json.loads(out.read_text())
    assert calls == [] and report["rechecked"] is False
    runs = [r for rows in report["runs"].values() for r in rows]
    assert all(r["path_valid"] is None and r["path_valid_fine"] is None for r in runs)
    assert "maze2d: --no-recheck: the returned paths are not re-checked" in captured.err
    assert "success (unverified)" in captured.out.splitlines()[1]
    assert "returned paths NOT re-checked (--no-recheck)" in captured.out
    assert "(not re-checked)" in captured.out and "re-checking" not in captured.err
    from train.benchmark.tables import format_family_table, format_field_table
    for table in (format_family_table(report), format_field_table(report)):     # every table of the report
        assert "(not re-checked)" in table and "passes the re-check" not in table

    assert cli.main([*BENCH, "--json", str(out)]) == 0
    captured = capsys.readouterr()
    report = json.loads(out.read_text())
    solved = sum(r["success"] for rows in report["runs"].values() for r in rows)
    assert report["rechecked"] is True and len(calls) == 2 * solved
    assert f"maze2d: re-checking the {solved} returned paths edge by edge" in captured.err
    assert "re-check done in" in captured.err and "--no-recheck" not in captured.out
    assert "success (unverified)" not in captured.out


def test_a_task_run_writes_the_success_vs_time_figure_and_the_planner_arena_log(tmp_path, capsys):
    """``--success-plot`` and ``--ompl-log`` of a one-task run (not only of a suite): the figure's curves
    are each row's share of problems solved by each time budget, 0 below the fastest solved run and the
    row's success rate at the time limit; the log holds every row's runs."""
    from gnn_mp_envs.baselines.ompl_log import read_ompl_log
    from train.benchmark.plots import success_curves
    figure, logs, out = tmp_path / "svt.svg", tmp_path / "ompl", tmp_path / "r.json"
    assert cli.main([*BENCH, "--success-plot", str(figure), "--ompl-log", str(logs), "--json", str(out)]) == 0
    svg = figure.read_text()
    assert svg.lstrip().startswith("<?xml") and "time budget" in svg and "goal-bias" in svg
    report = json.loads(out.read_text())
    grid, curves = success_curves(report)
    assert grid[-1] == pytest.approx(report["time_limit_s"]) and set(curves) == {"uniform", "goal-bias"}
    for name, fractions in curves.items():
        times = [r["wall_time_s"] for r in report["runs"][name] if r["success"]]
        assert np.all(np.diff(fractions) >= 0)
        assert fractions[-1] == pytest.approx(report["results"][name]["success_rate"])
        assert np.all(fractions[grid < min(times)] == 0) and fractions[np.searchsorted(grid, max(times))] > 0
    log = read_ompl_log(logs / "maze2d.log")
    assert set(log["planners"]) == {"uniform", "goal-bias"}
    assert all(len(p["runs"]) == 3 for p in log["planners"].values())
    from train.args import UsageError
    with pytest.raises(UsageError, match="--success-plot .*expected a file"):
        bm.validate_args(bm.BenchmarkArgs(samplers=["uniform"], problems=1, success_plot=tmp_path))
