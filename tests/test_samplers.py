"""The sampler interface: one TensorDictModule contract, usable from Gymnasium loops."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict

from agents.graph import to_pyg
from agents.samplers import SAMPLER_IN_KEYS, available_samplers, load_sampler


def _bounds(env_id="GNNMP/Maze2DBiRRT-v0"):
    env = gym.make(env_id)
    return env, env.action_space.low, env.action_space.high


@pytest.mark.parametrize("name", ["uniform", "goal-bias"])
def test_sampler_in_gym_loop_stays_in_bounds_and_is_seeded(name):
    env, low, high = _bounds("GNNMP/PendulumRRT-v0")
    actions = []
    for _ in range(2):
        sampler = load_sampler(name, low, high, seed=3)
        obs, _ = env.reset(seed=0)
        run = []
        for _ in range(50):
            a = sampler.act(obs)
            assert env.action_space.contains(a)
            run.append(a)
            obs, *_ = env.step(a)
        actions.append(np.array(run))
    np.testing.assert_array_equal(actions[0], actions[1])


def test_goal_bias_targets_the_active_trees_root():
    env, low, high = _bounds()
    sampler = load_sampler("goal-bias", low, high, seed=0, goal_bias=1.0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(sampler.act(obs), obs["goal"])
    obs, *_ = env.step(sampler.act(obs))
    assert obs["active_tree"][0] == 1
    np.testing.assert_allclose(sampler.act(obs), obs["start"])


def test_goal_bias_rate():
    env, low, high = _bounds("GNNMP/Maze2DRRT-v0")
    sampler = load_sampler("goal-bias", low, high, seed=0, goal_bias=0.2)
    obs, _ = env.reset(seed=0)
    hits = np.mean([np.allclose(sampler.act(obs), obs["goal"]) for _ in range(2000)])
    assert 0.17 < hits < 0.23


def test_tensordict_module_batched():
    env, low, high = _bounds()
    module = load_sampler("uniform", low, high, seed=0).as_module()
    assert list(module.in_keys) == list(SAMPLER_IN_KEYS) and list(module.out_keys) == ["action"]
    obs, _ = env.reset(seed=0)
    td = TensorDict({k: torch.as_tensor(np.stack([obs[k]] * 4)) for k in SAMPLER_IN_KEYS}, batch_size=[4])
    out = module(td)
    assert out["action"].shape == (4, 2)
    assert torch.all(out["action"] >= torch.as_tensor(low)) and torch.all(out["action"] <= torch.as_tensor(high))


def test_unknown_sampler_lists_known_names():
    with pytest.raises(ValueError, match="uniform"):
        load_sampler("nope", np.zeros(2), np.ones(2))
    assert {"uniform", "goal-bias"} <= set(available_samplers())


def test_pyg_converter_matches_tree():
    env = gym.make("GNNMP/Maze2DBiRRT-v0").unwrapped
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(40):
        obs, *_ = env.step(rng.uniform(0, 1, 2).astype(np.float32))
    data = to_pyg(obs)
    n = int(obs["num_nodes"][0])
    assert data.num_nodes == n and data.x.shape == (n, 5)
    edges = set(map(tuple, data.edge_index.T.tolist()))
    children = [i for i in range(n) if obs["parent"][i] >= 0]
    assert len(edges) == 2 * len(children)
    for c in children:
        assert (int(obs["parent"][c]), c) in edges and (c, int(obs["parent"][c])) in edges
    batch = to_pyg({k: np.stack([obs[k], obs[k]]) for k in obs})
    assert batch.num_graphs == 2 and batch.num_nodes == 2 * n
    assert batch.start.shape == (2, 2)
