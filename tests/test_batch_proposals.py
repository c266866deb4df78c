"""A learned sampler's batches (``samples_per_step=K``): ``K`` samples from one forward over the tree.

Oracles: one sample of a batch is exactly one :meth:`act` (the same draws, the adaptive share scored the
same way), a batch's forward over several trees is each tree's own forward, and a batched sampler plans
with the env of its batch size, deterministically.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from agents.registry import load_sampler
from agents.samplers.base import ModelSampler
from gnn_mp_envs.evaluation import evaluation_env, plan_problem
from gnn_mp_envs.registration import task_spec


def _env(task: str, **kwargs):
    return gym.make(task_spec(task).env_id, split="val", disable_env_checker=True, **kwargs)


@pytest.mark.parametrize("task, name, settings", [
    ("maze2d", "gnn", {}), ("maze2d", "gnn", {"adaptive": True}), ("maze2d", "gnn-cvae", {"proposals": 4}),
    ("maze2d", "cvae", {}), ("panda-mbm", "gnn", {"goal_bias": 0.05}), ("arm", "gnn", {"adaptive": True})])
def test_a_batch_of_one_is_one_act(task, name, settings):
    """Two envs plan the same problem, one driven by the general ``ModelSampler.act``, one by
    ``act_batch(obs, 1)`` of a sampler
    with the same seed: the same actions at every step (so the same trees), the adaptive share's
    scoring of a batch of one included."""
    envs = [_env(task), _env(task)]
    obs = [env.reset(seed=0, options={"index": 1})[0] for env in envs]
    samplers = [load_sampler(name, task=task, seed=5, **settings) for _ in envs]
    for sampler in samplers:
        sampler.reset(5)
    for step in range(60):
        a = ModelSampler.act(samplers[0], obs[0])        # the general path (a GNN's own act is a batch of one)
        b = samplers[1].act_batch(obs[1], 1)
        assert b.shape == (1, len(a)) and b.dtype == np.float32
        np.testing.assert_array_equal(a, b[0], err_msg=f"step {step}")
        results = [env.step(action) for env, action in zip(envs, (a, b[0]))]
        obs = [r[0] for r in results]
        if results[0][2] or results[0][3]:
            break
    assert step > 5


@pytest.mark.parametrize("task, settings", [("panda-mbm", {"goal_bias": 0.1}), ("maze2d", {"adaptive": False}),
                                            ("fetch-mbm", {"uniform_mix": 0.0})])
def test_the_gnn_samplers_compiled_batches_are_the_general_paths(task, settings):
    """The GNN sampler's batches (choices, forward and samples in compiled calls) against the general numpy
    path of :class:`~agents.samplers.base.ModelSampler` it replaces (``act_batch`` and ``model_batch``):
    the same samples, bit for bit, at every step of a growing tree, for batches of 1 to 64 (uniform, target
    and model samples; BiRRT's two trees, RRT's one; a batch of model samples only)."""
    from agents.samplers.base import ModelSampler
    env = _env(task)
    obs, _ = env.reset(seed=0, options={"index": 2})
    fast, general = (load_sampler("gnn", task=task, seed=9, **settings) for _ in range(2))
    for sampler in (fast, general):
        sampler.reset(9)
    sizes = [1, 2, 5, 16, 64]
    for step in range(40):
        k = sizes[step % len(sizes)]
        a, b = fast.act_batch(obs, k), ModelSampler.act_batch(general, obs, k)
        assert a.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(a, b, err_msg=f"step {step}, batch of {k}")
        obs, _, terminated, truncated, _ = env.step(a[0])
        if terminated or truncated:
            obs, _ = env.reset(seed=step, options={"index": 3})
    assert fast.forward_calls > 10


def test_a_batch_forward_over_both_trees_is_each_trees_forward():
    """:meth:`IncrementalTreeGNN.grown_mixtures` of trees (0, 1) in one call gives, row by row, the floats
    of :meth:`grown_mixture` for each tree alone (fresh engines, the same grown BiRRT tree)."""
    env = _env("panda-mbm")
    obs, _ = env.reset(seed=0, options={"index": 0})
    rng = np.random.default_rng(0)
    for _ in range(40):
        obs = env.step(rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32))[0]
    assert int(obs["num_nodes"][0]) > 10
    assert set(obs["node_features"][:int(obs["num_nodes"][0]), -1].tolist()) == {0.0, 1.0}
    batch = load_sampler("gnn", task="panda-mbm", seed=0)
    cumulative, shifts = batch.engine.grown_mixtures(obs, batch.engine.new_rows(obs), np.array([0, 1]), 0.7)
    for tree in (0, 1):
        alone = load_sampler("gnn", task="panda-mbm", seed=0)
        _, c, s = alone.engine.grown_mixture(obs, alone.engine.new_rows(obs), tree, 0.7)
        np.testing.assert_array_equal(cumulative[tree], c)
        np.testing.assert_array_equal(shifts[tree], s)


@pytest.mark.parametrize("task", ["maze2d", "panda-mbm"])
def test_a_batched_learned_sampler_plans_with_its_batch_and_repeats_itself(task):
    """``samples_per_step=16``: the benchmark's env of that batch size, every sample consumed by the
    planner counted, the same counters from the same seed twice; without the setting, the stored one
    (1 where none is stored)."""
    import json
    from agents.checkpoints import shipped_checkpoint
    stored = json.loads(shipped_checkpoint("gnn", task).with_suffix(".json").read_text())["sampler"]
    assert load_sampler("gnn", task=task, seed=0).samples_per_step == stored.get("samples_per_step", 1)
    sampler = load_sampler("gnn", task=task, seed=0, samples_per_step=16)
    assert sampler.samples_per_step == 16
    env = evaluation_env(task, "val", samples_per_step=16)
    first = [plan_problem(env, sampler, i, 0) for i in range(3)]
    again = [plan_problem(env, sampler, i, 0) for i in range(3)]
    assert all(r.success for r in first)
    assert [(r.iterations, r.collision_checks) for r in first] == [(r.iterations, r.collision_checks) for r in again]
    env.close()


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "4", 10**9])
def test_a_bad_batch_size_is_refused_in_one_line(bad):
    with pytest.raises(ValueError, match="samples_per_step must be an integer"):
        load_sampler("gnn", task="maze2d", seed=0, samples_per_step=bad)


def test_refresh_growth_reads_the_tree_again_only_after_it_grew_by_that_fraction():
    """``refresh_growth``: a forward serves later batches until the tree has more than ``(1 + f)`` times the
    nodes it read; 0 (the default) reads it whenever it grew. On one problem the forwards are those of the
    rule: with 0.5, a tree of 40 nodes is read again only at more than 60."""
    env = evaluation_env("panda-mbm", "val", samples_per_step=4)
    seen = {}
    for growth in (0.0, 0.5):
        sampler = load_sampler("gnn", task="panda-mbm", seed=0, samples_per_step=4, uniform_mix=0.0,
                               refresh_growth=growth)
        reads = []
        original = sampler.mixtures
        sampler.mixtures = lambda obs, trees, original=original, reads=reads: (
            reads.append(int(obs["num_nodes"][0])) or original(obs, trees))
        plan_problem(env, sampler, 4, 0)
        seen[growth] = reads
        assert reads[0] == 2 and all(b > a for a, b in zip(reads, reads[1:]))
    assert len(seen[0.5]) < len(seen[0.0])
    assert all(b > 1.5 * a for a, b in zip(seen[0.5], seen[0.5][1:]))
    env.close()


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), True, "0.1"])
def test_a_bad_refresh_growth_is_refused_in_one_line(bad):
    with pytest.raises(ValueError, match="refresh_growth must be a finite number >= 0"):
        load_sampler("gnn", task="panda-mbm", seed=0, refresh_growth=bad)


@pytest.mark.parametrize("settings", [{"adaptive": True}, {"proposals": 4}])
def test_refresh_growth_is_refused_where_it_would_be_ignored(settings):
    with pytest.raises(ValueError, match="refresh_growth applies to batches with fixed shares and proposals=1"):
        load_sampler("gnn", task="panda-mbm", seed=0, refresh_growth=0.1, **settings)
    assert load_sampler("gnn", task="panda-mbm", seed=0, refresh_growth=np.float32(0.0), **settings)
