"""RL samplers: the tree view, buffer memory, short training runs of SB3 PPO/SAC and
TorchRL PPO, policy checkpoints as reproducible samplers, the warm start, the CLI."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch

import gnn_mp_envs  # noqa: F401
from gnn_mp_envs.envs.wrappers import TreeViewWrapper, make_rl_env, scale_action, tree_view, view_rows

torch.set_num_threads(1)


def tree_obs(parent, n_real=None, d=2):
    """A padded observation of a hand-made tree: node i's state is (i, 10 i)."""
    parent = np.asarray(parent, np.int64)
    N = len(parent)
    n = N if n_real is None else n_real
    nodes = np.zeros((N, d), np.float32)
    nodes[:n, 0] = np.arange(n)
    nodes[:n, 1] = 10 * np.arange(n)
    feats = np.zeros((N, 2 * d + 1), np.float32)
    feats[:n, 0] = np.arange(n)
    mask = np.zeros(N, np.int8)
    mask[:n] = 1
    par = np.full(N, -1, np.int64)
    par[:n] = parent[:n]
    return {"nodes": nodes, "node_features": feats, "parent": par, "mask": mask,
            "num_nodes": np.array([n], np.int64), "start": np.zeros(d, np.float32),
            "goal": np.ones(d, np.float32), "active_tree": np.array([1], np.int64),
            "obstacles": np.zeros((1, 1), np.float32)}


# ----------------------------------------------------------------------------- the view
def test_view_of_a_known_tree():
    #         0 (root)
    #        / \
    #       1   3
    #       |   |
    #       2   5
    #       |
    #       4
    obs = tree_obs([-1, 0, 1, 0, 2, 3, -1, -1], n_real=6)
    view = tree_view(obs, 4)
    # the root, then the 3 most recent nodes (3, 4, 5)
    assert view["nodes"][:, 0].tolist() == [0, 3, 4, 5]
    # 3's parent 0 -> row 0; 4's parent 2 is not in the view -> -1; 5's parent 3 -> row 1
    assert view["parent"].tolist() == [-1, 0, -1, 1]
    assert view["num_nodes"].tolist() == [4] and view["mask"].tolist() == [1, 1, 1, 1]
    assert view["node_features"][:, 0].tolist() == [0, 3, 4, 5]
    assert view["active_tree"].tolist() == [1] and view["goal"].tolist() == [1, 1]
    assert {k: v.dtype for k, v in view.items()} == {k: v.dtype for k, v in obs.items()}
    # a small tree is copied whole and padded
    small = tree_view(tree_obs([-1, 0, 1], n_real=3), 5)
    assert small["parent"].tolist() == [-1, 0, 1, -1, -1] and small["mask"].tolist() == [1, 1, 1, 0, 0]
    assert small["nodes"][3:].sum() == 0


def test_view_keeps_both_birrt_roots():
    # BiRRT: rows 0 and 1 are the roots of the start and goal trees
    parent = [-1, -1, 0, 1, 2, 3, 4, 5, 6, 7]
    assert view_rows(np.array(parent), 10, 4).tolist() == [0, 1, 8, 9]
    # a root among the recent rows frees a row for one more recent node
    assert view_rows(np.array([-1, 0, 1, 2, -1, 4]), 6, 3).tolist() == [0, 4, 5]
    assert view_rows(np.array([-1, 0, 1, 2, 3, -1]), 6, 3).tolist() == [0, 4, 5]
    view = tree_view(tree_obs(parent), 4)
    assert view["parent"].tolist() == [-1, -1, -1, -1]   # 8 <- 6, 9 <- 7: both cut


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
def test_view_matches_the_env_tree(task):
    env = make_rl_env(task, view_nodes=16, copy_observations=True)
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(60):      # a candidate index (a float in [-1, 1] was read as candidate 0 before issue 51)
        obs, *_ = env.step(int(rng.integers(env.action_space.n)))
    full = env.unwrapped._obs.as_dict()
    n = int(full["num_nodes"][0])
    rows = view_rows(full["parent"], n, 16)
    m = int(obs["num_nodes"][0])
    assert m == min(n, 16) and obs["mask"].sum() == m
    np.testing.assert_array_equal(obs["nodes"][:m], full["nodes"][rows])
    for i, p in enumerate(obs["parent"][:m]):
        if p >= 0:
            assert full["parent"][rows[i]] == rows[p]
        else:
            assert full["parent"][rows[i]] not in rows or full["parent"][rows[i]] < 0
    assert env.observation_space.contains(obs)


def test_view_wrapper_passes_the_checkers():
    from gymnasium.utils.env_checker import check_env as gym_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env
    from torchrl.envs import GymWrapper, check_env_specs
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for task in ("maze2d", "pendulum"):
            gym_check_env(make_rl_env(task, view_nodes=8), skip_render_check=True)
            sb3_check_env(make_rl_env(task, view_nodes=8), warn=False)
            check_env_specs(GymWrapper(make_rl_env(task, view_nodes=8)), seed=0)
        wrapped = TreeViewWrapper(gym.make("GNNMP/Maze2DBiRRT-v0", max_nodes=300), 8)
        gym_check_env(wrapped, skip_render_check=True)


