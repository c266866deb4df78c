"""`train rl --lib torchrl`: a damaged resume state and a SIGTERM under --ray end in one line (issue 52
item 7: an 18-21-line traceback ending in the right CheckpointError; SIGABRT with Ray's C++ stack dump)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--lib", "torchrl", "--task", "maze2d", "--n-envs", "2", "--n-steps", "16", "--batch-size", "16",
        "--eval-problems", "1", "--hyperparams", "none", "--no-progress"]


def _gnn_mp(*argv: str) -> list[str]:
    return [sys.executable, "-c", "import sys; from train.cli import main; sys.exit(main())", *argv]


def test_a_damaged_torchrl_resume_state_is_one_line(tmp_path, capsys):
    """The command's stderr is one line and its status 2 (a process, as a user runs it); the other
    damages through the same ``main`` in this process."""
    from train.rl.cli import main
    run = tmp_path / "run"
    first = subprocess.run(_gnn_mp("train", "rl", *TINY, "--total-steps", "32", "--eval-every", "32", "--out", str(run)),
                           cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr[-3000:]
    state = run / "training_state.pt"
    whole = state.read_bytes()
    policy = (run / "best.pt").read_bytes()
    resume = [*TINY, "--total-steps", "64", "--eval-every", "32", "--out", str(run), "--resume"]
    for damage, says in ((b"", "empty file"), (whole[: len(whole) // 2], "not a readable checkpoint"),
                         (policy, "not a training state")):
        state.write_bytes(damage)
        if not damage:
            again = subprocess.run(_gnn_mp("train", "rl", *resume), cwd=ROOT, capture_output=True, text=True,
                                   timeout=300)
            code, err = again.returncode, again.stderr
        else:
            code, err = main(resume), capsys.readouterr().err
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1, err[-3000:]
        assert lines[0].startswith("gnn-mp train rl: error: --resume:") and str(state) in lines[0] and says in lines[0]


def _descendants(pid: int) -> set[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_sigterm_on_a_torchrl_ray_run_is_one_line_and_leaves_no_ray_process(tmp_path):
    pytest.importorskip("ray")
    proc = subprocess.Popen(_gnn_mp("train", "rl", *TINY, "--ray", "--ray-workers", "2", "--total-steps", "1000000",
                                    "--eval-every", "1000000", "--out", str(tmp_path / "run")),
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        for line in proc.stdout:                 # training has started: the untrained policy's evaluation
            if "step       0:" in line:
                break
        time.sleep(3)                            # the actors collect
        spawned = _descendants(proc.pid)         # Ray's processes (GCS, raylet, agents, the actors)
        assert spawned, f"no Ray processes; the run {'is running' if proc.poll() is None else 'ended'}"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    # Ray's own notice at its start is not an error line of ours
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("Token authentication")]
    assert proc.returncode == 130 and lines == ["gnn-mp: error: interrupted"], err[-3000:]
    deadline = time.monotonic() + 20
    while [p for p in spawned if _alive(p)] and time.monotonic() < deadline:
        time.sleep(0.5)
    left = {}
    for pid in (p for p in spawned if _alive(p)):     # the test's own leftovers: named, then ended by their ids
        try:
            left[pid] = Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")[:100]
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    assert not left, left
