"""Vectorised environments (docs/environments.md, "Vectorised environments"): Gymnasium's ``make_vec``
fails when two copies solve on one step with paths of different lengths (the info's ragged arrays);
``gnn_mp_envs.envs.vector.make_vec`` leaves those keys out, and a finished copy's path is there through
``envs.call("export_tree")`` until its next step resets it."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gnn_mp_envs  # noqa: F401  (registers the ids)
from gnn_mp_envs.envs.vector import RAGGED_INFO, make_vec

#: Two open maps, goals 0.32 and 0.22 from the start: the second copy first grows a branch away
#: (two steps), so both reach their goals on the sixth step, with paths of 8 and 6 states.
PROBLEMS = [{"start": [0.1, 0.5], "goal": [0.42, 0.5]}, {"start": [0.1, 0.5], "goal": [0.32, 0.5]}]
GOALS = np.array([p["goal"] for p in PROBLEMS], np.float32)
AWAY = np.array([PROBLEMS[0]["goal"], [0.1, 0.9]], np.float32)


def solve_together(envs):
    """Step both copies of a sync vector env to the step that solves both; its info and the trees."""
    envs.reset(seed=0)
    for env, problem in zip(envs.envs, PROBLEMS):
        env.reset(options={"problem": problem})
    for actions in [AWAY, AWAY] + [GOALS] * 10:
        _, _, terminated, _, info = envs.step(actions)
        if terminated.any():
            assert terminated.all()
            return info, envs.call("export_tree")
    raise AssertionError("the copies did not solve")


def test_gymnasium_make_vec_fails_on_paths_of_two_lengths_and_ours_does_not():
    with pytest.raises(ValueError, match="broadcast"):
        solve_together(gym.make_vec("GNNMP/Maze2DRRT-v0", 2, vectorization_mode="sync"))
    envs = make_vec("GNNMP/Maze2DRRT-v0", 2)
    info, trees = solve_together(envs)
    assert info["is_success"].tolist() == [True, True] and not set(RAGGED_INFO) & set(info)
    assert [len(t["path_nodes"]) for t in trees] == [8, 6]
    for tree, problem in zip(trees, PROBLEMS):
        path = tree["states"][tree["path_nodes"]]
        assert np.allclose(path[0], problem["start"]) and np.allclose(path[-1], problem["goal"])
    envs.close()


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_batches_the_observation_and_resets_a_finished_copy(mode):
    """Two copies of the test split for 300 steps: observations batched along the first axis, each copy
    plans its own problem, and a finished copy starts a new episode (a one-node tree again)."""
    envs = make_vec("GNNMP/Maze2DRRT-v0", 2, mode, split="test", max_nodes=60, copy_observations=False)
    obs, _ = envs.reset(seed=0)
    assert obs["nodes"].shape == (2, 60, 2) and obs["num_nodes"].tolist() == [[1], [1]]
    assert not np.array_equal(obs["start"][0], obs["start"][1])
    envs.action_space.seed(0)
    ended, done = 0, np.zeros(2, bool)
    for _ in range(300):
        obs, _, terminated, truncated, _ = envs.step(envs.action_space.sample())
        assert (obs["num_nodes"][done, 0] == 1).all()        # the step after the end: a new episode's root
        done = terminated | truncated
        ended += int(done.sum())
    assert ended >= 2
    envs.close()
