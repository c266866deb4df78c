"""The hyperparameter files ``train/rl/hyperparams/<task>.yml`` are in RL Zoo's format: ``rl_zoo3.train
-conf FILE`` trains from each (when the ``zoo`` extra is installed), and ``gnn-mp train rl`` reads the
same files into the flags it always had."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HYPERPARAMS = ROOT / "train" / "rl" / "hyperparams"
TASKS = ("maze2d", "pendulum", "arm", "panda-mbm")

#: What each task's file gave its PPO runs (SB3 and TorchRL alike) in the earlier layout.
PPO = {"maze2d": {"total_steps": 200000, "n_envs": 16, "n_steps": 256, "batch_size": 1024, "n_epochs": 4, "lr": 1e-3,
                  "ent_coef": 0.01, "candidates": 20, "pick_head": "shared", "eval_every": 50000,
                  "eval_problems": 100},     # issue 51: the five-minute recipe (docs/rl.md)
       "arm": {"total_steps": 200000, "n_envs": 8, "n_steps": 128, "batch_size": 256, "n_epochs": 4, "lr": 3e-4,
               "ent_coef": 0.01, "eval_every": 10000, "eval_problems": 50, "select_on": "collision_checks"},
       "pendulum": {"total_steps": 1000000, "n_envs": 16, "n_steps": 256, "batch_size": 1024, "n_epochs": 4,
                    "lr": 3e-4, "clip_range": 0.1, "ent_coef": 0.0, "candidates": 20, "prior": "gnn",
                    "prior_temperature": 0.5, "pick_head": "shared", "pi_arch": [], "eval_every": 50000,
                    "eval_problems": 100}}
PPO["panda-mbm"] = PPO["arm"]


@pytest.mark.parametrize("task", TASKS)
def test_each_file_is_read_into_the_flags_it_always_gave(task):
    """The flags a run gets from its task's file: the earlier sections' values (the picker's keys
    skipped by a box run, nothing for SAC)."""
    from train.rl.args import read_hyperparams
    from train.rl.cli import PICK_ONLY_FLAGS
    path = HYPERPARAMS / f"{task}.yml"
    expected = PPO[task]
    for lib in ("sb3", "torchrl"):
        values = read_hyperparams(path, lib, "ppo", task)
        assert {k: v for k, v in values.items() if k != "net_arch" or v != [64, 64]} == expected
    assert read_hyperparams(path, "sb3", "sac", task, action="box") == {}
    from train.rl.cli import parse
    box = parse(["--task", task, "--action", "box"])
    for name, value in expected.items():
        if name not in PICK_ONLY_FLAGS:
            assert getattr(box, name) == value


def test_the_file_layout_is_rl_zoos_and_bad_sections_are_one_line(tmp_path):
    import yaml

    from gnn_mp_envs.registration import rl_env_id, task_spec
    from train.rl.args import read_hyperparams
    for task in TASKS:
        data = yaml.safe_load((HYPERPARAMS / f"{task}.yml").read_text())
        assert set(data) == {rl_env_id(task_spec(task).env_id), "gnn-mp"}
    cases = [("GNNMP/Maze2DRRT-RLPick-v0: {n_stepz: 3}", "unknown key 'n_stepz'"),
             ("GNNMP/Maze2DRRT-RLPick-v0: {policy: MlpPolicy}", "policy 'MlpPolicy'"),
             ("GNNMP/PendulumRRT-RLPick-v0: {n_steps: 3}", "no section for task 'maze2d'"),
             ("GNNMP/Maze2DRRT-RLPick-v0: {n_steps: 3}\ngnn-mp: {n_steps: 4}", "given both"),
             ("GNNMP/Maze2DRRT-RLPick-v0: {env_kwargs: {gamma: 0.5}}", "unknown key 'gamma'"),
             ("gnn-mp: {algo: a2c}", "algo must be one of")]
    for text, fragment in cases:
        path = tmp_path / "h.yml"
        path.write_text(text)
        with pytest.raises(ValueError, match=fragment) as info:
            read_hyperparams(path, "sb3", "ppo", "maze2d")
        assert "\n" not in str(info.value)
    legacy = tmp_path / "legacy.yml"                    # the earlier layout is still read
    legacy.write_text("sb3-ppo: {n_steps: 32, learning_rate: 0.001}\n")
    assert read_hyperparams(legacy, "sb3", "ppo", "maze2d") == {"n_steps": 32, "lr": 0.001}


@pytest.mark.parametrize("task", ("maze2d", "pendulum"))
def test_rl_zoo_trains_from_the_shipped_file(task, tmp_path):
    """``python -m rl_zoo3.train --algo ppo -conf <task>.yml`` on the task's RL id: a few hundred steps
    (the budget flags RL Zoo takes on its command line), a saved model. ``make install`` installs the
    zoo extra, so a missing rl_zoo3 fails here rather than skipping."""
    assert importlib.util.find_spec("rl_zoo3") is not None, "rl_zoo3 is the zoo extra: pip install 'gnn-mp-envs[zoo]'"
    from gnn_mp_envs.registration import rl_env_id, task_spec
    env_id = rl_env_id(task_spec(task).env_id)
    done = subprocess.run([sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", env_id,
                           "--gym-packages", "gnn_mp_envs", "-conf", str(HYPERPARAMS / f"{task}.yml"), "-n", "256",
                           "--eval-freq", "-1", "--seed", "0", "--log-folder", str(tmp_path), "-params", "n_envs:2",
                           "n_steps:64", "batch_size:32"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    zips = list(tmp_path.glob(f"ppo/*/{env_id.replace('/', '-')}.zip"))
    assert zips, done.stdout[-2000:]
    from stable_baselines3 import PPO
    model = PPO.load(zips[0], device="cpu")          # RL Zoo's own file, made here: loading it is safe
    assert model.num_timesteps >= 256 and type(model.policy).__name__ == "CandidatePickPolicy"
    if task == "pendulum":
        assert model.policy.pick_head == "shared" and model.observation_space["candidate_features"].shape[0] == 20
