"""OMPL baseline runner and the OMPL benchmark-log writer.

Planning tests need the ``ompl`` extra (``make install`` takes it) and are skipped without
it; the availability error path, index parsing and the log format are pure Python.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gnn_mp_envs.baselines import ompl_runner
from gnn_mp_envs.baselines.ompl_log import STATUS_NAMES, read_ompl_log, run_properties, write_ompl_log
from gnn_mp_envs.baselines.ompl_runner import OMPLUnavailableError, parse_indices, run_ompl

needs_ompl = pytest.mark.skipif(not ompl_runner.ompl_available(), reason="optional extra 'ompl' not installed")


# ---------------------------------------------------------------------- pure Python
def test_parse_indices():
    assert parse_indices("0-3") == [0, 1, 2, 3]
    assert parse_indices("0,3,5-7") == [0, 3, 5, 6, 7]
    assert parse_indices(4) == [4]
    assert parse_indices(range(2)) == [0, 1]
    for bad in ("", "3-1", "-1", "a"):
        with pytest.raises(ValueError):
            parse_indices(bad)


def test_unavailable_ompl_raises_with_install_hint(monkeypatch):
    monkeypatch.setattr(ompl_runner, "ompl_available", lambda: False)
    with pytest.raises(OMPLUnavailableError, match="pip install"):
        run_ompl("maze2d", [0])


def test_runner_process_without_ompl_reports_unavailable(tmp_path):
    """An interpreter where ``import ompl`` fails: the runner writes an error, exit code 3,
    and run_ompl turns it into OMPLUnavailableError."""
    shim = tmp_path / "shim"
    shim.mkdir()
    (shim / "ompl.py").write_text("raise ImportError('no ompl here')\n")
    wrapper = tmp_path / "python_without_ompl"
    wrapper.write_text(f"#!/bin/sh\nPYTHONPATH={shim}:$PYTHONPATH exec {sys.executable} \"$@\"\n")
    wrapper.chmod(0o755)
    out = tmp_path / "out.json"
    proc = subprocess.run([str(wrapper), "-m", "gnn_mp_envs.baselines.ompl_runner", "--task", "maze2d",
                           "--indices", "0", "--json", str(out)], capture_output=True, text=True)
    assert proc.returncode == ompl_runner.EXIT_NO_OMPL
    assert "no ompl here" in out.read_text()
    with pytest.raises(OMPLUnavailableError, match="pip install"):
        run_ompl("maze2d", [0], python=str(wrapper))


def test_a_runner_past_its_timeout_is_killed_and_reported(tmp_path):
    """A runner that hangs: killed with its children at the timeout (a hang bound, not a speed
    target: the child sleeps 60 s), TimeoutExpired (the benchmark's one line)."""
    import time
    wrapper = tmp_path / "python_that_hangs"
    wrapper.write_text("#!/bin/sh\nsleep 60\n")
    wrapper.chmod(0o755)
    started = time.monotonic()
    with pytest.raises(subprocess.TimeoutExpired):
        run_ompl("maze2d", [0], python=str(wrapper), timeout=1.0)
    assert time.monotonic() - started < 30


@pytest.mark.parametrize("payload", ['{"results": {"0": {}}}', '{"results": [{"solved": true}]}',
                                     '{"results": [{"solved": "yes"}, {"solved": false}]}',
                                     '{"results": [{"solved": true, "nodes": "many"}, {"solved": false}]}',
                                     '[1, 2]', '{"results": [', '"ok"'])
def test_a_runner_answer_of_the_wrong_shape_is_one_line(tmp_path, payload):
    """Another runner (python=...) writing JSON of another shape, or none at all: a RuntimeError of one
    line saying what came back, not a traceback deep in the benchmark."""
    wrapper = tmp_path / "python_with_another_runner"
    wrapper.write_text("#!/bin/sh\nwhile [ $# -gt 0 ]; do if [ \"$1\" = --json ]; then out=$2; fi; shift; done\n"
                       f"printf '%s' '{payload}' > \"$out\"\n")
    wrapper.chmod(0o755)
    with pytest.raises(RuntimeError) as info:
        run_ompl("maze2d", [0, 1], python=str(wrapper))
    assert "\n" not in str(info.value) and "OMPL runner" in str(info.value), info.value


@needs_ompl
@pytest.mark.parametrize("modules", [["tests.tiny_task"], []], ids=["--import", "entry-point-module"])
def test_a_task_registered_outside_the_package_gets_ompl_rows(modules):
    """The runner process registers the task too: from the benchmark's --import modules, else from
    the module of the task's entry point (it used to build built-in tasks only: 'unknown task')."""
    from tests import tiny_task  # noqa: F401  (registers "tiny" here)
    from train import benchmark as bm
    report = bm.run_benchmark(bm.BenchmarkArgs(task="tiny", samplers=["uniform", "ompl-rrtconnect"], problems=2,
                                               modules=modules, progress=False))
    runs = report["runs"]["ompl-rrtconnect"]
    assert [r["problem"] for r in runs] == [0, 1] and all(r["success"] and r["path_valid"] for r in runs)


@needs_ompl
def test_a_checkers_first_call_is_not_counted_as_planning_time():
    """A process's first check may build or compile the checker (the sphere kernel compiles for tens of
    seconds where numba's cache is stale): the runner makes it before the clock, so the first problem is
    planned within a time limit shorter than that call, as the second is (it timed out with one node)."""
    runs = run_ompl("tiny-slow-first-check", [0, 1], time_limit=1.0, modules=["tests.slow_first_check_task"])
    assert [r["solved"] for r in runs] == [True, True], runs       # the first check there takes 3 s
    assert max(r["time"] for r in runs) < 1.0


def test_unknown_planner_is_refused():
    with pytest.raises(ValueError, match="rrtconnect"):
        run_ompl("maze2d", [0], planner="prm")


def _results():
    return {
        "geometric_RRTConnect": [
            {"solved": True, "status": "Exact solution", "time": 0.25, "collision_checks": 812, "nodes": 40,
             "path_length": 3.5, "path_valid": True, "index": 0, "path": [[0.0, 1.0]]},
            {"solved": False, "status": "Timeout", "time": 10.0, "collision_checks": 90000, "nodes": 5000,
             "path_length": None, "path_valid": None, "index": 1},
        ],
        "birrt_uniform": [
            {"solved": True, "time": 0.5, "collision_checks": 1500, "nodes": 120, "path_length": 4.0, "index": 0},
        ],
    }


def test_write_ompl_log_structure(tmp_path):
    path = write_ompl_log(tmp_path / "arm.log", "arm held-out", _results(), time_limit=10.0, seed=3,
                          planner_settings={"geometric_RRTConnect": {"range": 0.4}}, setup="scene test")
    lines = Path(path).read_text().splitlines()
    assert lines[0].split()[1] == "version"
    assert lines[1] == "Experiment arm held-out"
    assert lines[2].startswith("Running on ")
    assert lines[3].startswith("Starting at ")
    assert lines[4:7] == ["<<<|", "scene test", "|>>>"]
    assert "3 is the random seed" in lines
    assert "10.0 seconds per run" in lines
    assert "2 runs per planner" in lines
    assert "status|" + "|".join(STATUS_NAMES) in lines
    assert "2 planners" in lines
    i = lines.index("geometric_RRTConnect")
    assert lines[i + 1:i + 3] == ["1 common properties", "range = 0.4"]
    n = int(lines[i + 3].split()[0])
    props = lines[i + 4:i + 4 + n]
    assert props == sorted(props)
    assert "collision checks INTEGER" in props and "solution length REAL" in props
    assert "solved BOOLEAN" in props and "status ENUM" in props and "time REAL" in props
    assert lines[i + 4 + n] == "2 runs"
    runs = lines[i + 5 + n:i + 7 + n]
    assert all(r.endswith("; ") and r.count("; ") == n for r in runs)
    assert lines[i + 7 + n] == "."
    assert lines[-1] == "."


def test_ompl_log_round_trip(tmp_path):
    path = write_ompl_log(tmp_path / "x.log", "exp", _results(), time_limit=5.0)
    log = read_ompl_log(path)
    assert log["experiment"] == "exp" and log["time_limit"] == 5.0 and log["run_count"] == 2
    rrtc = log["planners"]["geometric_RRTConnect"]
    assert [r["solved"] for r in rrtc["runs"]] == [1.0, 0.0]
    assert rrtc["runs"][0]["collision_checks"] == 812.0
    assert rrtc["runs"][1]["solution_length"] is None  # missing -> NULL
    assert rrtc["runs"][0]["status"] == STATUS_NAMES.index("Exact solution")
    assert rrtc["runs"][1]["status"] == STATUS_NAMES.index("Timeout")
    assert log["planners"]["birrt_uniform"]["runs"][0]["status"] == STATUS_NAMES.index("Exact solution")
    assert "path" not in run_properties(_results()["geometric_RRTConnect"][0])


def test_write_ompl_log_rejects_bad_names(tmp_path):
    with pytest.raises(ValueError):
        write_ompl_log(tmp_path / "x.log", "two\nlines", _results())
    with pytest.raises(ValueError):
        write_ompl_log(tmp_path / "x.log", "exp", {})


# ---------------------------------------------------------------------- with OMPL
@needs_ompl
def test_rrtconnect_solves_maze2d_with_the_same_checker():
    reported = []     # the runner reports each problem as it finishes (the benchmark's progress bar)
    results = run_ompl("maze2d", "0-2", split="test", time_limit=5.0, seed=1, on_problem=reported.append)
    assert [r["index"] for r in results] == [0, 1, 2] and reported == [0, 1, 2]
    for r in results:
        assert r["solved"] and r["path_valid"]
        assert r["collision_checks"] > 0 and r["nodes"] >= 2 and r["path_length"] > 0
        assert r["planner"] == "geometric_RRTConnect" and r["status"] == "Exact solution"


@needs_ompl
def test_rrtconnect_solves_arm_with_the_same_checker():
    results = run_ompl("arm", [0, 1], split="test", task_kwargs={"scene": "test"}, time_limit=10.0)
    for r in results:
        assert r["solved"] and r["path_valid"]
        # Every edge goes through problem.check_motion: several checks per edge.
        assert r["collision_checks"] > r["edges_checked"] > 0


@needs_ompl
def test_rrtconnect_on_motionbenchmaker_counts_iterations_and_rechecks_paths_finely():
    """MotionBenchMaker's first two test problems: solved, the path valid at the planner's resolution
    and at 10x finer, the scene named, and iterations counted (each samples once and checks at least
    one state)."""
    results = run_ompl("panda-mbm", [0, 1], split="test", time_limit=10.0)
    assert [r["family"] for r in results] == ["table_pick", "table_under_pick"]
    for r in results:
        assert r["solved"] and r["path_valid"] and r["path_valid_fine"]
        assert 0 < r["iterations"] <= r["collision_checks"]


@needs_ompl
def test_planner_that_does_not_fit_the_task_is_refused_clearly():
    with pytest.raises(ValueError, match="kinodynamic"):
        run_ompl("pendulum", [0], planner="rrtconnect", time_limit=1.0)
    with pytest.raises(ValueError, match="geometric"):
        run_ompl("maze2d", [0], planner="kpiece", time_limit=1.0)


PENDULUM_KEYS = {"planner", "status", "solved", "approximate", "collision_checks", "edges_checked", "time",
                 "plan_time", "path_length", "path_states", "nodes", "goal_reached", "path_valid",
                 "propagation_steps", "task", "split", "index"}


@needs_ompl
@pytest.mark.parametrize("planner,name", [("rrt", "control_RRT"), ("kpiece", "control_KPIECE1")])
def test_control_planners_solve_pendulum_with_the_same_dynamics_and_checker(planner, name):
    """oc.RRT / oc.KPIECE1 on two held-out pendulum problems: solved exactly, every
    integrated state counted by problem.check_state, and the returned controls, re-simulated
    here with pendulum.rollout, arrive at states satisfying problem.in_goal."""
    from gnn_mp_envs.registration import make_task
    from gnn_mp_envs.tasks import pendulum as pend

    results = run_ompl("pendulum", [0, 1], time_limit=10.0, planner=planner, seed=0, keep_paths=True)
    task = make_task("pendulum")
    try:
        for i, r in zip([0, 1], results):
            assert PENDULUM_KEYS <= set(r)
            assert r["index"] == i and r["planner"] == name
            assert r["solved"] and r["status"] == "Exact solution" and not r["approximate"]
            assert r["goal_reached"] and r["path_valid"]
            # One check per 0.02 s integration step, plus OMPL's check of the start state.
            assert r["collision_checks"] == r["propagation_steps"] + 1 > 0
            assert r["edges_checked"] > 0 and r["nodes"] >= 2
            # path_length is the path's duration in seconds, in whole integration steps.
            dt = pend.EDGE_DURATION / pend.INTEGRATION_STEPS
            assert r["path_length"] == pytest.approx(sum(r["durations"]))
            assert r["path_length"] / dt == pytest.approx(round(r["path_length"] / dt), abs=1e-6)
            if planner == "rrt":   # every RRT edge is one torque held for EDGE_DURATION
                assert r["durations"] == pytest.approx([pend.EDGE_DURATION] * len(r["controls"]))
            problem = task.problem("test", i)
            states = np.array(r["path"])
            assert np.allclose(states[0], problem.start)
            assert problem.in_goal(states[-1])
            x = states[0]
            for u, duration in zip(r["controls"], r["durations"]):
                assert abs(u) <= pend.MAX_TORQUE
                steps = int(round(duration / dt))
                traj = pend.rollout(x[0], x[1], np.array([u]), duration, steps)[:, 0]
                assert problem.is_state_valid(traj).all()
                x = problem.normalize(traj[-1])
            assert problem.in_goal(x)
            assert np.allclose(problem.difference(x, states[-1]), 0.0, atol=1e-6)
    finally:
        task.close()


@needs_ompl
def test_pendulum_timeout_is_reported_as_unsolved():
    """A time limit too short to swing up: an approximate solution at most, never 'solved'."""
    (r,) = run_ompl("pendulum", [0], time_limit=0.01, planner="rrt")
    assert not r["solved"] and r["path_length"] is None and r["path_valid"] is None
    assert r["collision_checks"] > 0
