"""A user's own agent: a TorchRL actor on TorchRL's default action encoding, saved with
``agents.rl.export.save_rl_checkpoint`` and benchmarked as a row of its own beside the shipped ones
(issue 51, items 1 and 3); actions the pick envs cannot read are refused in one line; ``train rl
--minutes`` (item 2's budget) and its exact repeat with ``--total-steps``."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import gnn_mp_envs  # noqa: F401  (registers the envs)

PICK_ID = "GNNMP/Maze2DRRT-RLPick-v0"


def pick_actor(seed: int = 0):
    from agents.rl.torchrl import make_pick_actor
    torch.manual_seed(seed)
    return make_pick_actor(gym.make(PICK_ID).observation_space)


# ---------------------------------------------------------------------------- item 3: the encoding
def test_torchrl_default_encoding_with_the_default_actor_grows_trees():
    """The issue's repro: GymEnv(id) (one-hot by default), make_pick_actor(spaces) without an
    action_spec, 300 steps: the tree grows (it stayed at 2 nodes: the actor's index, read by TorchRL
    as a one-hot vector, became candidate 0, the target, every step)."""
    from torchrl.envs import GymEnv
    torch.set_num_threads(1)
    env = GymEnv(PICK_ID)
    env.set_seed(0)
    actor = pick_actor()
    batch = env.rollout(300, actor, break_when_any_done=False)
    assert batch["action"].shape[-1] == env.action_spec.shape[-1]            # one-hot, the env's encoding
    assert batch["next", "num_nodes"].max() > 20                              # the view's rows: up to 64


def test_an_actor_in_another_encoding_is_refused_in_one_line():
    """A one-hot actor into GymEnv(id, categorical_action_encoding=True): the env gets a vector and
    refuses it in one line (it read its first element, candidate 0 or 1, silently)."""
    from torchrl.envs import GymEnv
    env = GymEnv(PICK_ID, categorical_action_encoding=True)
    env.set_seed(0)
    with pytest.raises(ValueError) as info:
        env.rollout(5, pick_actor())
    message = str(info.value)
    assert len(message.splitlines()) == 1 and "one candidate index" in message and "shape (8,)" in message


@pytest.mark.parametrize("env_id", [i for i in gym.registry if i.startswith("GNNMP/") and "-RLPick-" in i])
def test_every_pick_env_refuses_what_is_no_candidate_index(env_id):
    """On every RLPick id: a one-hot vector, several indices, a fraction, NaN, a bool, a string and an
    index out of range are each one ValueError line naming the candidate index; an index as an int,
    a numpy integer, a 0-d or one-element array or an integral float is read as that index."""
    env = gym.make(env_id)
    env.reset(seed=0)
    count = env.action_space.n
    try:
        for bad in (np.eye(count)[3], np.array([1, 2]), 2.5, float("nan"), True, "3", count, -1):
            with pytest.raises(ValueError) as info:
                env.step(bad)
            assert len(str(info.value).splitlines()) == 1 and "one candidate index" in str(info.value), bad
        for good in (3, np.int64(3), np.array(3), np.array([3]), 3.0):
            env.step(good)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", [i for i in gym.registry if i.startswith("GNNMP/") and "-RLBox-" in i])
def test_every_box_env_refuses_a_wrong_shape_in_one_line(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    d = env.action_space.shape[0]
    try:
        for bad in (np.zeros(d + 1, np.float32), np.zeros((1, d), np.float32), 0.5):
            with pytest.raises(ValueError) as info:
                env.step(bad)
            assert len(str(info.value).splitlines()) == 1 and f"shape ({d},)" in str(info.value), bad
    finally:
        env.close()


# ---------------------------------------------------------------------------- item 1: own checkpoints
def test_a_saved_torchrl_picker_scores_as_the_actor(tmp_path):
    """save_rl_checkpoint reads the settings from the env (GymEnv of an RL id) and the sampler that loads
    the file computes the actor's own logits on the same candidate features."""
    from tensordict import TensorDict
    from torchrl.envs import GymEnv

    from agents.registry import load_sampler, sampler_for_checkpoint
    from agents.rl.export import save_rl_checkpoint
    actor = pick_actor(3)
    path = save_rl_checkpoint(tmp_path / "mine.pt", actor, GymEnv(PICK_ID))
    assert sampler_for_checkpoint(path) == "rl-ppo-torchrl"
    sampler = load_sampler("rl-ppo-torchrl", task="maze2d", checkpoint=path, seed=0)
    env = gym.make(PICK_ID)
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        with torch.no_grad():
            expected = actor(TensorDict({"candidate_features": torch.as_tensor(obs["candidate_features"])}, []))
        np.testing.assert_allclose(sampler.logits(obs, obs["candidate_features"]), expected["logits"].numpy(),
                                   rtol=1e-5, atol=1e-6)
    from agents.rl.export import env_settings
    assert sampler.candidate_set.config() == env_settings(env)["candidates"] and sampler.view_nodes == 64