def test_make_rl_env_scales_actions():
    env = make_rl_env("pendulum", view_nodes=8, action="box")
    box = env.unwrapped.action_space
    assert np.allclose(env.action_space.low, -1) and np.allclose(env.action_space.high, 1)
    np.testing.assert_allclose(scale_action(np.array([-1, 1]), box.low, box.high), [box.low[0], box.high[1]])
    np.testing.assert_allclose(scale_action(np.zeros(2), box.low, box.high), (box.low + box.high) / 2, atol=1e-6)
    with pytest.raises(ValueError, match="planner"):
        make_rl_env("pendulum", planner="birrt")
    with pytest.raises(ValueError, match="view_nodes"):
        TreeViewWrapper(gym.make("GNNMP/PendulumRRT-v0", max_nodes=50), 1)


# ----------------------------------------------------------------------------- memory
def test_buffer_formula_matches_sb3_buffers():
    from stable_baselines3.common.buffers import DictReplayBuffer, DictRolloutBuffer

    from train.rl.memory import sb3_buffer_bytes, sb3_buffer_nbytes
    for k in (None, 32):
        env = make_rl_env("maze2d", view_nodes=k, max_nodes=200, action="box")
        space, act = env.observation_space, env.action_space
        rollout = DictRolloutBuffer(64, space, act, n_envs=2)
        replay = DictReplayBuffer(100, space, act, n_envs=1)
        assert sb3_buffer_nbytes(rollout) == sb3_buffer_bytes(space, 2, 64, 2, "rollout")
        assert sb3_buffer_nbytes(replay) == sb3_buffer_bytes(space, 2, 100, 1, "replay")
    # the figures of docs/rl.md: SAC's 100k-transition buffer and a 2,048-step PPO rollout on maze2d
    full, view = (make_rl_env("maze2d", view_nodes=k, action="box").observation_space for k in (None, 64))
    assert sb3_buffer_bytes(full, 2, 100_000, 1, "replay") > 30 * 2**30     # ~34 GiB, full padding
    assert sb3_buffer_bytes(view, 2, 100_000, 1, "replay") < 900 * 2**20    # 850 MiB, 64-row view
    assert sb3_buffer_bytes(view, 2, 2048, 1, "rollout") < 20 * 2**20


# ----------------------------------------------------------------------------- training
def tiny_args(tmp_path, lib, algo, task, **kw):
    from train.rl.args import RLArgs
    defaults = dict(lib=lib, algo=algo, task=task, total_steps=256, n_envs=2, n_steps=64, batch_size=32,
                    n_epochs=1, view_nodes=16, hidden_channels=8, num_layers=1, out_channels=16, net_arch=[16],
                    buffer_size=500, learning_starts=64, eval_every=10_000, eval_problems=1, eval_max_steps=100,
                    progress=False, out=tmp_path / f"{lib}-{algo}-{task}",
                    action="box" if algo == "sac" or "init_from" in kw or "encoder" in kw else "pick")
    defaults.update(kw)
    return RLArgs(**defaults)


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
@pytest.mark.parametrize("lib,algo", [("sb3", "ppo"), ("sb3", "sac"), ("torchrl", "ppo")])
def test_short_training_runs(tmp_path, lib, algo, task):
    from train.rl.cli import main  # noqa: F401  (the CLI module imports)
    from train.rl.sb3 import train as train_sb3
    from train.rl.torchrl import train as train_torchrl
    args = tiny_args(tmp_path, lib, algo, task)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = (train_sb3 if lib == "sb3" else train_torchrl)(args)
    assert result.steps >= 256
    assert torch.get_num_threads() == args.threads  # TorchRL's env close raises it; training puts it back
    assert 0 < result.buffer_bytes < 8 * 2**20     # bounded: the full padding would be 100-1000x more
    run = result.run_dir
    assert run == args.out
    for name in ("config.json", "policy.pt", "best.pt", "policy.json", "evaluations.json", "learning_curve.png"):
        assert (run / name).exists(), name
    assert json.loads((run / "config.json").read_text())["algo"] == algo
    rows = json.loads((run / "evaluations.json").read_text())
    assert rows[0]["steps"] == 0 and rows[-1]["steps"] == result.steps
    assert list((run / "tb").rglob("events.out.tfevents.*"))
    # the policy is a sampler of the benchmark
    from agents.samplers import load_sampler
    env = gym.make(f"GNNMP/{'Maze2D' if task == 'maze2d' else 'Pendulum'}RRT-v0", copy_observations=False)
    sampler = load_sampler(args.sampler_name, task=task, seed=0,
                           checkpoint=result.best)
    obs, _ = env.reset(seed=0)
    assert env.action_space.contains(sampler.act(obs))


