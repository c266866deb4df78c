"""The adaptive mixture: a learned sampler whose model's share follows how useful its
samples are, so that it cannot end much worse than uniform sampling."""

import numpy as np
import pytest

from agents.registry import load_sampler
from agents.samplers.adaptive import GUARANTEE_FACTOR, MODEL, OTHER, UNIFORM, AdaptiveShare
from agents.samplers.base import ModelSampler
from gnn_mp_envs.evaluation import evaluation_env, plan_problems, summarize


class InsideAWall(ModelSampler):
    """A useless model: always the centre of the map's first obstacle (inside a wall)."""

    def model_sample(self, obs):
        return np.asarray(obs["obstacles"][0, 1:3], np.float64)


def test_a_useless_model_ends_within_the_documented_factor_of_uniform():
    """The guarantee, on 20 maze2d problems: with the adaptive share, a model that always proposes
    a point inside a wall needs at most GUARANTEE_FACTOR x uniform's median collision checks and
    iterations; with the fixed 75% model share the same model needs far more (the test can fail)."""
    env = evaluation_env("maze2d", "test")
    low, high = np.zeros(2), np.ones(2)
    uniform = plan_problems(load_sampler("uniform", task="maze2d", seed=0), env, range(20), 0)
    adaptive = plan_problems(InsideAWall(low, high, 0, uniform_mix=0.25, adaptive=True), env, range(20), 0)
    fixed = plan_problems(InsideAWall(low, high, 0, uniform_mix=0.25), env, range(20), 0)
    env.close()

    def median(records, key):
        return float(np.median([getattr(r, key) for r in records]))
    for key in ("collision_checks", "iterations"):
        assert median(adaptive, key) <= GUARANTEE_FACTOR * median(uniform, key), key
        assert median(fixed, key) > 2 * GUARANTEE_FACTOR * median(uniform, key), key
    assert summarize(adaptive)["success_rate"] >= summarize(uniform)["success_rate"] - 0.05


def _obs(nodes, tree_ids=None, start=(0.1, 0.1), goal=(0.9, 0.9)):
    nodes = np.asarray(nodes, np.float32).reshape(-1, 2)
    feats = np.zeros((len(nodes), 5), np.float32)
    if tree_ids is not None:
        feats[:, -1] = tree_ids
    return {"nodes": nodes, "node_features": feats, "num_nodes": np.array([len(nodes)]),
            "start": np.asarray(start, np.float32), "goal": np.asarray(goal, np.float32)}


def test_the_share_follows_the_rule_step_by_step():
    """Hand-made outcomes: the model's samples add no new cell, uniform's always do; the share is
    the documented formula of the discounted rates (the oracle written out here)."""
    share = AdaptiveShare(np.zeros(2), np.ones(2), np.zeros(2, bool), top=0.75, floor=0.05, discount=0.9, power=2.0,
                          cells=10, prior=1.0, prior_weight=2.0)
    nodes = [[0.05, 0.05]]
    assert share.observe(_obs(nodes)) == 0.75
    pulls, useful = np.array([2.0, 2.0]), np.array([1.0, 1.0])
    for t in range(30):
        source = MODEL if t % 2 else UNIFORM
        share.chose(source)
        if source == UNIFORM:            # a node in a new cell
            nodes.append([0.05 + 0.1 * (len(nodes) % 10), 0.05 + 0.1 * (len(nodes) // 10)])
        else:                            # a node in an old cell
            nodes.append([0.051, 0.051])
        got = share.observe(_obs(nodes))
        pulls, useful = 0.9 * pulls, 0.9 * useful
        pulls[source] += 1
        useful[source] += source == UNIFORM
        rate = useful / pulls
        expected = 0.05 + 0.7 * min(1.0, rate[MODEL] / rate[UNIFORM]) ** 2
        assert got == pytest.approx(expected)
    assert got < 0.1                          # near the floor
    share.chose(OTHER)                        # a goal sample is not scored
    assert share.observe(_obs(nodes)) == pytest.approx(got)
    assert share.observe(_obs(nodes[:3])) == 0.75          # a smaller tree: a new episode


def test_a_model_as_useful_as_uniform_keeps_its_share():
    share = AdaptiveShare(np.zeros(2), np.ones(2), np.zeros(2, bool), top=0.75, cells=20)
    nodes = [[0.01, 0.01]]
    share.observe(_obs(nodes))
    for t in range(200):
        share.chose(MODEL if t % 4 else UNIFORM)
        nodes.append([(t % 20) / 20 + 0.01, (t // 20) / 20 + 0.01])      # always a new cell
        assert share.observe(_obs(nodes)) == 0.75


def test_cells_are_counted_per_tree_and_wrap_periodic_coordinates():
    share = AdaptiveShare(np.array([-np.pi, -8.0]), np.array([np.pi, 8.0]), np.array([True, False]), top=0.5,
                          cells=4)
    share.observe(_obs([[0.1, 0.0]], [0]))
    share.chose(UNIFORM)
    share.observe(_obs([[0.1, 0.0], [0.2, 0.1]], [0, 1]))     # the same cell in the other tree: a new one
    assert (1.0, 2, 2) in share.visited and share.useful[UNIFORM] > share.useful[MODEL]
    share.chose(UNIFORM)
    share.observe(_obs([[0.1, 0.0], [0.2, 0.1], [np.pi, 0.0]], [0, 1, 0]))
    assert (0.0, 0, 2) in share.visited                       # theta = pi wraps to the first cell


def test_adaptive_learned_sampler_is_seeded_and_keeps_a_uniform_share():
    env = evaluation_env("maze2d", "val")
    runs = []
    for _ in range(2):
        sampler = load_sampler("gnn", task="maze2d", seed=0, adaptive=True)
        records = plan_problems(sampler, env, range(2), 0)
        runs.append([(r.nodes_expanded, r.collision_checks) for r in records])
        drawn = sampler.adaptive.drawn
        assert drawn[UNIFORM] > 0 and drawn[MODEL] > 0
        assert sampler.adaptive.floor <= sampler.adaptive.share <= sampler.adaptive.top
        assert 1 - sampler.goal_bias - sampler.adaptive.top >= sampler.uniform_mix - 1e-12
    env.close()
    assert runs[0] == runs[1]


def test_bad_adaptive_settings_are_refused():
    with pytest.raises(ValueError, match="unknown adaptive setting"):
        InsideAWall(np.zeros(2), np.ones(2), 0, adaptive={"flor": 0.1})
    with pytest.raises(ValueError, match="floor must be in"):
        InsideAWall(np.zeros(2), np.ones(2), 0, uniform_mix=0.5, adaptive={"floor": 0.9})
    with pytest.raises(ValueError, match="adaptive must be"):
        InsideAWall(np.zeros(2), np.ones(2), 0, adaptive="yes")
