"""`train rl --parallel` on a task of the user's directory: the env processes (SB3's SubprocVecEnv,
TorchRL's ParallelEnv) import the ``--import`` module from the file the command loaded, and nothing else of
the directory (issue 51 item 11: they knew no such task, a 33-line traceback with SB3, 79 with TorchRL)."""

from __future__ import annotations

import subprocess

import pytest

from tests.plugin_dir import TASK, cli, environment, make_user_directory


@pytest.mark.parametrize("lib", ["sb3", "torchrl"])
def test_parallel_env_processes_import_the_plugin(tmp_path, lib):
    user = make_user_directory(tmp_path)
    result = subprocess.run(cli("train", "rl", "--lib", lib, "--import", "cwd_task", "--task", TASK, "--parallel",
                                "--n-envs", "2", "--total-steps", "32", "--n-steps", "16", "--batch-size", "16",
                                "--eval-problems", "1", "--eval-every", "1000", "--hyperparams", "none",
                                "--out", "run", "--no-progress"),
                            cwd=user, env=environment(), capture_output=True, text=True, timeout=400)
    assert result.returncode == 0, result.stderr[-3000:]
    assert (user / "run" / "best.pt").is_file()
    assert "Traceback" not in result.stderr
