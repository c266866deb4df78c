"""A learned sampler fed the trees of several envs serves each its own tree.

One ``gnn`` sampler, two envs planning the same problem (the same start and goal; different trees):
every draw for an env's observation equals the draw of a sampler that only ever saw that env, given
the same random stream. What a sampler keeps per episode (the adaptive share's statistics, the tree
engine's node embeddings, a forward reused over ``proposals`` samples) is keyed on the tree's content,
not on the node count or the problem.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from agents.samplers import load_sampler
from agents.samplers.trees import TreeStates, tree_size


def _draw(sampler, obs, seed: int) -> np.ndarray:
    sampler.rng = np.random.default_rng(seed)       # the same stream for the shared and the fresh sampler
    return sampler.act(obs)


@pytest.mark.parametrize("task,env_id", [("pendulum", "GNNMP/PendulumRRT-v0"), ("maze2d", "GNNMP/Maze2DRRT-v0")])
def test_one_sampler_fed_two_envs_draws_what_a_sampler_per_env_draws(task, env_id):
    envs = [gym.make(env_id, split="test", disable_env_checker=True) for _ in range(2)]
    obs = [env.reset(seed=0, options={"index": 0})[0] for env in envs]
    assert all(np.array_equal(o["start"], obs[0]["start"]) and np.array_equal(o["goal"], obs[0]["goal"]) for o in obs)
    shared = load_sampler("gnn", task=task, seed=0)
    fresh = [load_sampler("gnn", task=task, seed=0) for _ in envs]
    assert shared.adaptive is not None          # the shipped settings: the per-episode statistics are in play
    seeds = iter(np.random.default_rng(11).integers(2 ** 31, size=10_000).tolist())
    # each env grows alone first (two trees of one root are one tree to any sampler), then the smaller
    # tree grows (at equal sizes, in turn): the sampler sees two trees of one problem, often of one size
    compared, same_size = 0, 0
    for step in range(200):
        sizes = [tree_size(o) for o in obs]
        i = 0 if step < 8 else 1 if step < 16 else int(np.argmin(sizes)) if sizes[0] != sizes[1] else step % 2
        same_size += step >= 16 and sizes[0] == sizes[1]
        seed = next(seeds)
        got, want = _draw(shared, obs[i], seed), _draw(fresh[i], obs[i], seed)
        np.testing.assert_array_equal(got, want, err_msg=f"{task}: env {i}, draw {compared}")
        compared += 1
        obs[i], _, terminated, truncated, _ = envs[i].step(want)
        if terminated or truncated:
            obs[i] = envs[i].reset(seed=0, options={"index": 0})[0]
    assert same_size > 20                       # the trees had the same node count, and differed
    assert tree_size(obs[0]) > 3 and tree_size(obs[1]) > 3


def _obs(rows, start=(0.0, 0.0), goal=(1.0, 1.0)) -> dict:
    nodes = np.zeros((16, 2), np.float32)
    nodes[:len(rows)] = rows
    return {"nodes": nodes, "num_nodes": np.array([len(rows)]), "start": np.array(start, np.float32),
            "goal": np.array(goal, np.float32)}


def test_tree_states_tell_trees_apart_by_content():
    states = TreeStates(object, keep=3)
    root = [[0.0, 0.0]]
    a, b = root + [[0.5, 0.1]], root + [[0.1, 0.5]]
    sa = states.of(_obs(a))
    assert states.of(_obs(a + [[0.6, 0.2]])) is sa           # the same tree, grown
    sb = states.of(_obs(b))                                    # the same problem and size, another tree
    assert sb is not sa
    assert states.of(_obs(a + [[0.6, 0.2], [0.7, 0.3]])) is sa
    assert states.of(_obs(b + [[0.2, 0.6]])) is sb
    assert states.of(_obs(a, goal=(0.9, 1.0))) is not sa       # another problem
    assert states.of(_obs(root)) not in (sa, sb)               # a smaller tree: a new episode
    states.of(_obs([[5.0, 5.0]], start=(5.0, 5.0)))            # a fourth tree: the least recently used goes
    assert states.of(_obs(b + [[0.2, 0.6]])) is not sb and len(states) == 3