def test_saved_policy_reloads_and_reproduces_actions(tmp_path):
    """Same seed -> same actions, for every policy kind, after a save/load round trip."""
    from agents.rl.policies import SB3PPOPolicy, SB3SACPolicy, TorchRLPPOPolicy, encoder_config
    from agents.nn.encoders import TreeEncoder
    from agents.samplers import load_sampler
    from agents.rl.sampler import RL_SAMPLERS, save_policy
    env = gym.make("GNNMP/Maze2DRRT-v0", copy_observations=False)
    low, high = env.action_space.low, env.action_space.high
    view_space = make_rl_env("maze2d", view_nodes=16).observation_space
    enc = encoder_config(TreeEncoder.from_space(view_space, hidden_channels=8, num_layers=1, out_channels=16))
    obs, _ = env.reset(seed=0)
    for _ in range(40):
        obs, *_ = env.step(env.action_space.sample())
    policies = {"rl/sb3-ppo": (SB3PPOPolicy, {"hidden": [16]}), "rl/sb3-sac": (SB3SACPolicy, {"hidden": [16]}),
                "rl/torchrl-ppo": (TorchRLPPOPolicy, {"head_hidden": 16})}
    for name, kinds in RL_SAMPLERS.items():
        kind = kinds[0]
        cls, extra = policies[kind]
        torch.manual_seed(0)
        args = {"encoder": enc, "action_dim": 2, **extra}
        path = save_policy(tmp_path / f"{name}.pt", cls(**args), kind, args, task="maze2d", view_nodes=16,
                           low=low, high=high, uniform_mix=0.25)
        a = load_sampler(name, task="maze2d", seed=7, checkpoint=path)
        b = load_sampler(name, task="maze2d", seed=7, checkpoint=path)
        assert a.uniform_mix == 0.25 and a.view_nodes == 16
        first = [a.act(obs) for _ in range(20)]
        assert np.array_equal(first, [b.act(obs) for _ in range(20)])
        a.reset(7)
        assert np.array_equal(first, [a.act(obs) for _ in range(20)])
        a.reset(8)
        assert not np.array_equal(first, [a.act(obs) for _ in range(20)])
        assert all(np.all(x >= low) and np.all(x <= high) for x in first)
        # batched TorchRL use: full observations in, actions out
        from tensordict import TensorDict
        td = TensorDict({k: torch.as_tensor(np.stack([v] * 3)) for k, v in obs.items()}, batch_size=[3])
        out = a.as_module()(td)
        assert out["action"].shape == (3, 2) and torch.isfinite(out["action"]).all()
        with pytest.raises(ValueError, match="task"):
            load_sampler(name, task="pendulum", checkpoint=path)
    with pytest.raises(FileNotFoundError):
        load_sampler("rl-sac", task="arm", seed=0)


def test_compiled_target_map_is_the_numpy_expressions_bit_for_bit():
    """The RL sampler's compiled state map (clipped policy, target frame) against the numpy
    expressions it replaces, bit for bit: random float32 draws well inside, at and beyond the action
    box, targets at the bounds, states that wrap by one period or land on its edges, and signed zeros."""
    from agents.rl.sampler import _ACTION_HIGH32, _ACTION_LOW32, _clipped_target_map
    from gnn_mp_envs.envs.candidates import wrap_into_box
    rng = np.random.default_rng(0)
    low = np.array([-np.pi, -8.0], np.float32)
    high = np.array([np.pi, 8.0], np.float32)
    span = high - low
    for periodic in (np.array([True, False]), np.array([False, False]), np.array([True, True])):
        for trial in range(3000):
            loc = rng.normal(0.0, [0.3, 1.5][trial % 2], 2).astype(np.float32)
            scale = np.abs(rng.normal(0.0, 0.5, 2)).astype(np.float32)
            noise = rng.normal(0.0, 1.0, 2).astype(np.float32)
            target = rng.uniform(low, high).astype(np.float32)
            if trial % 10 == 0:
                target = np.where(rng.random(2) < 0.5, low, high).astype(np.float32)
            if trial % 17 == 0:
                loc, scale = np.array([-0.0, 0.5], np.float32), np.array([0.0, 0.0], np.float32)
            z = loc + scale * noise
            u = np.minimum(np.maximum(z, -1.0), 1.0)
            x = target + u * span
            x = wrap_into_box(x, low, span, periodic)
            expected = np.minimum(np.maximum(x, low), high)
            got = _clipped_target_map(loc, scale, noise, target, span, low, high, periodic, _ACTION_LOW32,
                                      _ACTION_HIGH32)
            assert got.dtype == expected.dtype == np.float32
            assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected)), trial


