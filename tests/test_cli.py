"""The `gnn-mp` command end to end, through subprocesses (as a user runs it)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

STATS_KEYS = {"median", "mean", "q25", "q75", "p95"}
METRICS = ("nodes_expanded", "edges", "collision_checks", "path_length", "wall_time_s", "sampler_time_s",
           "planner_time_s")


def gnn_mp(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run the CLI exactly as the `gnn-mp` console script does."""
    code = "import sys; from train.cli import main; sys.exit(main())"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout)


def assert_one_line_error(result: subprocess.CompletedProcess, *fragments: str) -> None:
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_samplers_lists_the_baselines():
    result = gnn_mp("samplers")
    assert result.returncode == 0, result.stderr
    names = [line.split()[0] for line in result.stdout.splitlines() if line.strip()]
    assert "uniform" in names and "goal-bias" in names


def validate_report(report: dict, task: str, problems: int, seed: int, samplers: list[str]) -> None:
    assert report["task"] == task and report["problems"] == problems and report["seed"] == seed
    assert list(report["results"]) == samplers
    for name, summary in report["results"].items():
        assert 0.0 <= summary["success_rate"] <= 1.0
        for metric in METRICS:
            stats = summary[metric]
            assert set(stats) == STATS_KEYS, (name, metric)
            for value in stats.values():
                assert value is None or (isinstance(value, (int, float)) and math.isfinite(value))
            if stats["median"] is not None:
                assert stats["q25"] <= stats["median"] <= stats["q75"] <= stats["p95"]


def test_benchmark_end_to_end_json_plot_and_render(tmp_path: Path):
    out_json, out_plot, render_dir = tmp_path / "r.json", tmp_path / "r.png", tmp_path / "renders"
    result = gnn_mp("benchmark", "--task", "maze2d", "--samplers", "uniform,goal-bias", "--problems", "3",
                    "--seed", "7", "--max-nodes", "200", "--json", str(out_json), "--plot", str(out_plot),
                    "--render", str(render_dir), "--no-progress")
    assert result.returncode == 0, result.stderr
    assert "uniform" in result.stdout and "goal-bias" in result.stdout and "success" in result.stdout
    text = out_json.read_text()
    assert "NaN" not in text and "Infinity" not in text
    report = json.loads(text)
    validate_report(report, "maze2d", 3, 7, ["uniform", "goal-bias"])
    assert report["max_nodes"] == 200 and report["env_id"] == "GNNMP/Maze2DRRT-v0"
    for runs in report["runs"].values():
        assert [r["problem"] for r in runs] == [0, 1, 2]
        assert all(r["nodes_expanded"] <= 200 for r in runs)
        # the planning loop's time, split into the sampler's and the planner's share
        assert all(r["sampler_time_s"] + r["planner_time_s"] == pytest.approx(r["wall_time_s"], abs=1e-9)
                   and r["sampler_time_s"] > 0 and r["planner_time_s"] > 0 for r in runs)
    assert "sampler / planner [ms]" in result.stdout
    assert out_plot.stat().st_size > 0
    assert sorted(p.name for p in render_dir.iterdir()) == ["maze2d_goal-bias_problem0.png",
                                                            "maze2d_uniform_problem0.png"]


@pytest.mark.parametrize("args, fragments", [
    (["benchmark", "--samplers", "uniform,no-such-sampler", "--problems", "1"], ["no-such-sampler", "uniform"]),
    (["benchmark", "--task", "no-such-task"], ["no-such-task", "maze2d"]),
    (["benchmark", "--problems", "-3"], ["--problems"]),
    (["benchmark", "--problems", "1000000000"], ["--problems", "1,000,000"]),
    (["benchmark", "--problems", str(2**63)], ["--problems"]),
])
def test_bad_input_exits_with_one_line(args: list[str], fragments: list[str]):
    assert_one_line_error(gnn_mp(*args), *fragments)