def test_a_saved_sb3_picker_scores_as_the_model(tmp_path):
    from stable_baselines3 import PPO

    from agents.registry import load_sampler, sampler_for_checkpoint
    from agents.rl.export import save_rl_checkpoint
    from agents.rl.sb3 import CandidateFeaturesExtractor
    env = gym.make(PICK_ID, candidates=12)
    model = PPO("MultiInputPolicy", env, n_steps=64, batch_size=32, seed=0, device="cpu",
                policy_kwargs={"features_extractor_class": CandidateFeaturesExtractor,
                               "net_arch": {"pi": [], "vf": [16]}})
    path = save_rl_checkpoint(tmp_path / "sb3.pt", model, env)
    assert sampler_for_checkpoint(path) == "rl-ppo"
    sampler = load_sampler("rl-ppo", checkpoint=path, seed=0)
    assert sampler.candidate_set.count == 12
    obs, _ = env.reset(seed=0)
    tensors, _ = model.policy.obs_to_tensor(obs)
    with torch.no_grad():
        expected = model.policy.get_distribution(tensors).distribution.logits.numpy()[0]
    got = sampler.logits(obs, obs["candidate_features"])
    np.testing.assert_allclose(got - got.max(), expected - expected.max(), rtol=1e-5, atol=1e-5)


def test_save_rl_checkpoint_refuses_a_mismatch_in_one_line(tmp_path):
    from agents.rl.export import ExportError, save_rl_checkpoint
    actor = pick_actor()
    for agent, env, fragment in ((actor, gym.make(PICK_ID, candidates=12), "scores 8 candidates, the env offers 12"),
                                 (actor, gym.make("GNNMP/Maze2DRRT-RLBox-v0"), "candidate picker and an env of box"),
                                 (actor, gym.make("CartPole-v1"), "not a planning env"),
                                 ("model", gym.make(PICK_ID), "pass an SB3 model")):
        with pytest.raises(ExportError) as info:
            save_rl_checkpoint(tmp_path / "x.pt", agent, env)
        assert len(str(info.value).splitlines()) == 1 and fragment in str(info.value)
    assert not (tmp_path / "x.pt").exists()


def test_a_labelled_row_runs_beside_the_shipped_one(tmp_path, capsys):
    """--samplers uniform,rl-ppo,mine --checkpoint mine=PATH: a row 'mine' beside the shipped rl-ppo
    (not replacing it); mine's runs are those of the sampler its kind names under that name, and
    rl-ppo's those of the shipped weights."""
    from torchrl.envs import GymEnv

    from agents.rl.export import save_rl_checkpoint
    from train.cli import main
    path = save_rl_checkpoint(tmp_path / "mine.pt", pick_actor(1), GymEnv(PICK_ID))
    common = ["benchmark", "--task", "maze2d", "--problems", "2", "--seed", "0", "--no-progress"]
    assert main([*common, "--samplers", "uniform,rl-ppo,mine", "--checkpoint", f"mine={path}",
                 "--json", str(tmp_path / "mine.json")]) == 0
    table = capsys.readouterr().out
    assert any(line.startswith("mine ") for line in table.splitlines())
    assert any(line.startswith("rl-ppo ") for line in table.splitlines())
    assert main([*common, "--samplers", "rl-ppo,rl-ppo-torchrl", "--checkpoint", f"rl-ppo-torchrl={path}",
                 "--json", str(tmp_path / "named.json")]) == 0
    counters = ("success", "nodes_expanded", "collision_checks", "iterations")

    def runs(file, name):
        rows = json.loads((tmp_path / file).read_text())["runs"][name]
        return [{k: r[k] for k in counters} for r in rows]
    assert runs("mine.json", "mine") == runs("named.json", "rl-ppo-torchrl")
    assert runs("mine.json", "rl-ppo") == runs("named.json", "rl-ppo")


