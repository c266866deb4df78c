"""Candidate selection: the candidate features against brute force, the registered RL
ids (the MDP of `gnn-mp train rl`, with the time limit in the spec), the picker's numpy twin
against its torch model, SB3's .zip and --resume, and a user's own SB3 PPO from docs/rl.md."""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import gnn_mp_envs  # noqa: F401
from gnn_mp_envs.envs.candidates import CANDIDATE_KINDS, SCALAR_FEATURES, CandidateSet
from gnn_mp_envs.envs.wrappers import RL_MAX_EPISODE_STEPS, candidate_settings, make_rl_env, rl_env_id

ROOT = Path(__file__).resolve().parents[1]
torch.set_num_threads(1)


def grown_env(task: str, steps: int, seed: int = 0):
    """The task's planning env after ``steps`` uniform samples (full observation)."""
    env = gym.make(gnn_mp_envs.task_spec(task).env_id, split="val", copy_observations=True)
    obs, _ = env.reset(seed=seed, options={"index": 0})
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    cs = CandidateSet(low, high, **candidate_settings(task))
    for _ in range(steps):
        x = (low + (high - low) * rng.random(len(low))).astype(np.float32)
        cs.record(obs, x)
        obs, _, term, trunc, _ = env.step(x)
        if term or trunc:
            break
    return env, obs, cs


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
def test_candidate_features_match_brute_force(task):
    """Nearest node, reach and distances to the target by a brute-force loop under the planner's own metric."""
    env, obs, cs = grown_env(task, 60)
    problem = env.unwrapped.problem
    cands, feats = cs.propose(obs, np.random.default_rng(1))
    n = int(obs["num_nodes"][0])
    tree_nodes = np.asarray(obs["nodes"][:n], np.float64)
    D = float(problem.distance(problem.start[None], problem.goal)[0])
    kinds = feats[:, :len(CANDIDATE_KINDS)]
    assert np.array_equal(kinds.argmax(1)[:4], np.arange(4)) and np.all(kinds.argmax(1)[4:] == 4)
    np.testing.assert_allclose(cands[0], problem.goal, atol=1e-6)          # RRT: the target is the goal
    step = cs.step
    k = len(CANDIDATE_KINDS)
    for c, f in zip(cands.astype(np.float64), feats):
        dist = problem.distance(tree_nodes, c)                          # the planner's metric, brute force
        near = int(np.argmin(dist))
        assert f[k] == pytest.approx(np.log1p(dist[near] / step), rel=1e-4, abs=1e-5)
        assert f[k + 1] == pytest.approx(float(problem.distance(c[None], problem.goal)[0]) / D, rel=1e-4, abs=1e-5)
        assert f[k + 2] == pytest.approx(float(problem.distance(tree_nodes[near][None], problem.goal)[0]) / D,
                                         rel=1e-4, abs=1e-5)
        assert f[k + 4] == pytest.approx(np.log1p(n - 1 - near), abs=1e-5)   # age of the nearest node
    assert feats.shape[1] == SCALAR_FEATURES + 4 * len(cands[0])
    env.close()