@pytest.mark.parametrize("args, fragments", [
    (["benchmark", "--workers", "0"], ["--workers"]),
    (["benchmark", "--max-nodes", "-1"], ["--max-nodes"]),
    (["benchmark", "--problems", "1", "--checkpoint", "gnn=/no/such/file.pt", "--samplers", "gnn"],
     ["missing checkpoint"]),
    (["benchmark", "--problems", "1", "--checkpoint", "uniform=agents/checkpoints/gnn_maze2d.pt"], ["no weights"]),
    (["benchmark", "--problems", "1", "--samplers", "rl-ppo-torchrl"],     # nothing shipped for maze2d
     ["missing checkpoint", "gnn-mp train rl --lib torchrl --task maze2d", "--checkpoint rl-ppo-torchrl=PATH"]),
    (["benchmark", "--samplers", "gnn", "--checkpoint", "gnn=a.pt", "--checkpoint", "gnn=b.pt"],
     ["--checkpoint given twice", "'gnn'"]),
    (["benchmark", "--samplers", "ompl-kpiece", "--task", "maze2d"], ["ompl-kpiece"]),
    (["benchmark", "--suite", "no-such-suite"], ["no-such-suite"]),
    (["benchmark", "--samplers", "ompl-rrt", "--ompl-time-limit", "inf"], ["--ompl-time-limit", "finite"]),
    (["benchmark", "--samplers", "uniform,ompl-rrt", "--seed", str(2**70)], ["--seed"]),
    (["benchmark", "--problems", "1", "--json", "/"], ["--json", "expected a file"]),
    (["train", "no-such-model"], ["train"]),
    (["train", "sampler", "--seed", str(2**64)], ["--seed", "2**32"]),
    (["critical", "train", "--seed", str(2**64)], ["--seed", "2**32"]),
    (["no-such-command"], ["no-such-command"]),
    # every count and size flag is bounded by one shared validator (train/args.py)
    (["benchmark", "--workers", "100000"], ["--workers", "at most 256"]),
    (["benchmark", "--workers", str(10**30)], ["--workers", "at most 256"]),
    (["train", "rl", "--pi-arch", "-1"], ["--pi-arch"]),
    (["train", "rl", "--pi-arch", "0"], ["--pi-arch"]),
    (["train", "rl", "--prior-temperature", "1e-300"], ["--prior-temperature", "0.001"]),
    (["train", "rl", "--candidates", "100000"], ["--candidates", "at most 4,096"]),
    (["train", "rl", "--candidate-hidden", str(10**30)], ["--candidate-hidden"]),
    (["train", "rl", "--n-envs", "100000"], ["--n-envs"]),
    (["train", "rl", "--n-steps", str(10**30)], ["--n-steps"]),
    (["train", "rl", "--eval-problems", str(10**30)], ["--eval-problems"]),
    (["train", "rl", "--threads", str(10**30)], ["--threads"]),
    (["train", "sampler", "--threads", str(10**30)], ["--threads"]),
    (["train", "sampler", "--problems", str(10**30)], ["--problems"]),
    (["train", "sampler", "--dagger-rounds", str(10**30)], ["--dagger-rounds"]),
    (["critical", "evaluate", "--threads", str(10**30)], ["--threads"]),
    (["critical", "evaluate", "--pairs-per-map", str(10**30)], ["--pairs-per-map"]),
    (["critical", "evaluate", "--num-maps", str(10**30)], ["--num-maps"]),
    # a figure suffix matplotlib cannot write is refused before any work
    (["benchmark", "--problems", "1", "--plot", "boxes"], ["--plot", "suffix"]),
    (["benchmark", "--problems", "1", "--plot", "boxes.txt"], ["--plot", "suffix"]),
    (["critical", "evaluate", "--plot", "fig.txt"], ["--plot", "suffix"]),
    # one task's flags with --suite are refused, not ignored
    (["benchmark", "--suite", "smoke", "--task", "arm"], ["--suite smoke", "--task"]),
    (["benchmark", "--suite", "smoke", "--problems", "3", "--samplers", "gnn"], ["--samplers", "--problems"]),
    # an empty path is refused, not taken as the current directory
    (["benchmark", "--render", ""], ["--render", "expected a path"]),
    (["benchmark", "--out", ""], ["--out", "expected a path"]),
    (["benchmark", "--ompl-log", ""], ["--ompl-log", "expected a path"]),
    (["critical", "train", "--out", ""], ["--out", "expected a path"]),
    (["train", "sampler", "--data-dir", ""], ["--data-dir", "expected a path"]),
])
def test_bad_input_in_process(args: list[str], fragments: list[str], capsys):
    """The same one-line contract, checked in-process (faster than a subprocess per case)."""
    from train.cli import main
    try:
        code = main(args)
    except SystemExit as exit_:   # argparse errors exit from inside parse_args
        code = exit_.code
    assert code not in (0, None)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(f in err[0] for f in fragments), err