def box_policy_sampler(task: str, seed: int = 0, **settings):
    """A continuous (box) SB3 PPO policy sampler of ``task`` in the target frame (the shipped ``rl-ppo``
    are pickers): a random policy of that kind (a wide Gaussian, so the pendulum's states wrap around
    the angle often), saved and loaded by name."""
    import tempfile

    from agents.nn.encoders import TreeEncoder
    from agents.registry import load_sampler
    from agents.rl.policies import SB3PPOPolicy, encoder_config
    from agents.rl.sampler import save_policy
    from gnn_mp_envs.registration import task_spec
    spec = task_spec(task)
    low, high = spec.state_bounds()
    enc = encoder_config(TreeEncoder.from_space(make_rl_env(task, view_nodes=64, action="box").observation_space,
                                                hidden_channels=8, num_layers=1, out_channels=16))
    torch.manual_seed(0)
    args = {"encoder": enc, "action_dim": 2, "hidden": [16]}
    policy = SB3PPOPolicy(**args)
    with torch.no_grad():
        policy.log_std.fill_(np.log(0.3))
    path = save_policy(Path(tempfile.mkdtemp()) / "box.pt", policy, "rl/sb3-ppo", args, task=task, view_nodes=64,
                       low=low, high=high, uniform_mix=0.5, action_frame="target",
                       periodic=spec.periodic_mask(2).tolist())
    return load_sampler("rl-ppo", task, seed=seed, checkpoint=path, **settings)


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
def test_the_box_policy_acts_alike_with_and_without_the_compiled_map(task):
    """A box ``rl-ppo`` sampler plans a validation problem with the same
    actions, bit for bit, whether its state map is the compiled call or the numpy expressions."""
    from gnn_mp_envs.evaluation import evaluation_env
    runs = []
    for compiled in (True, False):
        sampler = box_policy_sampler(task)
        assert sampler._compiled_map
        sampler._compiled_map = compiled
        sampler.reset(5)
        env = evaluation_env(task, "val")
        obs, _ = env.reset(seed=5, options={"index": 3})
        actions = []
        for _ in range(300):
            action = sampler.act(obs)
            actions.append(action.copy())
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        runs.append(np.array(actions))
    assert runs[0].dtype == np.float32 and len(runs[0]) > 20
    assert np.array_equal(runs[0], runs[1])


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
def test_numpy_twin_of_the_tree_policy_matches_torch(task):
    """The RL sampler's numpy forward (numpy_tree_params) against the torch policy on views of a grown
    tree, a hand-made tree with an orphan row and a one-node tree; unsupported policies stay in torch."""
    from agents.nn.encoders import TreeEncoder
    from agents.rl.policies import SB3PPOPolicy, SB3SACPolicy, encoder_config
    from agents.rl.sampler import numpy_tree_params, numpy_tree_policy
    view_space = make_rl_env(task, view_nodes=16).observation_space
    env = gym.make({"maze2d": "GNNMP/Maze2DRRT-v0", "pendulum": "GNNMP/PendulumRRT-v0"}[task])
    obs, _ = env.reset(seed=1)
    views = [tree_view(obs, 16)]
    for _ in range(60):
        obs, *_ = env.step(env.action_space.sample())
        views.append(tree_view(obs, 16))
    hand = tree_obs([-1, 0, 0, 1, 12, -1, 3, 2, 7, 0, 0, 0, 0, 0, 0, 0], n_real=9)   # row 4: parent not a real row
    views.append({k: v for k, v in hand.items() if k in views[0]})
    for act, hidden in (("relu", [16, 8]), ("tanh", [])):
        torch.manual_seed(0)
        enc = encoder_config(TreeEncoder.from_space(view_space, hidden_channels=8, num_layers=2, out_channels=12,
                                                    act=act))
        policy = SB3PPOPolicy(enc, 2, hidden=hidden).eval()
        twin = numpy_tree_policy(policy)
        assert twin is not None
        for view in views:
            with torch.inference_mode():
                loc, scale = policy({k: torch.as_tensor(v) for k, v in view.items()})
            mine = numpy_tree_params(twin, view)
            np.testing.assert_allclose(mine[0], loc.numpy(), rtol=1e-5, atol=1e-6)
            np.testing.assert_array_equal(mine[1], scale.numpy())
            assert mine[0].dtype == np.float32 and mine[0].shape == (2,)
    knn = encoder_config(TreeEncoder.from_space(view_space, hidden_channels=8, num_layers=1, out_channels=8, knn=3))
    assert numpy_tree_policy(SB3PPOPolicy(knn, 2, hidden=[8])) is None            # k-NN edges: torch
    assert numpy_tree_policy(SB3SACPolicy(enc, 2, hidden=[8])) is None            # another actor: torch
    env.close()


def test_warm_start_copies_the_encoder(tmp_path):
    from agents.checkpoints import save_checkpoint
    from agents.nn.encoders import TreeEncoder
    from agents.rl.policies import SB3PPOPolicy, encoder_config, warm_start_encoder
    space = make_rl_env("maze2d", view_nodes=16).observation_space
    source = SB3PPOPolicy(encoder_config(TreeEncoder.from_space(space, hidden_channels=8, num_layers=1,
                                                                out_channels=16)), 2, hidden=[16])
    path = save_checkpoint(tmp_path / "src.pt", source, "rl/sb3-ppo",
                           {"encoder": encoder_config(source.encoder), "action_dim": 2, "hidden": [16]})
    targets = [TreeEncoder.from_space(space, hidden_channels=8, num_layers=1, out_channels=16) for _ in range(2)]
    assert warm_start_encoder(path, *targets) == "rl/sb3-ppo:encoder."
    for t in targets:
        for k, v in source.encoder.state_dict().items():
            assert torch.equal(t.state_dict()[k], v)
    with pytest.raises(ValueError, match="TreeEncoder"):
        warm_start_encoder(path, TreeEncoder.from_space(space, hidden_channels=12, num_layers=1, out_channels=16))


def test_warm_start_flag_in_training(tmp_path):
    from agents.checkpoints import read_checkpoint
    from train.rl.sb3 import train
    first = train(tiny_args(tmp_path, "sb3", "ppo", "maze2d", total_steps=128, out=tmp_path / "a", action="box"))
    src = {k: v for k, v in read_checkpoint(first.best)["state_dict"].items() if k.startswith("encoder.")}
    args = tiny_args(tmp_path, "sb3", "ppo", "maze2d", total_steps=128, out=tmp_path / "b", init_from=first.best,
                     lr=1e-12)
    train(args)
    after = read_checkpoint(tmp_path / "b" / "policy.pt")["state_dict"]
    for k, v in src.items():
        assert torch.allclose(after[k], v, atol=1e-6), k