def test_a_labelled_row_of_a_file_no_sampler_runs_is_one_line(tmp_path, capsys):
    from agents.checkpoints import SHIPPED_DIR
    from train.cli import main
    assert main(["benchmark", "--task", "maze2d", "--samplers", "uniform,mine", "--checkpoint",
                 f"mine={SHIPPED_DIR / 'critical_gnn.pt'}", "--problems", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no registered sampler runs" in err[0] and "critical/gnn" in err[0], err
    assert main(["benchmark", "--task", "maze2d", "--samplers", "uniform,mine", "--problems", "1",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown sampler 'mine'" in err[0] and "--checkpoint mine=PATH" in err[0], err


def test_the_registrys_kinds_are_the_loaders_kinds():
    """The kinds the registry names per sampler (written out so listing imports no torch) are the ones
    the samplers' loaders accept."""
    from agents.registry import BUILTIN_KINDS
    from agents.rl.sampler import RL_SAMPLERS
    from agents.tree.samplers import NAME_KINDS
    assert BUILTIN_KINDS == {**NAME_KINDS, **RL_SAMPLERS}


# ---------------------------------------------------------------------------- item 2: --minutes
@pytest.mark.parametrize("lib", ["sb3", "torchrl"])
def test_train_rl_minutes_stops_on_the_clock_and_total_steps_repeats_it(lib, tmp_path, capsys):
    """--minutes alone (the task file's step count does not apply) stops at a rollout boundary and says
    where; --total-steps with that number repeats the run: the same evaluations and the same best.pt."""
    import re
    import warnings

    from agents.checkpoints import read_checkpoint
    from train.cli import main
    tiny = ["train", "rl", "--lib", lib, "--task", "maze2d", "--n-envs", "2", "--n-steps", "16", "--batch-size",
            "16", "--eval-every", "96", "--eval-problems", "1", "--eval-max-steps", "50", "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main([*tiny, "--minutes", "0.1", "--out", str(tmp_path / "clock")]) == 0
        out = capsys.readouterr().out          # one rollout at least, however slow the first evaluation
        steps = int(re.search(r"--minutes 0.1: stopped at step ([\d,]+)", out).group(1).replace(",", ""))
        assert steps > 0 and steps % 32 == 0, out
        assert main([*tiny, "--total-steps", str(steps), "--out", str(tmp_path / "steps")]) == 0

    def evaluations(run):
        rows = json.loads((tmp_path / run / "evaluations.json").read_text())
        return [{k: v for k, v in r.items() if "wall" not in k} for r in rows]
    assert evaluations("clock") == evaluations("steps") and evaluations("clock")[-1]["steps"] == steps
    first, second = (read_checkpoint(tmp_path / run / "best.pt")["state_dict"] for run in ("clock", "steps"))
    assert all(torch.equal(first[k], second[k]) for k in first)


def test_prior_scale_starts_the_shared_head_blind_to_the_prior(tmp_path, capsys):
    """--prior-scale 0: the pendulum picker reads the prior's logits at weight 0 (a vanishing learning
    rate keeps it there); without a prior or a shared head the flag is one line."""
    import warnings

    from agents.checkpoints import read_checkpoint
    from train.cli import main
    tiny = ["train", "rl", "--task", "pendulum", "--n-envs", "2", "--n-steps", "16", "--batch-size", "16",
            "--total-steps", "32", "--eval-problems", "1", "--eval-max-steps", "20", "--lr", "1e-12", "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main([*tiny, "--prior-scale", "0", "--out", str(tmp_path / "blind")]) == 0
    state = read_checkpoint(tmp_path / "blind" / "policy.pt")["state_dict"]
    assert abs(float(state["logits.prior_scale"])) < 1e-6
    capsys.readouterr()                    # the run's own lines (a numba notice on a fresh cache)
    with pytest.raises(SystemExit) as info:
        main(["train", "rl", "--task", "maze2d", "--prior-scale", "0", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and "needs --prior and --pick-head shared" in err[0], err
