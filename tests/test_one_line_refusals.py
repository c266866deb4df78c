"""Inputs and stops that used to end in a traceback, a crash after the work or a silently ignored flag:
each is one line now."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_critical_train_and_val_evaluation_refuse_a_labelled_set_without_validation_maps(tmp_path, capsys):
    """Validation maps are every tenth from map 8: a 4-map set has none, and training used to crash
    after its first epoch (an empty validation set); now one line before any data or training."""
    from train.critical.cli import main
    small = ["--data", str(tmp_path / "data"), "--num-maps", "4", "--pairs-per-map", "2", "--eval-problems", "2"]
    assert main(["train", "--model", "gnn", *small, "--epochs", "1", "--out", str(tmp_path / "run" / "m.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--num-maps 4" in err[0] and "--num-maps 9" in err[0], err
    assert not (tmp_path / "run").exists() and not (tmp_path / "data").exists()
    (tmp_path / "ckpt").mkdir()
    assert main(["evaluate", *small, "--models", "gnn", "--checkpoints", str(tmp_path / "ckpt"), "--split", "val",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--split val" in err[0], err


@pytest.mark.parametrize("flags", [["--pick-head", "shared"], ["--pi-arch", "32"], ["--candidates", "12"],
                                   ["--candidate-hidden", "16", "--pick-head", "shared"]])
def test_train_rl_refuses_a_pickers_flags_with_a_box_policy(flags, capsys):
    from train.rl.cli import parse
    with pytest.raises(SystemExit) as info:
        parse(["--task", "maze2d", "--action", "box", *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and "--action box ignores the picker's flags" in err[0]
    assert flags[0] in err[0]
    args = parse(["--task", "pendulum", "--action", "box"])      # the task's file's picker keys are not the user's
    assert args.action == "box" and args.prior is None


def test_train_rl_refuses_a_zero_width_policy_layer(capsys):
    from train.rl.cli import parse
    with pytest.raises(SystemExit) as info:
        parse(["--task", "maze2d", "--pi-arch", "0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and "--pi-arch" in err[0]


@pytest.mark.parametrize("env_id", ["GNNMP/ArmBiRRT-v0", "GNNMP/PandaMBM-v0", "GNNMP/Maze2DRRT-v0"])
def test_step_and_reset_after_close_are_one_clear_error(env_id):
    """The arm's and Panda's simulator is gone after close(): not pybullet's 'Not connected to physics server'."""
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401
    env = gym.make(env_id)
    env.reset(seed=0)
    action = env.action_space.sample()
    env.close()
    for call in (lambda: env.step(action), lambda: env.reset(seed=1)):
        with pytest.raises(RuntimeError, match="on a closed environment") as info:
            call()
        assert "\n" not in str(info.value)
    env.close()        # closing twice stays harmless


@pytest.mark.parametrize("lib", ["sb3", "torchrl"])
def test_sigterm_on_a_parallel_rl_run_is_one_line_and_leaves_no_worker(tmp_path, lib):
    """`train rl --parallel` stopped by SIGTERM: one line (exit 130), not each worker's traceback of its
    broken pipe; no worker process left behind."""
    code = "import sys; from train.cli import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, "train", "rl", "--lib", lib, "--task", "maze2d",
                             "--total-steps", "1000000", "--n-envs", "2", "--n-steps", "64", "--batch-size", "32",
                             "--eval-problems", "1", "--parallel", "--no-progress", "--out", str(tmp_path / "run")],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        for line in proc.stdout:                 # training has started: the untrained policy's evaluation
            if "step       0:" in line:
                break
        children: list[str] = []
        deadline = time.monotonic() + 60              # the workers start within seconds, later on a loaded machine
        while not children and time.monotonic() < deadline:
            time.sleep(1)
            children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
        assert children, (f"no worker processes; the run {'is still running' if proc.poll() is None else 'ended'}"
                          + ("" if proc.poll() is None else f" (exit {proc.returncode}): {proc.stderr.read()[-3000:]}"))
        time.sleep(2)                                # let them start their rollouts
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 130 and lines == ["gnn-mp: error: interrupted"], err[-3000:]
    time.sleep(1)
    assert not [c for c in children if Path(f"/proc/{c}").exists()
                and open(f"/proc/{c}/stat").read().split()[2] != "Z"]


@pytest.mark.parametrize("argv, flag", [
    (["train", "sampler", "--task", "maze2d", "--minutes", "1e30"], "--minutes"),
    (["train", "sampler", "--task", "maze2d", "--dagger-minutes", "1e30"], "--dagger-minutes"),
    (["critical", "train", "--model", "gnn", "--time-budget", "1e30"], "--time-budget"),
])
def test_a_time_budget_past_thirty_days_is_refused_in_one_line(argv, flag, tmp_path, capsys):
    """A minutes flag of 1e30 used to start training that never ends (tools/fuzz_cli.py counted it
    as a hang): every time budget is at most 30 days, refused in one line with exit 2."""
    from train.cli import main
    with pytest.raises(SystemExit) as info:
        main([*argv, "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and flag in err[-1] and "at most 43,200" in err[-1], err
    assert not (tmp_path / "run").exists()