@pytest.mark.parametrize("task", ["maze2d", "pendulum", "arm"])
def test_compiled_candidate_features_equal_the_numpy_statement_bit_for_bit(task):
    """The compiled candidates and features (:func:`_assemble`, :func:`_features`) against
    :meth:`CandidateSet.propose_reference` / :meth:`CandidateSet.features_reference`, along a growing tree (periodic coordinates on the pendulum, BiRRT's two trees on the arm): equal
    arrays, and the same nearest node remembered for ``record``."""
    env, obs, cs = grown_env(task, 0)
    rng, twin_rng, picks = np.random.default_rng(7), np.random.default_rng(7), np.random.default_rng(8)
    low, high = env.action_space.low, env.action_space.high
    twin = CandidateSet(low, high, **candidate_settings(task))       # numpy all the way, fed the same tree
    compared = 0
    for step in range(60):
        cands, feats = cs.propose(obs, rng)
        twin_cands, twin_feats = twin.propose_reference(obs, twin_rng)
        assert np.array_equal(cands, twin_cands) and np.array_equal(feats, twin_feats), (task, step)
        n = int(obs["num_nodes"][0])
        active = int(obs["active_tree"][0])
        target = cs._start if active == 1 else cs._goal
        extra = (low + (high - low) * picks.random((5, len(low)))).astype(np.float32).astype(np.float64)
        for pts in (cands.astype(np.float64), extra):
            fast = cs.features(pts, n, active, target)
            fast_near = cs._near.copy()
            slow = cs.features_reference(pts, n, active, target)
            assert np.array_equal(fast, slow), (task, step, np.abs(fast - slow).max())
            assert np.array_equal(fast_near, cs._near)
            compared += 1
        pick = int(picks.integers(len(cands)))
        x = cands[pick]
        cs.record(obs, x)
        twin.record(obs, x, pick)
        obs, _, term, trunc, _ = env.step(x)
        if term or trunc:
            break
    env.close()
    assert compared >= 20


@pytest.mark.parametrize("file", ["none", "the task's"])
def test_rl_ids_are_the_training_commands_mdp_with_the_time_limit(file):
    """gym.make(<RL id>) == make_rl_env(task) == what `gnn-mp train rl --hyperparams none` builds: same
    rewards, same observations for the same seed and actions; with the task's file, the same with the
    file's env_kwargs (maze2d.yml: 20 candidates, as RL Zoo's env gets them); TimeLimit in the spec, as
    RL Zoo reads it."""
    from train.rl.cli import parse
    env_id = rl_env_id("GNNMP/Maze2DRRT-v0")
    assert env_id == "GNNMP/Maze2DRRT-RLPick-v0"
    assert gym.spec(env_id).max_episode_steps == RL_MAX_EPISODE_STEPS
    assert gym.spec("GNNMP/ArmBiRRT-RLBox-v0").max_episode_steps == RL_MAX_EPISODE_STEPS
    args = parse(["--task", "maze2d"] + (["--hyperparams", "none"] if file == "none" else []))
    kwargs = {} if file == "none" else {"candidates": 20}
    envs = [gym.make(env_id, **kwargs), make_rl_env("maze2d", **kwargs),
            make_rl_env("maze2d", split="train", **args.env_kwargs())]
    assert all(isinstance(e.action_space, gym.spaces.Discrete) for e in envs)
    assert {e.action_space.n for e in envs} == {20 if kwargs else 8}
    runs = []
    for env in envs:
        obs, _ = env.reset(seed=4)
        rows = [obs["candidate_features"].copy()]
        rewards = []
        for t in range(40):
            obs, r, term, trunc, _ = env.step(t % env.action_space.n)
            rows.append(obs["candidate_features"].copy())
            rewards.append(r)
            if term or trunc:
                break
        runs.append((np.array(rewards), np.stack(rows)))
    for rewards, rows in runs[1:]:
        np.testing.assert_array_equal(rewards, runs[0][0])
        np.testing.assert_array_equal(rows, runs[0][1])


def test_pick_sampler_numpy_twin_matches_the_torch_policy():
    from agents.nn.encoders import CandidateEncoder
    from agents.rl.pick import PickPolicy
    from agents.rl.sampler import numpy_pick_layers, numpy_pick_logits
    env, obs, cs = grown_env("maze2d", 30)
    _, feats = cs.propose(obs, np.random.default_rng(0))
    torch.manual_seed(0)
    enc = CandidateEncoder(feats.shape[1], feats.shape[0], hidden=16, embed=8)
    for hidden in ([], [12]):
        policy = PickPolicy(enc.config(), hidden=hidden).eval()
        with torch.no_grad():
            expected = policy({"candidate_features": torch.as_tensor(feats)[None]})[0].numpy()
        np.testing.assert_allclose(numpy_pick_logits(numpy_pick_layers(policy), feats), expected, rtol=1e-5,
                                   atol=1e-5)
    env.close()


