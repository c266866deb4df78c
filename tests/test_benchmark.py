"""The benchmark library: statistics, seeds, parallel runs and outputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from train import benchmark as bm
from train import cli


def tiny_args(**overrides) -> bm.BenchmarkArgs:
    kwargs = dict(task="maze2d", samplers=["uniform", "goal-bias"], problems=3, seed=3, max_nodes=150,
                  progress=False)
    kwargs.update(overrides)
    return bm.BenchmarkArgs(**kwargs)


TIMES = ("wall_time_s", "sampler_time_s", "planner_time_s")


def without_wall_time(report: dict) -> dict:
    runs = {name: [{k: v for k, v in r.items() if k not in TIMES} for r in rs]
            for name, rs in report["runs"].items()}
    results = {name: {k: v for k, v in s.items() if k not in TIMES} for name, s in report["results"].items()}
    return {"runs": runs, "results": results}


def test_summarize_ignores_missing_values_and_never_returns_nan():
    assert bm.summarize([]) == {"median": None, "mean": None, "q25": None, "q75": None, "p95": None}
    assert bm.summarize([None, float("inf")])["median"] is None
    stats = bm.summarize([1.0, 2.0, 3.0, None])
    assert stats == {"median": 2.0, "mean": 2.0, "q25": 1.5, "q75": 2.5, "p95": 2.9}


def test_problem_seeds_are_shared_across_samplers_and_distinct_across_problems():
    from gnn_mp_envs.evaluation import problem_seed
    assert problem_seed(0, 1) == problem_seed(0, 1)
    assert len({problem_seed(0, i) for i in range(50)}) == 50
    assert problem_seed(0, 1) != problem_seed(1, 1)
    # the rule's values are pinned: every benchmark table's runs were seeded with them
    assert [problem_seed(0, i) for i in range(3)] == [int(np.random.SeedSequence([0, i]).generate_state(1)[0])
                                                      for i in range(3)]


def test_samplers_see_the_same_problems_and_seeds():
    report = bm.run_benchmark(tiny_args())
    uniform, goal_bias = report["runs"]["uniform"], report["runs"]["goal-bias"]
    assert [(r["problem"], r["seed"]) for r in uniform] == [(r["problem"], r["seed"]) for r in goal_bias]
    json.dumps(report, allow_nan=False)   # no NaN / inf anywhere
    table = bm.format_table(report)
    assert "uniform" in table and "goal-bias" in table


def test_two_workers_match_a_serial_run():
    serial = bm.run_benchmark(tiny_args(workers=1, problems=2))
    parallel = bm.run_benchmark(tiny_args(workers=2, problems=2))
    assert without_wall_time(parallel) == without_wall_time(serial)


def test_unknown_sampler_lists_known_names():
    with pytest.raises(bm.BenchmarkError, match="known: .*goal-bias.*uniform"):
        bm.validate_args(tiny_args(samplers=["nope"]))


def test_ompl_rows_fail_early_with_an_install_hint(monkeypatch):
    from gnn_mp_envs.baselines import ompl_runner
    monkeypatch.setattr(ompl_runner, "ompl_available", lambda: False)
    with pytest.raises(bm.BenchmarkError, match=r"pip install .gnn-mp-envs\[ompl\].|OMPL runner is not available"):
        bm.validate_args(tiny_args(samplers=["uniform", "ompl-rrtconnect"]))


def test_ompl_record_maps_runner_counters():
    from train.benchmark.ompl_rows import _ompl_record
    record = _ompl_record("ompl-rrtconnect", 4, 11, {"solved": True, "collision_checks": 120, "time": 0.02,
                                                         "path_length": 1.5, "nodes": 40})
    assert record["success"] and record["collision_checks"] == 120 and record["wall_time_s"] == 0.02
    assert record["nodes_expanded"] == 40 and record["edges"] is None
    failed = _ompl_record("ompl-rrtconnect", 4, 11, {"solved": False, "path_length": float("inf")})
    assert failed["path_length"] is None


def test_plot_writes_a_png(tmp_path):
    report = bm.run_benchmark(tiny_args(problems=2, samplers=["uniform"]))
    bm.plot_report(report, tmp_path / "box.png")
    assert (tmp_path / "box.png").read_bytes()[:4] == b"\x89PNG"


def test_passthrough_of_a_missing_module_is_a_one_line_error(capsys):
    with pytest.raises(cli.CLIError, match="not available"):
        cli.load_module_main("train.no_such_module")


def test_ompl_log_of_our_samplers(tmp_path):
    args = tiny_args(problems=2, samplers=["uniform"], ompl_log=tmp_path)
    report = bm.run_benchmark(args)
    text = bm.write_ompl_logs(args, report, tmp_path).read_text()
    assert "\nuniform\n" in text and "2 runs" in text and "collision checks INTEGER" in text


def test_ompl_log_names_the_experiment_in_one_word_and_control_planners_as_such(tmp_path):
    """OMPL's ompl_benchmark_statistics.py names an experiment by the last word of its line: the
    whole name is one word (scene and checker in it); the pendulum's OMPL rows are control-based
    planners and are named so (maze2d's ompl-rrt is geometric RRT); OMPL rows carry their settings."""
    from gnn_mp_envs.baselines.ompl_log import read_ompl_log
    args = tiny_args(task="pendulum", problems=1, samplers=["uniform", "ompl-rrt"], ompl_log=tmp_path)
    report = {"env_id": "GNNMP/PendulumRRT-v0", "max_nodes": 100, "checker": None,
              "runs": {name: [{"problem": 0, "success": True, "wall_time_s": 0.01, "path_length": 1.0,
                               "nodes_expanded": 5, "edges": 5, "collision_checks": 50, "iterations": 5}]
                       for name in args.samplers}}
    log = read_ompl_log(bm.write_ompl_logs(args, report, tmp_path))
    assert len(log["experiment"].split()) == 1 and "PendulumRRT" in log["experiment"]
    assert set(log["planners"]) == {"uniform", "ompl-control-rrt"}
    assert log["planners"]["ompl-control-rrt"]["common"]


@pytest.mark.skipif(not bm.ompl_available(), reason="OMPL (optional extra) not installed")
def test_ompl_rows_run_the_same_problems():
    report = bm.run_benchmark(tiny_args(problems=2, samplers=["uniform", "ompl-rrtconnect"]))
    runs = report["runs"]["ompl-rrtconnect"]
    assert [r["problem"] for r in runs] == [0, 1]
    assert all(r["success"] and r["collision_checks"] > 0 and r["nodes_expanded"] > 0 for r in runs)
    assert report["results"]["ompl-rrtconnect"]["success_rate"] == 1.0


def test_ray_actors_give_the_counters_of_local_workers(monkeypatch):
    """`--ray` (a local Ray instance) runs the same jobs as `--workers 2`: same counters, and the same
    verdicts of the re-check, which runs on the actors of the timed runs (Ray started once)."""
    pytest.importorskip("ray")
    import train.workers
    starts = []
    start_ray = train.workers.start_ray
    monkeypatch.setattr(train.workers, "start_ray", lambda *a, **k: (starts.append(a), start_ray(*a, **k)))
    on_ray = bm.run_benchmark(tiny_args(workers=2, problems=3, max_nodes=2000, ray="local"))
    assert len(starts) == 1
    assert any(r["path_valid_fine"] for row in on_ray["runs"].values() for r in row)   # the re-check ran
    local = bm.run_benchmark(tiny_args(workers=2, problems=3, max_nodes=2000))
    assert without_wall_time(on_ray) == without_wall_time(local)



def test_an_ompl_runner_timeout_is_one_error_naming_the_row(monkeypatch):
    import subprocess

    from gnn_mp_envs.baselines import ompl_runner
    from train.benchmark.ompl_rows import run_ompl_rows

    def hung(*args, **kwargs):
        raise subprocess.TimeoutExpired(cmd="ompl_runner", timeout=42.0)
    monkeypatch.setattr(ompl_runner, "run_ompl", hung)
    with pytest.raises(bm.BenchmarkError, match=r"ompl-rrt on maze2d: the OMPL runner did not finish within 42 s"):
        run_ompl_rows(tiny_args(samplers=["ompl-rrt"]), "ompl-rrt", [0, 1])


def test_a_suite_draws_its_tree_growth_images(tmp_path, capsys):
    """--suite writes tree-growth images to OUT/renders, or to --render DIR when given (the two flags
    used to share one argparse destination, and no image was written)."""
    assert cli.main(["benchmark", "--suite", "smoke", "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    for name in ("uniform", "goal-bias"):
        assert (tmp_path / "a" / "renders" / f"maze2d_{name}_problem0.png").stat().st_size > 1000
    assert (tmp_path / "a" / "summary.md").exists()
    assert cli.main(["benchmark", "--suite", "smoke", "--out", str(tmp_path / "b"), "--render",
                     str(tmp_path / "elsewhere"), "--no-progress"]) == 0
    assert (tmp_path / "elsewhere" / "maze2d_uniform_problem0.png").exists()
    assert not (tmp_path / "b" / "renders").exists()
    assert cli.main(["benchmark", "--suite", "smoke", "--out", str(tmp_path / "c"), "--no-render",
                     "--no-progress"]) == 0
    assert not (tmp_path / "c" / "renders").exists()
    capsys.readouterr()


def test_an_unreachable_ray_address_fails_at_once():
    """Nothing listens on 127.0.0.1:1: one line, not Ray's minutes of retries (a hang times out here)."""
    import subprocess
    import sys
    pytest.importorskip("ray")
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, "benchmark", "--problems", "2", "--ray", "127.0.0.1:1",
                             "--no-progress"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stderr.strip().count("\n") == 0, result.stderr
    assert "cannot reach Ray at 127.0.0.1:1" in result.stderr


def test_a_setting_overrides_the_one_stored_with_the_weights(tmp_path):
    """--setting SAMPLER.KEY=VALUE reaches the sampler instead of its stored value; a setting the
    sampler does not take, or one for a sampler not benchmarked, is one line."""
    report = bm.run_benchmark(tiny_args(task="maze2d", samplers=["uniform", "goal-bias"], problems=2,
                                   settings=[("goal-bias", "goal_bias", 1.0)]))
    # every sample is the goal: the tree grows straight to the first wall and stops there
    assert report["results"]["goal-bias"]["success_rate"] == 0.0
    assert max(r["nodes_expanded"] for r in report["runs"]["goal-bias"]) < 30
    assert min(r["nodes_expanded"] for r in report["runs"]["uniform"]) > 30
    from train.benchmark.runs import cached_sampler
    assert cached_sampler("goal-bias", "maze2d", settings=(("goal_bias", 1.0),)).goal_bias == 1.0
    with pytest.raises(bm.BenchmarkError, match="unknown: goal_bias"):
        bm.run_benchmark(tiny_args(task="maze2d", samplers=["uniform"], problems=1, settings=[("uniform", "goal_bias", 1)]))
    with pytest.raises(bm.BenchmarkError, match="not one of the --samplers"):
        bm.run_benchmark(tiny_args(task="maze2d", samplers=["uniform"], problems=1, settings=[("gnn", "proposals", 1)]))
    with pytest.raises(SystemExit) as exc:
        cli.main(["benchmark", "--samplers", "uniform", "--setting", "oops", "--problems", "1"])
    assert exc.value.code == 2


@pytest.mark.parametrize("flag", [["--out", "elsewhere"], ["--out", "results"], ["--no-ompl"], ["--no-vamp"],
                                  ["--no-render"]])
def test_suite_only_flags_without_a_suite_are_refused_in_one_line(flag, capsys):
    """A one-task run writes only --json/--plot/--render: a suite's --out (or --no-ompl, --no-vamp, --no-render)
    given without --suite is refused in one line before anything runs, not silently ignored."""
    code = cli.main(["benchmark", "--samplers", "uniform", "--problems", "1", "--no-progress", *flag])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--suite only" in err[0] and "--json" in err[0], err


def test_every_returned_path_is_rechecked_and_failures_are_named():
    """The benchmark re-checks each solved run's path edge by edge (problem.path_valid) and the
    table says how many passed; a failing row is named."""
    from train.benchmark.tables import path_check_note
    report = bm.run_benchmark(tiny_args(problems=2, samplers=["uniform", "goal-bias"], max_nodes=3000))
    records = [r for runs in report["runs"].values() for r in runs]
    assert all(r["path_valid"] is (True if r["success"] else None) for r in records)
    assert all(r["path_valid_fine"] is (True if r["success"] else None) for r in records)
    solved = sum(r["success"] for r in records)
    assert solved >= 2
    assert path_check_note(report) == (f"returned paths re-checked: {solved} of {solved} valid edge by edge; "
                                       f"{solved} of {solved} valid at 10x finer resolution")
    first = next(r for r in report["runs"]["goal-bias"] if r["success"])
    first["path_valid"] = False   # a hand-made failure
    assert f"1 of {solved} INVALID edge by edge (goal-bias: 1); {solved} of {solved} valid" in path_check_note(report)
    first["path_valid_fine"] = False
    assert path_check_note(report).endswith(f"1 of {solved} INVALID at 10x finer resolution (goal-bias: 1)")


def test_every_suite_entry_fits_its_split():
    """A suite entry never asks for more problems than its split holds (with its scene and
    checker): a finite split (MotionBenchMaker's) is planned whole, not past its end."""
    from gnn_mp_envs.registration import make_task, task_spec
    from train.benchmark.suites import SUITES
    for name, entries in SUITES.items():
        for entry in entries:
            kwargs = {"checker": entry.checker} if entry.checker else {}
            scene = entry.scene or task_spec(entry.task).benchmark_scene
            if scene:
                kwargs["scene"] = scene
            task = make_task(entry.task, **kwargs)
            try:
                size = task.num_problems(entry.split)
            finally:
                task.close()
            assert size is None or entry.problems <= size, (name, entry.name, entry.problems, size)


def test_box_plots_show_wall_time_and_colour_rows_by_kind(tmp_path):
    """The box plots have a wall-time panel beside the paper's three, the success rates in the
    title, and one colour per kind of sampler; an .svg suffix writes SVG."""
    from train.benchmark.plots import KIND_COLOURS, plot_report, sampler_kind
    report = bm.run_benchmark(tiny_args(problems=2, samplers=["uniform", "goal-bias"]))
    plot_report(report, tmp_path / "boxes.svg")
    svg = (tmp_path / "boxes.svg").read_text()
    assert svg.lstrip().startswith("<?xml") and "wall time" in svg and "success" in svg
    assert [sampler_kind(n) for n in ("uniform", "gnn", "rl-ppo", "ompl-rrt", "gnn-pick")] == \
        ["classical", "supervised", "rl", "ompl", "supervised"]
    assert KIND_COLOURS["classical"].lstrip("#") in svg or KIND_COLOURS["classical"].upper().lstrip("#") in svg


def test_the_time_budget_is_the_tasks_unless_given():
    """`--ompl-time-limit` (OMPL's solve limit and the time of 'solved within the budgets') defaults to
    the task's `TaskSpec.time_limit_s`: 10 s for most, 30 s with 30,000 nodes for the Fetch; a flag
    overrides it and a non-positive one is refused."""
    import gnn_mp_envs
    assert gnn_mp_envs.task_spec("maze2d").time_limit_s == 10.0
    fetch = gnn_mp_envs.task_spec("fetch-mbm")
    assert (fetch.max_nodes, fetch.time_limit_s) == (30000, 30.0)
    for task, expected in (("maze2d", 10.0), ("fetch-mbm", 30.0)):
        args = bm.BenchmarkArgs(task=task, samplers=["uniform"], problems=1)
        bm.validate_args(args)
        assert args.ompl_time_limit == expected
    args = bm.BenchmarkArgs(task="fetch-mbm", samplers=["uniform"], problems=1, ompl_time_limit=5.0)
    bm.validate_args(args)
    assert args.ompl_time_limit == 5.0
    with pytest.raises(bm.BenchmarkError, match="--ompl-time-limit must be > 0"):
        bm.validate_args(bm.BenchmarkArgs(task="maze2d", samplers=["uniform"], problems=1, ompl_time_limit=0.0))


def test_paths_are_rechecked_after_every_timed_run_with_the_verdicts_of_an_inline_recheck(monkeypatch):
    """The re-check's work (pybullet at 10x the resolution on the arms) must not evict the caches of the
    next timed run: every path_valid call comes after the last planning run. Its verdicts are those of
    re-checking each path right after its run (run_episode's default), and no report carries a path."""
    from gnn_mp_envs import evaluation
    from gnn_mp_envs.tasks.maze2d.task import Maze2DProblem
    events: list[str] = []
    plan, path_valid = evaluation.plan_problem, Maze2DProblem.path_valid
    monkeypatch.setattr(evaluation, "plan_problem", lambda *a, **k: events.append("plan") or plan(*a, **k))
    monkeypatch.setattr(Maze2DProblem, "path_valid",
                        lambda self, *a, **k: events.append("recheck") or path_valid(self, *a, **k))
    from train.benchmark.args import env_kwargs_for
    args = tiny_args(problems=3, samplers=["uniform", "goal-bias"], max_nodes=3000)
    report = bm.run_benchmark(args)
    records = [r for runs in report["runs"].values() for r in runs]
    solved = sum(r["success"] for r in records)
    assert solved >= 2 and events.count("plan") == 6 and events.count("recheck") == 2 * solved
    assert events.index("recheck") > len(events) - 1 - events[::-1].index("plan")     # all plans first
    inline = [bm.run_episode("maze2d", env_kwargs_for(args), r["sampler"], r["problem"], args.seed) for r in records]
    keys = ("success", "nodes_expanded", "collision_checks", "path_valid", "path_valid_fine")
    assert [{k: r[k] for k in keys} for r in records] == [{k: r[k] for k in keys} for r in inline]
    assert all(set(r) == set(i) for r, i in zip(records, inline)), "a record kept its path or lost a key"
    json.dumps(report)


@pytest.mark.parametrize("task, batch", [("maze2d", 1), ("panda-mbm", 64)])
def test_a_benchmark_env_steps_once_before_its_timed_runs_and_plans_as_a_fresh_one(monkeypatch, task, batch):
    """A process's first step loads the compiled planning loop and checker from numba's cache (or compiles
    them): the benchmark's env takes one untimed step of its first problem when it is made, so the first
    timed run of the first row does not pay for it. Its runs' counters are a cold env's."""
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    from agents.samplers import load_sampler
    from train.benchmark import runs
    monkeypatch.setattr(runs, "_ENVS", {})
    kwargs = {"samples_per_step": batch} if batch > 1 else {}
    env = runs.cached_env(task, kwargs)
    assert 1 <= env.planner.iterations <= batch     # one step: a batch's samples, up to a solution
    cold = evaluation_env(task, **kwargs)
    keys = ("success", "nodes_expanded", "edges", "collision_checks", "iterations")
    for index in (0, 1):
        warm_run, cold_run = (plan_problem(e, load_sampler("uniform", task=task, seed=0), index, 0).counters()
                              for e in (env, cold))
        assert {k: warm_run[k] for k in keys} == {k: cold_run[k] for k in keys}


def test_times_from_one_millisecond_up_keep_three_significant_figures():
    """Rows 1.28 and 1.47 ms apart read apart (they printed as "1" and "1"); sub-millisecond rows keep three
    decimals; the sampler / planner split follows the same rule."""
    from train.benchmark.tables import ms_digits
    assert [f"{v:.{ms_digits(v)}f}" for v in (0.0874, 1.284, 12.84, 128.4, 1284.0)] == \
        ["0.087", "1.28", "12.8", "128", "1284"]
    stat = {"median": 1.284e-3, "q25": 0.9e-3, "q75": 3.5e-3}
    split = {"median": 0.2e-3, "q25": 0.1e-3, "q75": 0.3e-3}
    report = {"task": "maze2d", "env_id": "GNNMP/Maze2D-v0", "max_nodes": 100, "problems": 1, "seed": 0,
              "results": {"uniform": {"nodes_expanded": stat, "edges": stat, "collision_checks": stat,
                                      "path_length": stat, "wall_time_s": stat, "sampler_time_s": split,
                                      "planner_time_s": stat, "success_rate": 1.0}},
              "runs": {}}
    row = bm.format_table(report).splitlines()[3]
    assert "1.28 [0.90, 3.50]" in row and "0.200 / 1.28" in row, row


def test_balanced_trees_are_a_flag_for_birrt_tasks(tmp_path, capsys):
    """``--balance`` plans BiRRT with balanced trees: the table's title and the JSON say so, the runs are those
    of ``evaluation_env(task, balance=True)`` counter for counter, and a task planned with RRT refuses the flag
    in one line."""
    from agents.samplers import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    out = tmp_path / "b.json"
    assert cli.main(["benchmark", "--task", "maze2d", "--samplers", "uniform", "--problems", "1", "--no-progress",
                     "--balance", "--no-recheck"]) == 2                      # maze2d's benchmark planner is RRT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--balance applies to BiRRT's two trees" in err[0], err
    assert cli.main(["benchmark", "--task", "panda-mbm", "--samplers", "uniform", "--problems", "2", "--no-progress",
                     "--balance", "--json", str(out)]) == 0
    assert "balanced trees" in capsys.readouterr().out
    report = json.loads(out.read_text())
    assert report["balance"] is True
    env = evaluation_env("panda-mbm", balance=True)
    sampler = load_sampler("uniform", task="panda-mbm")
    for run in report["runs"]["uniform"]:
        mine = plan_problem(env, sampler, run["problem"], report["seed"]).counters()
        assert all(mine[k] == run[k] for k in ("nodes_expanded", "edges", "collision_checks", "iterations"))
    env.close()