def test_environment_docs_cover_every_id_and_info_key():
    """docs/environments.md stays consistent with the registration table and the env's info."""
    import gymnasium as gym

    from gnn_mp_envs.registration import BUILTIN_TASKS

    text = (Path(__file__).resolve().parents[1] / "docs" / "environments.md").read_text()
    for env_id in (env_id for spec in BUILTIN_TASKS for env_id in spec.envs):
        assert f"`{env_id}`" in text, env_id
    env = gym.make("GNNMP/Maze2DRRT-v0", split="test", max_nodes=50)
    _, info = env.reset(options={"index": 0})
    for key in [*info, "path", "path_controls", "path_nodes"]:
        assert f"`{key}`" in text, key
    for key in env.observation_space.spaces:
        assert f"`{key}`" in text, key


def test_train_help_lists_the_targets_and_their_flags():
    result = gnn_mp("train", "--help")
    assert result.returncode == 0 and "critical" in result.stdout and "sampler" in result.stdout
    result = gnn_mp("train", "sampler", "--help")
    assert result.returncode == 0 and "usage: gnn-mp train sampler" in result.stdout and "--dagger-rounds" in result.stdout
    assert "(default: 400)" in result.stdout


def test_listing_the_samplers_imports_no_torch():
    code = "import sys; from train.cli import main; main(['samplers']); print('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    lines = result.stdout.strip().splitlines()
    assert lines[-1] == "False" and any(line.startswith("gnn ") for line in lines)


@pytest.mark.parametrize("argv", [["train", "sampler", "--help"], ["train", "sampler", "--model", "nope"]])
def test_train_sampler_help_and_bad_flags_import_no_torch(argv):
    """`gnn-mp train sampler --help` took 10-14 s importing torch before argparse:
    the flags live in train.tree.args, and torch is imported once they parsed."""
    code = ("import sys\nfrom train.cli import main\ntry:\n    main(%r)\nexcept SystemExit as exc:\n"
            "    print('rc', exc.code)\nprint('torch' in sys.modules)" % (argv,))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    lines = result.stdout.strip().splitlines()
    assert lines[-1] == "False", result.stdout + result.stderr
    assert lines[-2] == ("rc 0" if "--help" in argv else "rc 2"), result.stdout + result.stderr