def test_cli_train_rl_flags(tmp_path, capsys):
    from train.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["train", "rl", "--lib", "torchrl", "--algo", "sac", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "not available" in capsys.readouterr().err


def test_arm_view_and_sampler(tmp_path):
    """BiRRT on the arm: both roots stay in the view, and a policy acts for the active tree."""
    from agents.nn.encoders import TreeEncoder
    from agents.rl.policies import SB3PPOPolicy, encoder_config
    from agents.rl.sampler import sampler_from_checkpoint, save_policy
    env = make_rl_env("arm", view_nodes=8, max_nodes=300)
    obs, _ = env.reset(seed=0)
    assert obs["parent"][:2].tolist() == [-1, -1] and obs["node_features"].shape == (8, 13)
    for _ in range(20):
        obs, _, term, trunc, info = env.step(env.action_space.sample())
        if term or trunc:
            break
    assert env.observation_space.contains(obs)
    enc = encoder_config(TreeEncoder.from_space(env.observation_space, hidden_channels=8, num_layers=1,
                                                out_channels=16))
    box = env.unwrapped.action_space
    args = {"encoder": enc, "action_dim": 6, "hidden": [16]}
    path = save_policy(tmp_path / "arm.pt", SB3PPOPolicy(**args), "rl/sb3-ppo", args, task="arm", view_nodes=8,
                       low=box.low, high=box.high)
    sampler = sampler_from_checkpoint(path, box.low, box.high, seed=0, task="arm")
    full = env.unwrapped._obs.as_dict()
    action = sampler.act(full)
    assert action.shape == (6,) and box.contains(action)
    env.close()


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
def test_sampler_maps_actions_as_the_training_env(task):
    """TargetRelativeAction (training) and the RL sampler (benchmark) turn a policy action into the
    same state: one map (policy_action_to_state), wrapped and clipped alike."""
    from agents.rl.sampler import RLSampler
    from agents.rl.policies import SB3PPOPolicy, encoder_config
    from agents.nn.encoders import TreeEncoder
    from agents.samplers import active_target
    from gnn_mp_envs.envs.wrappers import TargetRelativeAction, policy_action_to_state
    from gnn_mp_envs.registration import task_spec
    env = make_rl_env(task, view_nodes=8, action="box", action_frame="target")
    env.reset(seed=3)
    box = env.unwrapped.action_space
    periodic = task_spec(task).periodic_mask(2)
    enc = encoder_config(TreeEncoder.from_space(env.observation_space, hidden_channels=8, num_layers=1,
                                                out_channels=8))
    sampler = RLSampler(box.low, box.high, 0, policy=SB3PPOPolicy(enc, 2, hidden=[8]), view_nodes=8,
                        action_frame="target", periodic=periodic)
    full = env.unwrapped._obs.as_dict()
    wrapper = env
    while not isinstance(wrapper, TargetRelativeAction):
        wrapper = wrapper.env
    assert np.allclose(wrapper.action(np.zeros(2)), env.unwrapped.problem.goal, atol=1e-6)   # 0 = the goal
    for u in np.random.default_rng(0).uniform(-1, 1, (100, 2)).astype(np.float32):
        mine = sampler.finish(policy_action_to_state(u, "target", sampler.low, sampler.high, active_target(full)))
        np.testing.assert_allclose(wrapper.action(u), mine, atol=1e-5)


def test_training_wrappers():
    from gnn_mp_envs.envs.wrappers import ProgressReward, UniformMixAction
    # uniform mix: reproducible under reset(seed), about the requested fraction replaced
    env = UniformMixAction(gym.make("GNNMP/Maze2DRRT-v0", max_nodes=500, copy_observations=False), 0.5)
    env.reset(seed=0)
    a = np.array([0.5, 0.5], np.float32)
    first = [env.action(a) for _ in range(200)]
    env.reset(seed=0)
    assert np.array_equal(first, [env.action(a) for _ in range(200)])
    assert 60 < sum(np.array_equal(x, a) for x in first) < 140
    # progress shaping: gamma * phi' - phi with phi = -(closest distance to the goal) / |start - goal|
    base = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=500, copy_observations=False, step_penalty=0.0)
    shaped = ProgressReward(base, 1.0, gamma=1.0)
    shaped.reset(seed=0)
    problem = base.unwrapped.problem
    scale = float(problem.distance(problem.start[None], problem.goal)[0])
    total = 0.0
    for _ in range(50):
        _, r, term, *_ = shaped.step(np.asarray(problem.goal, np.float32))   # pull toward the goal
        total += r
        if term:
            break
    tree = base.unwrapped.planner.tree
    closest = float(problem.distance(tree.states[:len(tree)], problem.goal).min())
    expected = (0.0 if term else -closest / scale) + 1.0 + (base.unwrapped.success_reward if term else 0.0)
    assert total == pytest.approx(expected, abs=1e-6)


def _docs_rl():
    from pathlib import Path
    return (Path(__file__).resolve().parents[1] / "docs" / "rl.md").read_text()


def test_docs_tiny_command_runs(tmp_path):
    """The smallest training command of docs/rl.md, as written (output redirected to tmp_path)."""
    import shlex

    from train.cli import main
    line = next(ln for ln in _docs_rl().splitlines() if ln.startswith("gnn-mp train rl") and "runs/tiny" in ln)
    argv = shlex.split(line)[1:]
    argv[argv.index("--out") + 1] = str(tmp_path / "tiny")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(argv + ["--no-progress"]) == 0
    assert (tmp_path / "tiny" / "best.pt").exists()