def test_sb3_run_saves_a_zip_and_resumes(tmp_path, monkeypatch, capsys):
    """model.zip loads with PPO.load; --resume continues the run to --total-steps; a damaged model.zip is
    refused in one line before any environment is made."""
    from stable_baselines3 import PPO

    import train.rl.sb3
    from train.cli import main
    base = ["train", "rl", "--task", "maze2d", "--n-envs", "2", "--n-steps", "64", "--batch-size", "32",
            "--eval-problems", "1", "--eval-max-steps", "200", "--out", str(tmp_path / "run"), "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(base + ["--total-steps", "128"]) == 0
        first = PPO.load(tmp_path / "run" / "model.zip", device="cpu")
        assert first.num_timesteps == 128
        assert main(base + ["--total-steps", "256", "--resume"]) == 0
    assert PPO.load(tmp_path / "run" / "model.zip", device="cpu").num_timesteps == 256
    assert (tmp_path / "run" / "best_model.zip").is_file()
    zipped = tmp_path / "run" / "model.zip"
    zipped.write_bytes(zipped.read_bytes()[:100])

    def no_envs(*args, **kwargs):
        raise AssertionError("environments made before the resumed model was read")
    monkeypatch.setattr(train.rl.sb3, "make_vec_env", no_envs)
    capsys.readouterr()
    assert main(base + ["--total-steps", "384", "--resume", "--parallel"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--resume:" in err[0] and "not a readable Stable-Baselines3 zip" in err[0], err


@pytest.mark.parametrize("changed", [["--lr", "0.0005"], ["--gamma", "0.9"], ["--candidates", "12"],
                                     ["--action", "box"], ["--algo", "sac"], ["--task", "pendulum"]])
def test_a_resume_with_other_flags_is_refused_in_one_line(tmp_path, changed, capsys):
    """`train rl --resume` with a flag that differs from the run's config.json (other than the step
    budget and where it runs) is one line naming the flag; nothing is trained or overwritten."""
    from train.cli import main
    base = ["train", "rl", "--task", "maze2d", "--n-envs", "2", "--n-steps", "64", "--batch-size", "32",
            "--eval-problems", "1", "--eval-max-steps", "200", "--out", str(tmp_path / "run"), "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(base + ["--total-steps", "64"]) == 0
    model = (tmp_path / "run" / "model.zip").read_bytes()
    capsys.readouterr()
    argv = list(base)
    if changed[0] in argv:
        argv[argv.index(changed[0]) + 1] = changed[1]
    else:
        argv += changed
    try:
        code = main(argv + ["--total-steps", "128", "--resume"])
    except SystemExit as exit_:         # a flag combination argparse's checks refuse first
        code = exit_.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and changed[0] in err[0], err
    assert (tmp_path / "run" / "model.zip").read_bytes() == model


def snippet() -> str:
    """docs/rl.md's own-agent snippet (the python block that builds a PPO on an RL id)."""
    text = (ROOT / "docs" / "rl.md").read_text()
    return next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "MultiInputPolicy" in b)


def test_users_own_sb3_ppo_from_the_docs_improves():
    """The snippet as written: SB3 PPO, MultiInputPolicy, the documented extractor, 10,000 steps;
    its median nodes on validation problems go down from step 0."""
    out = subprocess.run([sys.executable, "-c", snippet()], cwd=ROOT, capture_output=True, text=True, timeout=900,
                         env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-2000:]
    before, after = map(float, re.search(r"(\d+) before, (\d+) after", out.stdout).groups())
    assert after < before, out.stdout


def test_users_own_torchrl_ppo_from_the_docs_grows_trees():
    """The TorchRL block of docs/rl.md as written, on TorchRL's default (one-hot) action encoding:
    the actor acts in that encoding, so its trees grow (an index read as one-hot picks the target
    every step: trees of a few nodes)."""
    block = next(b for b in re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "rl.md").read_text(), re.S)
                 if "ClipPPOLoss" in b)
    out = subprocess.run([sys.executable, "-c", block], cwd=ROOT, capture_output=True, text=True, timeout=600,
                         env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 0, out.stderr[-2000:]
    nodes = int(re.search(r"largest tree: (\d+) nodes", out.stdout).group(1))
    assert nodes > 20, out.stdout


def test_a_picker_actor_given_the_one_hot_spec_plans_as_with_indices():
    """The same seeds through TorchRL's one-hot encoding (actor given the spec) and the index
    encoding: the same trees, step by step."""
    from torchrl.envs import GymEnv

    from agents.rl.torchrl import make_pick_actor
    spaces = gym.make("GNNMP/Maze2DRRT-RLPick-v0").observation_space
    sizes = []
    for categorical in (False, True):
        torch.manual_seed(0)
        env = GymEnv("GNNMP/Maze2DRRT-RLPick-v0", categorical_action_encoding=categorical)
        env.set_seed(0)
        actor = make_pick_actor(spaces, action_spec=env.action_spec)
        sizes.append(env.rollout(40, actor)["next", "num_nodes"])
    assert torch.equal(sizes[0], sizes[1]) and sizes[0].max() > 10
    with pytest.raises(ValueError, match="Discrete"):
        from torchrl.data import Bounded
        make_pick_actor(spaces, action_spec=Bounded(-1.0, 1.0, shape=(2,)))


@pytest.mark.parametrize("name", ["rl-ppo", "rl-ppo-torchrl"])
def test_shipped_arm_pickers_beat_uniform_on_val_collision_checks(name):
    """The shipped SB3 and TorchRL arm pickers (docs/rl.md: 199.5 and 367.5 median val checks on 50
    problems against uniform's 780.5) need well under uniform's checks on a few val problems, with
    the benchmark's seeding, every problem solved."""
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problems
    torch.set_num_threads(1)
    env = evaluation_env("arm", "val")
    runs = {s: plan_problems(load_sampler(s, task="arm", seed=0), env, range(8), 0) for s in ("uniform", name)}
    env.close()
    assert all(r.success for r in runs[name])
    checks = {s: np.median([r.collision_checks for r in records]) for s, records in runs.items()}
    assert checks[name] < 0.7 * checks["uniform"], checks


@pytest.mark.parametrize("name", ["rl-ppo", "rl-ppo-torchrl"])
def test_shipped_pendulum_pickers_beat_goal_bias_on_val_nodes(name):
    """The shipped SB3 and TorchRL pendulum pickers (docs/rl.md: 47 and 50 median nodes on 200 val
    problems against goal-bias's 626) need far fewer nodes than goal-bias on a few val problems,
    with the benchmark's seeding, every problem solved; each carries the scorer prior it was trained with."""
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problems
    torch.set_num_threads(1)
    picker = load_sampler(name, task="pendulum", seed=0)
    assert picker.candidate_set.prior is not None and picker.policy.head == "shared"
    env = evaluation_env("pendulum", "val")
    runs = {"goal-bias": plan_problems(load_sampler("goal-bias", task="pendulum", seed=0), env, range(8), 0),
            name: plan_problems(picker, env, range(8), 0)}
    env.close()
    assert all(r.success for r in runs[name])
    nodes = {s: np.median([r.nodes_expanded for r in records]) for s, records in runs.items()}
    assert nodes[name] < 0.5 * nodes["goal-bias"], nodes


def test_a_picker_with_proposals_scores_a_set_for_that_many_samples():
    """proposals=1 is the training env's picker (a fresh candidate set every model sample, the
    counters the benchmark records); proposals=k scores one set per k model samples, each of its
    picks drawn from the same categorical, and plans as well."""
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    torch.set_num_threads(1)
    env = evaluation_env("arm", "val")
    one = load_sampler("rl-ppo", task="arm", seed=0)
    assert one.proposals == 1
    base = plan_problem(env, one, 0, 0)
    assert one.forward_calls == base.iterations            # no uniform mix: every iteration a fresh set
    four = load_sampler("rl-ppo", task="arm", seed=0, proposals=4)
    run = plan_problem(env, four, 0, 0)
    env.close()
    assert run.success and four.forward_calls <= (run.iterations + 3) // 4 + 2     # one set per 4 (per tree)
    assert (run.nodes_expanded, run.collision_checks) != (base.nodes_expanded, base.collision_checks)


# ----------------------------------------------------------------------------- the candidate prior
def scorer_prior():
    from agents.checkpoints import shipped_checkpoint
    from agents.tree.prior import ScorerPrior
    return ScorerPrior.from_checkpoint(shipped_checkpoint("gnn", "pendulum"))


def test_candidate_prior_column_is_the_scorers_logit():
    """The prior column against the scorer's numpy head at brute-force nearest nodes (an independent
    path from the compiled one the prior calls); every other column as without a prior."""
    from agents.checkpoints import load_checkpoint, shipped_checkpoint
    from agents.tree.engine import IncrementalTreeScorer
    env, obs, cs = grown_env("pendulum", 80)
    with_prior = CandidateSet(env.action_space.low, env.action_space.high, prior=scorer_prior(),
                              **candidate_settings("pendulum", 12))
    plain = CandidateSet(env.action_space.low, env.action_space.high, **candidate_settings("pendulum", 12))
    cands, feats = with_prior.propose(obs, np.random.default_rng(3))
    cands2, feats2 = plain.propose(obs, np.random.default_rng(3))
    np.testing.assert_array_equal(cands, cands2)
    assert feats.shape == (12, feats2.shape[1] + 1)
    np.testing.assert_array_equal(feats[:, :-1], feats2)
    model, _ = load_checkpoint(shipped_checkpoint("gnn", "pendulum"), expected_kind="tree/gnn-scorer")
    engine = IncrementalTreeScorer(model)
    engine.ingest(obs)
    n = int(obs["num_nodes"][0])
    problem = env.unwrapped.problem
    x = cands.astype(np.float64)
    near = np.array([int(np.argmin(problem.distance(np.asarray(obs["nodes"][:n], np.float64), c))) for c in x])
    np.testing.assert_allclose(feats[:, -1], engine.logits(x, near), rtol=1e-5, atol=1e-5)
    assert np.ptp(feats[:, -1]) > 0.5                      # a real score, not a constant
    env.close()


def test_prior_picker_starts_as_the_prior_and_its_twin_agrees():
    """A PickPolicy with a prior and its other head weights zeroed gives exactly the prior's logits; with
    any weights, the numpy twin the sampler runs matches the torch policy."""
    from agents.checkpoints import shipped_checkpoint
    from agents.nn.encoders import CandidateEncoder
    from agents.rl.pick import PickPolicy
    from agents.rl.sampler import numpy_pick_layers, numpy_pick_logits
    env, obs, _ = grown_env("pendulum", 40)
    cs = CandidateSet(env.action_space.low, env.action_space.high, prior=scorer_prior(),
                      **candidate_settings("pendulum", 8))
    _, feats = cs.propose(obs, np.random.default_rng(0))
    space = make_rl_env("pendulum", candidates=8, candidate_prior=scorer_prior).observation_space
    assert space["candidate_features"].shape == feats.shape
    torch.manual_seed(0)
    enc = CandidateEncoder.from_space(space, prior_checkpoint=str(shipped_checkpoint("gnn", "pendulum")),
                                      hidden=16, embed=8)
    policy = PickPolicy(enc.config()).eval()
    policy.encoder.load_state_dict(enc.state_dict())
    with torch.no_grad():
        policy.logits.weight[:, :-8] = 0
        start = policy({"candidate_features": torch.as_tensor(feats)[None]})[0].numpy()
    np.testing.assert_array_equal(start, feats[:, -1])
    with torch.no_grad():
        policy.logits.weight.normal_()
        expected = policy({"candidate_features": torch.as_tensor(feats)[None]})[0].numpy()
    np.testing.assert_allclose(numpy_pick_logits(numpy_pick_layers(policy), feats), expected, rtol=1e-5, atol=1e-5)
    # the shared head: exactly the prior at the start, then a score per candidate from one set of weights
    shared = PickPolicy(enc.config(), head="shared").eval()
    shared.encoder.load_state_dict(enc.state_dict())
    obs_t = {"candidate_features": torch.as_tensor(feats)[None]}
    with torch.no_grad():
        np.testing.assert_array_equal(shared(obs_t)[0].numpy(), feats[:, -1])
        for p in shared.logits.parameters():
            p.normal_()
        expected = shared(obs_t)[0].numpy()
        # the oracle: each candidate scored by hand from the encoder's embeddings
        per, summary = shared.encoder(obs_t)
        head = shared.logits
        by_hand = [float(head.score(torch.cat([per[0, k], summary[0]]))) + float(head.slot_bias[k])
                   + float(head.prior_scale) * float(feats[k, -1]) for k in range(8)]
    np.testing.assert_allclose(expected, by_hand, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(numpy_pick_logits(numpy_pick_layers(shared), feats), expected, rtol=1e-5, atol=1e-5)
    for bad in ({"hidden": [16]}, {"hidden": [16], "head": "shared"}):
        with pytest.raises(ValueError, match="no hidden layers"):
            PickPolicy(enc.config(), **bad)
    env.close()


@pytest.mark.parametrize("lib,head", [("sb3", "linear"), ("sb3", "shared"), ("torchrl", "shared")])
def test_prior_run_exports_the_prior_it_trained_with(tmp_path, lib, head):
    """A short run with the pendulum's prior (and a vanishing learning rate, so the policy stays the
    untrained one): SB3's re-initialisation of its extractor does not reach the exported sampler's
    prior (the same logits as the env's), and the pick probabilities are the prior's softmax (to
    within SB3's small initial weights for its slot-wise head; exactly for the shared head)."""
    from agents.rl.sampler import sampler_from_checkpoint
    from train.cli import main
    out = tmp_path / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["train", "rl", "--task", "pendulum", "--lib", lib, "--pick-head", head, "--prior-temperature",
                     "0.7", "--total-steps", "64", "--n-envs", "2", "--n-steps", "32", "--batch-size", "32", "--lr",
                     "1e-12", "--eval-problems", "1", "--eval-max-steps", "100", "--out", str(out),
                     "--no-progress"]) == 0
    env, obs, _ = grown_env("pendulum", 50)
    low, high = env.action_space.low, env.action_space.high
    sampler = sampler_from_checkpoint(out / "policy.pt", low, high, seed=0)
    prior = scorer_prior()
    prior.temperature = 0.7
    reference = CandidateSet(low, high, prior=prior, **sampler.candidate_set.config())
    a = sampler.candidate_set.propose(obs, np.random.default_rng(5))[1]
    b = reference.propose(obs, np.random.default_rng(5))[1]
    np.testing.assert_allclose(a[:, -1], b[:, -1], rtol=1e-6, atol=1e-6)
    logits = sampler.logits(obs, b).astype(np.float64)
    p, q = np.exp(logits - logits.max()), np.exp(b[:, -1] - b[:, -1].max())
    np.testing.assert_allclose(p / p.sum(), q / q.sum(), atol=0.02 if head == "linear" else 1e-6)
    env.close()


def test_prior_flags_are_refused_where_they_cannot_work(capsys):
    from train.rl.cli import parse
    for argv, message in ((["--task", "maze2d", "--prior", "gnn"], "tree/gnn-scorer"),
                          (["--task", "pendulum", "--pi-arch", "32"], "--pi-arch none"),
                          (["--task", "pendulum", "--action", "box", "--prior", "gnn"], "picker"),
                          (["--task", "pendulum", "--prior", "nosuch"], "no such file")):
        with pytest.raises(SystemExit):
            parse(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) <= 2 and message in err[-1], (argv, err)     # usage line + one line of error
    args = parse(["--task", "pendulum", "--action", "box", "--hyperparams", "none"])
    assert args.prior is None and args.n_envs == 4 and args.hyperparams is None
    args = parse(["--task", "pendulum", "--action", "box"])      # the file's picker keys do not apply
    assert args.prior is None and args.candidates == 8 and args.n_envs == 16
    args = parse(["--task", "pendulum"])                # the task's YAML file: the prior picker
    assert args.prior.name == "gnn_pendulum.pt" and args.candidates == 20 and args.pi_arch == []


def test_gnn_pick_scores_the_pickers_candidates_by_its_prior_alone():
    """`gnn-pick` (the prior-only row): the shipped pendulum picker's candidate sets, scored by the
    supervised scorer prior it carries (the features' last column), not by the policy. The maze2d
    picker was trained without a prior: its `gnn-pick` scores the same candidates by the shipped
    supervised `gnn`'s mixture density; a picker without a prior and no prior given is refused."""
    from agents.registry import load_sampler
    env, obs, _ = grown_env("pendulum", 40)
    prior_only = load_sampler("gnn-pick", task="pendulum", seed=3)
    policy = load_sampler("rl-ppo", task="pendulum", seed=3)
    cands, feats = prior_only.candidate_set.propose(obs, np.random.default_rng(0))
    _, same = policy.candidate_set.propose(obs, np.random.default_rng(0))
    assert np.array_equal(feats, same)                          # the same candidates and features
    assert np.array_equal(prior_only.logits(obs, feats), feats[:, -1])
    assert not np.allclose(policy.logits(obs, feats), feats[:, -1])
    env.close()
    from agents.checkpoints import shipped_checkpoint
    from agents.tree.prior import MixturePrior
    from agents.rl.sampler import sampler_from_checkpoint
    env, obs, _ = grown_env("maze2d", 40)
    prior_only = load_sampler("gnn-pick", task="maze2d", seed=3)
    policy = load_sampler("rl-ppo", task="maze2d", seed=3)
    assert isinstance(prior_only.candidate_set.prior, MixturePrior) and policy.candidate_set.prior is None
    cands, feats = prior_only.candidate_set.propose(obs, np.random.default_rng(0))
    same, plain = policy.candidate_set.propose(obs, np.random.default_rng(0))
    assert np.array_equal(cands, same) and np.array_equal(feats[:, :-1], plain)   # + the prior's column
    expected = MixturePrior.__call__(prior_only.candidate_set.prior, obs, cands.astype(np.float64), 0)
    np.testing.assert_allclose(prior_only.logits(obs, feats), expected, rtol=1e-5, atol=1e-4)   # float32 column
    low, high = env.action_space.low, env.action_space.high
    with pytest.raises(ValueError, match="without a candidate prior"):
        sampler_from_checkpoint(shipped_checkpoint("rl-ppo", "maze2d"), low, high, task="maze2d", prior_only=True)
    env.close()


def test_resume_never_unpickles_the_run_directorys_model(tmp_path):
    """A crafted model.zip (a cloudpickle payload in its policy keywords, as SB3's PPO.load would
    run) is resumed weights-only: the payload never runs, training continues to --total-steps."""
    import json as _json
    import zipfile

    from tests.helpers import armed
    from train.cli import main
    marker = tmp_path / "payload-ran"
    base = ["train", "rl", "--task", "maze2d", "--n-envs", "2", "--n-steps", "64", "--batch-size", "32",
            "--eval-problems", "1", "--eval-max-steps", "200", "--out", str(tmp_path / "run"), "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(base + ["--total-steps", "64"]) == 0
    path = tmp_path / "run" / "model.zip"
    armed(path, marker)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(base + ["--total-steps", "128", "--resume"]) == 0
    assert not marker.exists()
    from stable_baselines3.common.save_util import load_from_zip_file
    assert _json.loads(zipfile.ZipFile(path).read("data"))["num_timesteps"] == 128
    assert load_from_zip_file(path, load_data=False)[1]["policy"]