def test_version_and_render_without_a_mode(capsys):
    """`gnn-mp --version` names the installed version; render() without a render mode warns as
    Gymnasium's own envs do instead of returning None silently."""
    import warnings

    import gymnasium as gym
    from importlib.metadata import version
    from train.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"gnn-mp {version('gnn-mp-envs')}"
    env = gym.make("GNNMP/Maze2DRRT-v0", disable_env_checker=True)
    env.reset(seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert env.render() is None
    assert any("render_mode='rgb_array'" in str(w.message) for w in caught)


def test_an_import_module_that_raises_is_one_line(tmp_path, monkeypatch, capsys):
    """--import of a module whose own code fails (not an ImportError): one line naming the module
    and the error, rc 2."""
    from train.cli import main
    (tmp_path / "raising_plugin.py").write_text("raise RuntimeError('boom at import')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    code = main(["benchmark", "--import", "raising_plugin", "--problems", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "raising_plugin" in err[0] and "boom at import" in err[0], err


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_an_output_that_is_not_a_regular_file_is_refused_and_left_alone(kind, tmp_path, capsys):
    """A FIFO or a device (``/dev/null``) given as an output is refused in one line and never
    replaced by a regular file (as root, replacing /dev/null would break the system)."""
    import os
    import stat
    from train.cli import main
    if kind == "fifo":
        target = tmp_path / "pipe.png"         # a figure suffix: only the file's kind is wrong
        os.mkfifo(target)
    else:
        target = Path("/dev/null")
    for flag in ("--json", "--plot"):
        try:
            code = main(["benchmark", "--problems", "1", flag, str(target)])
        except SystemExit as exit_:
            code = exit_.code
        assert code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        mode = os.stat(target).st_mode
        assert (stat.S_ISFIFO(mode) if kind == "fifo" else stat.S_ISCHR(mode))


def test_atomic_writes_refuse_special_files_and_write_through_links(tmp_path):
    """Every output of every entry point goes through ``atomic_path``: a FIFO is refused with an
    OSError naming it (the CLIs print it in one line), a symbolic link keeps pointing at the file
    it names, which gets the new content."""
    import os
    from gnn_mp_envs.utils.io import atomic_write_text
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match="not a regular file"):
        atomic_write_text(fifo, "x")
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    atomic_write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"


def test_the_benchmark_starts_no_more_workers_than_jobs(monkeypatch):
    """``--workers 8`` over 2 jobs starts a pool of 2 processes (one job: none)."""
    import train.benchmark.runs as runs
    import train.workers
    from train.benchmark.args import BenchmarkArgs
    sizes = []

    class Recording(train.workers.WorkerPool):
        def __init__(self, workers, modules=()):
            sizes.append(workers)
            super().__init__(workers, modules)

    monkeypatch.setattr(train.workers, "WorkerPool", Recording)      # the pool train.workers.SharedPool makes
    runs.run_benchmark(BenchmarkArgs(task="maze2d", samplers=["uniform"], problems=2, workers=8, progress=False))
    runs.run_benchmark(BenchmarkArgs(task="maze2d", samplers=["uniform"], problems=1, workers=8, progress=False))
    assert sizes == [2]


def test_train_rl_without_yaml_names_the_extra(monkeypatch, capsys):
    """An environments-only install (no pyyaml, part of the agents extra): `train rl` is the same
    one-line refusal as the other commands of that extra, not a raw ModuleNotFoundError."""
    import sys as _sys
    from train.cli import main
    monkeypatch.setitem(_sys.modules, "yaml", None)
    try:
        code = main(["train", "rl", "--total-steps", "10"])
    except SystemExit as exit_:
        code = exit_.code
    assert code not in (0, None)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "agents" in err[0] and "yaml" in err[0], err


def test_import_finds_a_module_of_the_current_directory_that_shadows_nothing(tmp_path):
    """`gnn-mp benchmark --import my_plugin` run in the plugin's directory needs no PYTHONPATH, and a
    `train.py` and an `agents/` package beside it do not replace this package's modules (in the
    main process and in spawned workers)."""
    (tmp_path / "my_plugin.py").write_text(
        "from agents.samplers import register_sampler\n"
        "from agents.samplers.baselines import UniformSampler\n"
        "register_sampler('my-uniform', lambda low, high, task=None, seed=None, **kw: "
        "UniformSampler(low, high, seed, **kw), 'uniform, from a plugin')\n")
    (tmp_path / "train.py").write_text("raise SystemExit('the current directory shadowed train')\n")
    (tmp_path / "agents").mkdir()
    (tmp_path / "agents" / "__init__.py").write_text("raise SystemExit('the current directory shadowed agents')\n")
    script = Path(sys.executable).parent / "gnn-mp"
    result = subprocess.run([str(script), "benchmark", "--import", "my_plugin", "--samplers", "my-uniform,gnn",
                             "--problems", "2", "--workers", "2", "--no-progress", "--json", "out.json"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads((tmp_path / "out.json").read_text())
    assert report["samplers"] == ["my-uniform", "gnn"] and report["results"]["my-uniform"]["success_rate"] == 1.0