def test_docs_python_block_runs():
    """The python blocks of docs/rl.md (they load the shipped maze2d policy)."""
    import re
    import subprocess
    import sys
    from pathlib import Path
    blocks = [b for b in re.findall(r"```python\n(.*?)```", _docs_rl(), re.S)
              if "MultiInputPolicy" not in b and "ClipPPOLoss" not in b]   # own-agent snippets: test_rl_pick.py
    assert blocks
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", "\n".join(blocks)], cwd=root, capture_output=True, text=True,
                         timeout=300, env={**__import__("os").environ, "PYTHONPATH": str(root)})
    assert out.returncode == 0, out.stderr[-2000:]


@pytest.mark.parametrize("lib", ["sb3", "torchrl"])
def test_warm_start_from_the_supervised_gnn_sampler(tmp_path, lib):
    """--encoder tree-gnn builds the GNN sampler's own backbone (one module), and --init-from
    the shipped gnn checkpoint copies its weights into the policy's encoder."""
    from agents.checkpoints import SHIPPED_DIR, read_checkpoint
    from train.rl.sb3 import train as train_sb3
    from train.rl.torchrl import train as train_torchrl
    shipped = SHIPPED_DIR / "gnn_maze2d.pt"
    args = tiny_args(tmp_path, lib, "ppo", "maze2d", total_steps=128, encoder="tree-gnn", init_from=shipped,
                     lr=1e-12)
    (train_sb3 if lib == "sb3" else train_torchrl)(args)
    gnn = read_checkpoint(shipped)["state_dict"]
    policy = read_checkpoint(args.out / "policy.pt")
    assert policy["ctor_args"]["encoder"]["class"] == "tree-gnn"
    state = policy["state_dict"]
    for key, value in gnn.items():
        assert torch.allclose(state[f"encoder.gnn.{key}"], value, atol=1e-5), key


@pytest.mark.parametrize("extra, fragment", [
    (["--planner", "nope"], "nope"),
    (["--max-nodes", "1"], "--max-nodes"),
    (["--n-steps", "1", "--n-envs", "1"], "--n-steps"),
    (["--net-arch=-5"], "--net-arch"),
    (["--net-arch", "0"], "--net-arch"),
    (["--view-nodes", "100000000"], "--view-nodes"),
    (["--algo", "sac", "--action", "box", "--buffer-size", "1000000000"], "--buffer-size"),
    (["--gamma", "1.5"], "--gamma"),
    (["--gae-lambda", "7"], "--gae-lambda"),
    (["--clip-range", "3"], "--clip-range"),
    (["--reward-scale", "1e300"], "--reward-scale"),
    (["--local-scale", "1e9"], "--local-scale"),
    (["--target-scale", "1e9"], "--target-scale"),
    (["--seed", str(2**64)], "--seed"),
    (["--action", "box", "--init-from", "{dir}"], "no such file"),
    (["--action", "box", "--init-from", "{truncated}"], "truncated.pt"),
    (["--action", "box", "--init-from", "{crafted}"], "crafted.pt"),
    (["--action", "box", "--init-from", "gnm"], "shipped: cvae, gnn, gnn-cvae, rl-ppo"),
])
def test_train_rl_refuses_bad_values_before_the_run_in_one_line(extra, fragment, tmp_path, capsys):
    """Values that cannot train end in one line and rc 2 before any env is built."""
    from train.cli import main
    shipped = Path(__file__).resolve().parents[1] / "agents" / "checkpoints" / "rl-ppo_maze2d.pt"
    (tmp_path / "truncated.pt").write_bytes(shipped.read_bytes()[:1000])
    (tmp_path / "crafted.pt").write_bytes(b"PK\x03\x04 not a checkpoint")
    files = {"{dir}": str(tmp_path), "{truncated}": str(tmp_path / "truncated.pt"),
             "{crafted}": str(tmp_path / "crafted.pt")}
    extra = [files.get(a, a) for a in extra]
    with pytest.raises(SystemExit) as exc:
        main(["train", "rl", "--out", str(tmp_path / "run"), *extra])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert not (tmp_path / "run").exists()


def test_train_rl_init_from_takes_a_shipped_sampler_name(tmp_path, monkeypatch):
    """`--init-from gnn` is the task's shipped gnn weights from any directory (docs/rl.md used a path
    into the checkout, which failed elsewhere)."""
    from agents.checkpoints import shipped_checkpoint
    from train.rl.cli import parse
    monkeypatch.chdir(tmp_path)
    args = parse(["--action", "box", "--encoder", "tree-gnn", "--init-from", "gnn", "--task", "pendulum"])
    assert args.init_from == shipped_checkpoint("gnn", "pendulum") and args.init_from.is_file()


def test_train_rl_init_from_weights_of_another_size_is_one_line(tmp_path, capsys):
    """A checkpoint without a backbone of the run's size: found when the model exists, still one line, rc 2."""
    from train.cli import main
    gnn = Path(__file__).resolve().parents[1] / "agents" / "checkpoints" / "gnn_maze2d.pt"
    code = main(["train", "rl", "--action", "box", "--init-from", str(gnn), "--total-steps", "64",
                 "--n-envs", "1", "--n-steps", "32", "--batch-size", "32", "--out", str(tmp_path / "run"),
                 "--no-progress"])
    assert code == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "error" in line]
    assert len(err) == 1 and "--init-from" in err[0], err


