"""The benchmark's worker processes die with it; Ctrl-C stops it quickly with one line."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from train import benchmark as bm

ROOT = Path(__file__).resolve().parents[1]
# A benchmark that runs for about a minute on 2 workers.
LONG_RUN = ["benchmark", "--task", "pendulum", "--samplers", "uniform,goal-bias", "--problems", "60",
            "--workers", "2", "--no-progress"]


def start(*extra: str) -> subprocess.Popen:
    """The CLI in its own process group, with Ctrl-C handled as in a terminal (a background
    job of a non-interactive shell would start with SIGINT ignored)."""
    code = "import sys; from train.cli import main; sys.exit(main())"
    return subprocess.Popen([sys.executable, "-c", code, *LONG_RUN, *extra], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def descendants(pid: int) -> set[int]:
    out = subprocess.run(["ps", "-e", "-o", "pid=,ppid="], capture_output=True, text=True).stdout
    children: dict[int, list[int]] = {}
    for line in out.splitlines():
        p, pp = map(int, line.split())
        children.setdefault(pp, []).append(p)
    found, stack = set(), [pid]
    while stack:
        for c in children.get(stack.pop(), []):
            found.add(c)
            stack.append(c)
    return found


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:   # a zombie is dead
        return open(f"/proc/{pid}/stat").read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def wait_for_workers(proc: subprocess.Popen, count: int = 2, timeout: float = 60) -> set[int]:
    end = time.time() + timeout
    while time.time() < end:
        found = descendants(proc.pid)
        if len(found) >= count:
            time.sleep(3)   # let the workers start planning
            return descendants(proc.pid)
        time.sleep(0.2)
    raise AssertionError("the benchmark started no workers")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_workers_die_with_the_benchmark(sig):
    proc = start()
    workers = wait_for_workers(proc)
    proc.send_signal(sig)
    proc.wait(timeout=10)
    time.sleep(5)
    assert not [p for p in workers if alive(p)], "processes outlived the benchmark"


def test_ctrl_c_stops_within_two_seconds_with_one_line_and_keeps_finished_runs(tmp_path):
    out = tmp_path / "partial.json"
    args = [a for a in LONG_RUN if a != "--no-progress"]
    code = "import sys; from train.cli import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, *args, "--json", str(out)], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    err_chunks: list[str] = []
    reader = threading.Thread(target=lambda: err_chunks.extend(iter(lambda: proc.stderr.read(64), "")))
    reader.start()
    deadline = time.time() + 120
    while not re.search(r"\| *[2-9]\d*/120", "".join(err_chunks)):   # a couple of runs finished
        assert time.time() < deadline and proc.poll() is None, "".join(err_chunks)
        time.sleep(0.2)
    workers = descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)   # Ctrl-C in a terminal reaches the whole group
    proc.wait(timeout=30)                # a benchmark that ignored Ctrl-C would not end in time
    reader.join(timeout=10)
    err = "".join(err_chunks)
    assert proc.returncode == 130
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip() and "%|" not in line]
    assert lines == [f"wrote {out} (partial)", lines[-1]] and lines[-1].startswith(
        "gnn-mp: error: benchmark: interrupted;"), err
    report = json.loads(out.read_text())
    assert report["partial"] is True and 0 < sum(map(len, report["runs"].values())) < 120
    time.sleep(5)
    assert not [p for p in workers if alive(p)]


def test_a_sampler_returning_nan_is_named_in_one_line(tmp_path):
    plugin = tmp_path / "nan_sampler.py"
    plugin.write_text(
        "import torch\n"
        "from agents.samplers import register_sampler\n"
        "from agents.samplers.baselines import UniformSampler\n"
        "class NaNSampler(UniformSampler):\n"
        "    def act(self, obs):\n"
        "        return super().act(obs) * float('nan')\n"
        "register_sampler('nan', lambda low, high, task=None, seed=None, **kw: NaNSampler(low, high, seed))\n")
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, "benchmark", "--import", "nan_sampler", "--samplers",
                             "nan", "--problems", "2", "--no-progress"], cwd=ROOT, capture_output=True, text=True,
                            env={**os.environ, "PYTHONPATH": f"{tmp_path}:{ROOT}"}, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "sampler 'nan' on maze2d problem" in lines[-1] and "finite" in lines[-1], result.stderr


def test_json_over_an_existing_file_stays_whole_when_the_write_fails(tmp_path, monkeypatch):
    target = tmp_path / "report.json"
    target.write_text('{"old": true}\n')
    import gnn_mp_envs.utils.io as io

    def failing_replace(src, dst):
        raise OSError(27, "File too large")
    monkeypatch.setattr(io.os, "replace", failing_replace)
    with pytest.raises(OSError) as info:
        bm.write_outputs(bm.BenchmarkArgs(json=target), {"task": "maze2d"})
    assert info.value.filename == str(target)
    assert json.loads(target.read_text()) == {"old": True}
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]   # no temporary file left


def test_a_killed_worker_is_one_line_and_the_finished_runs_are_written(tmp_path):
    """A worker killed mid-run (SIGKILL, out of memory) breaks the pool: the benchmark says so
    in one line and writes the runs that finished, marked partial."""
    plugin = tmp_path / "killer_sampler.py"
    plugin.write_text(
        "import os, signal\n"
        "from agents.samplers import register_sampler\n"
        "from agents.samplers.baselines import UniformSampler\n"
        "class KillerSampler(UniformSampler):\n"
        "    def act(self, obs):\n"
        "        if int(obs['num_nodes'][0]) > 3 and abs(float(obs['goal'][0]) - self.victim_goal) < 1e-5:\n"
        "            os.kill(os.getpid(), signal.SIGKILL)\n"
        "        return super().act(obs)\n"
        "def make(low, high, task=None, seed=None, **kw):\n"
        "    s = KillerSampler(low, high, seed)\n"
        "    import gnn_mp_envs\n"
        "    s.victim_goal = float(gnn_mp_envs.make_task('maze2d').problem('test', 5).goal[0])\n"
        "    return s\n"
        "register_sampler('killer', make)\n")
    out = tmp_path / "report.json"
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, "benchmark", "--import", "killer_sampler", "--samplers",
                             "uniform,killer", "--problems", "8", "--workers", "2", "--no-progress",
                             "--json", str(out)], cwd=ROOT, capture_output=True, text=True,
                            env={**os.environ, "PYTHONPATH": f"{tmp_path}:{ROOT}"}, timeout=300)
    assert result.returncode not in (0, 130) and "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert lines[-1].startswith("gnn-mp: error: benchmark: a worker process died"), result.stderr
    report = json.loads(out.read_text())
    assert report["partial"] is True
    finished = sum(map(len, report["runs"].values()))
    assert 0 < finished < 16
    assert all(r["problem"] != 5 for r in report["runs"]["killer"])


@pytest.mark.parametrize("wait_for_runs", [True, False])
def test_sigterm_keeps_the_finished_runs_and_an_older_file_when_none_finished(tmp_path, wait_for_runs):
    """SIGTERM ends a benchmark like Ctrl-C (finished runs written, marked partial); stopped before
    any run finished, an older complete --json is left whole."""
    out = tmp_path / "runs.json"
    out.write_text('{"complete": true}\n')
    args = [a for a in LONG_RUN if a != "--no-progress"]
    code = "import sys; from train.cli import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, *args, "--json", str(out)], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    err_chunks: list[str] = []
    reader = threading.Thread(target=lambda: err_chunks.extend(iter(lambda: proc.stderr.read(64), "")))
    reader.start()
    deadline = time.time() + 120
    pattern = r"\| *[2-9]\d*/120" if wait_for_runs else r"\| *0/120"      # runs finished / the bar just drawn
    while not re.search(pattern, "".join(err_chunks)):
        assert time.time() < deadline and proc.poll() is None, "".join(err_chunks)
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=30)
    reader.join(timeout=10)
    err = "".join(err_chunks)
    assert proc.returncode == 130, err
    if wait_for_runs or "wrote" in err:      # (a fast machine may finish a run before the signal lands)
        report = json.loads(out.read_text())
        assert report["partial"] is True and 0 < sum(map(len, report["runs"].values())) < 120
    else:
        assert out.read_text() == '{"complete": true}\n' and "left as it was" in err, err