@pytest.mark.parametrize("kwargs, fragment", [
    ({"view_nodes": 2.5}, "view_nodes"), ({"view_nodes": 10**8}, "view_nodes"), ({"view_nodes": 1}, "view_nodes"),
    ({"uniform_mix": -0.1}, "uniform_mix"), ({"uniform_mix": float("nan")}, "uniform_mix"),
    ({"reward_scale": float("nan")}, "reward_scale"), ({"reward_scale": 0.0}, "reward_scale"),
])
def test_make_rl_env_refuses_values_it_would_silently_bend(kwargs, fragment):
    """2.5 rows, a NaN mixing rate or reward scale: refused, not rounded or switched off."""
    from gnn_mp_envs.envs.wrappers import make_rl_env
    with pytest.raises(ValueError, match=fragment):
        make_rl_env("maze2d", **kwargs)


def test_a_complex_action_is_refused():
    env = gym.make("GNNMP/Maze2DRRT-v0", disable_env_checker=True)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="real"):
        env.step(np.array([0.5 + 1j, 0.5]))


def test_reward_scale_is_gymnasiums_transform_reward_with_the_same_rewards():
    """Gymnasium's TransformReward replaced a hand-written ScaleReward: every reward of an episode is
    exactly the unscaled env's reward times the scale (same seed, same actions), and the env pickles."""
    import pickle

    from gymnasium.wrappers import TransformReward
    scaled = make_rl_env("maze2d", reward_scale=0.01, view_nodes=8)
    plain = make_rl_env("maze2d", reward_scale=1.0, view_nodes=8)
    layer = scaled
    while not isinstance(layer, TransformReward):
        layer = layer.env
    pickle.loads(pickle.dumps(layer))      # the TransformReward layer and the env it wraps
    scaled.reset(seed=3)
    plain.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(40):
        action = int(rng.integers(scaled.action_space.n))     # a candidate (a 2-vector was read as candidate 0)
        _, r_scaled, term, trunc, _ = scaled.step(action)
        _, r_plain, *_ = plain.step(action)
        assert type(r_scaled) is float and r_scaled == float(r_plain) * 0.01
        if term or trunc:
            break


def test_parallel_env_workers_are_deaf_to_ctrl_c_while_the_trainer_hears_it_during_their_start():
    """Ctrl-C on `train rl --lib torchrl --parallel`: the env's worker processes
    start with SIGINT ignored (no traceback per worker), while this process gets the KeyboardInterrupt
    (exit 130, one line) even while the workers are still starting; its handler is restored after."""
    import multiprocessing
    import os
    import signal
    import threading
    import time

    from helpers import report_sigint_ignored
    from train.rl.torchrl import start_workers_deaf_to_ctrl_c
    ctx = multiprocessing.get_context("spawn")
    answers, release = ctx.Queue(), threading.Event()

    def ctrl_c_once_heard():     # as soon as this process listens to Ctrl-C again (a loaded machine is slow)
        deadline = time.monotonic() + 30
        while signal.getsignal(signal.SIGINT) is signal.SIG_IGN and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGINT)

    leftover = ctx.Process(target=time.sleep, args=(60,))       # a child of earlier work, which exits meanwhile
    leftover.start()

    class SlowStartingEnv:       # a ParallelEnv's start: spawn the workers, then wait for them
        def start(self):
            leftover.terminate()
            leftover.join(10)
            self.workers = [ctx.Process(target=report_sigint_ignored, args=(answers,)) for _ in range(2)]
            for w in self.workers:
                w.start()
            threading.Thread(target=ctrl_c_once_heard, daemon=True).start()      # Ctrl-C meanwhile
            release.wait(60)     # an ignored Ctrl-C: start returns, and no KeyboardInterrupt is raised

    env = SlowStartingEnv()
    # Python's own Ctrl-C handler, whatever an earlier test left behind (an ignored SIGINT here would
    # make the Ctrl-C below silent however the mechanism behaved); the suite's handler is put back after.
    suite_handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            start_workers_deaf_to_ctrl_c(env, 2)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler     # restored by the mechanism
    finally:
        release.set()
        signal.signal(signal.SIGINT, suite_handler)
    assert [answers.get(timeout=60), answers.get(timeout=60)] == [True, True]
    for w in [*env.workers, leftover]:
        w.join(10)


@pytest.mark.parametrize("lib", ["sb3", "torchrl"])
def test_rerunning_train_rl_into_a_finished_run_is_refused_and_keeps_it(lib, tmp_path, capsys):
    """The same `train rl --out DIR` twice: the second is one line and rc 2,
    and the finished run's files stay as they were (default run folders carry a timestamp)."""
    from train.cli import main
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.json").write_text('{"finished": true}\n')
    (out / "policy.pt").write_bytes(b"the finished run's weights")
    rc = main(["train", "rl", "--lib", lib, "--task", "maze2d", "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already holds a run" in err[0], err
    assert (out / "config.json").read_text() == '{"finished": true}\n'
    assert (out / "policy.pt").read_bytes() == b"the finished run's weights"
    assert sorted(p.name for p in out.iterdir()) == ["config.json", "policy.pt"]


def test_rl_sampler_target_map_is_policy_action_to_state_bit_for_bit():
    """The RL sampler's inlined target map (pendulum: the angle wrapped in place) gives exactly what the
    one action map, policy_action_to_state, gives for the same draws: the oracle recomputed step by
    step from a second sampler with the same seed, along a real planning run."""
    from agents.registry import load_sampler
    from agents.samplers import active_target
    from gnn_mp_envs.envs.wrappers import policy_action_to_state
    from gnn_mp_envs.evaluation import evaluation_env
    torch.set_num_threads(1)
    env = evaluation_env("pendulum", "val")
    mine, oracle = (box_policy_sampler("pendulum", seed=5, proposals=1) for _ in range(2))
    obs, _ = env.reset(seed=5, options={"index": 2})
    wrapped = 0
    for _ in range(300):
        x = mine.model_sample(obs)
        loc, scale = oracle.params(obs)
        u = np.minimum(np.maximum(loc + scale * oracle.rng.normal(2), -1.0), 1.0).astype(np.float32)
        raw = np.asarray(active_target(obs), np.float32) + u * oracle.span32
        wrapped += not -np.pi <= raw[0] < np.pi
        expected = policy_action_to_state(u, "target", oracle.low32, oracle.high32,
                                          np.asarray(active_target(obs), np.float32), oracle.periodic)
        expected = np.minimum(np.maximum(expected, oracle.low32), oracle.high32)
        assert x.dtype == np.float32 and x.tobytes() == expected.tobytes()
        obs, _, terminated, truncated, _ = env.step(x)
        if terminated or truncated:
            break
    assert wrapped > 10         # the wrap was exercised
    env.close()


def test_torchrl_training_on_ray_actors_writes_a_local_runs_directory(tmp_path):
    """`train rl --lib torchrl --ray` (a local Ray instance, two actors collecting) runs to the end
    and writes the files a local run writes; the learner's policy is what the actors step."""
    pytest.importorskip("ray")
    from train.rl.torchrl import train as train_torchrl
    runs = {}
    for mode, extra in (("local", {}), ("ray", {"ray": "local", "ray_workers": 2})):
        args = tiny_args(tmp_path, "torchrl", "ppo", "maze2d", out=tmp_path / mode, eval_every=128, **extra)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = train_torchrl(args)
        assert result.steps >= 256
        runs[mode] = sorted(p.name for p in (tmp_path / mode).iterdir())
    assert runs["ray"] == runs["local"] and "best.pt" in runs["ray"] and "training_state.pt" in runs["ray"]


@pytest.mark.parametrize("argv, fragment", [
    (["--lib", "torchrl", "--ray", "127.0.0.1:1"], "cannot reach Ray at 127.0.0.1:1"),
    (["--ray"], "--lib torchrl"),
    (["--lib", "torchrl", "--ray", "--parallel"], "choose one"),
    (["--lib", "torchrl", "--ray", "--ray-workers", "8", "--n-envs", "4"], "--ray-workers 8 > --n-envs 4"),
    # issue 51 item 12: TorchRL's RayCollector stacked 2 and 1 envs' batches (a 34-line traceback)
    (["--lib", "torchrl", "--ray", "--ray-workers", "2", "--n-envs", "3"],
     "--n-envs 3 does not split evenly over --ray-workers 2"),
])
def test_train_rl_ray_flags_are_refused_in_one_line_before_any_work(argv, fragment, tmp_path, capsys):
    """An unreachable Ray address fails at once (a socket check, not Ray's minutes of retries), and
    --ray combinations that cannot work are one line; no run directory is made."""
    import time as _time

    from train.cli import main
    started = _time.perf_counter()
    with pytest.raises(SystemExit) as exc:
        main(["train", "rl", "--task", "maze2d", "--out", str(tmp_path / "run"), *argv])
    assert exc.value.code == 2 and _time.perf_counter() - started < 30
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("checkpoint", [True, False])
def test_a_dead_ray_actor_ends_the_run_in_one_line_naming_what_is_kept(tmp_path, checkpoint):
    """`collected` (the --ray training loop's batches): an actor that dies mid-run (Ray raises
    ActorDiedError out of the collector's iterator) ends the run with one RunError line that names the
    kept checkpoint (or says none was saved yet); the batches before it are delivered and the
    collector is shut down. Without --ray the same exception is not swallowed."""
    pytest.importorskip("ray")
    from ray.exceptions import ActorDiedError

    from train.rl.torchrl import collected
    from train.run import RunError

    class DyingCollector:
        shut = False

        def __iter__(self):
            yield "batch-0"
            yield "batch-1"
            raise ActorDiedError()

        def shutdown(self):
            self.shut = True
            raise RuntimeError("the actors are already gone")    # a failing shutdown is tolerated

    state = tmp_path / "training_state.pt"
    if checkpoint:
        state.write_bytes(b"kept")
    collector, seen = DyingCollector(), []
    with pytest.raises(RunError) as exc:
        for batch in collected(collector, SimpleNamespace(ray="local"), state):
            seen.append(batch)
    message = str(exc.value)
    assert seen == ["batch-0", "batch-1"] and collector.shut and "\n" not in message
    assert "a collector actor died (ActorDiedError)" in message
    assert (f"{state} is kept: continue with --resume" in message) if checkpoint else \
        ("no evaluation had saved a checkpoint yet" in message)
    assert state.exists() == checkpoint
    with pytest.raises(ActorDiedError):
        list(collected(DyingCollector(), SimpleNamespace(ray=None), state))
