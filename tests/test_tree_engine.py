"""The incremental numpy engines against their torch models, on what makes an action.

For every shipped tree model (the GNN node mixture on RRT and BiRRT, the GNN-CVAE's tree
context and decoder, the pendulum's sample scorer), a tree is grown to a few hundred nodes
with uniform samples and fed to the engine one step at a time; at several sizes the engine's
offsets, log-sigmas, keys, mixture weights, component shift, tree context, decoded state and
candidate scores must equal the torch model's forward pass over the whole prefix (float64) to 1e-5.
"""

from __future__ import annotations

import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import gnn_mp_envs  # noqa: F401
from agents.checkpoints import load_checkpoint, shipped_checkpoint
from agents.tree.engine import IncrementalTreeGNN, IncrementalTreeScorer
from agents.nn.causal import causal_knn
from tests.helpers import uniform_policy

ROOT = Path(__file__).resolve().parents[1]

TOL = 1e-5


def grown(task: str, min_nodes: int, max_steps: int = 1500):
    """Copies of every observation of a uniform run on validation problem 0 (goal reached or not)."""
    spec = gnn_mp_envs.task_spec(task)
    env = gym.make(spec.env_id, split="val", copy_observations=False, disable_env_checker=True)
    policy = uniform_policy(env, 0)
    for index in range(10):
        obs, _ = env.reset(seed=0, options={"index": index})
        snapshots = [{k: np.array(v) for k, v in obs.items()}]
        for _ in range(max_steps):
            obs, _, terminated, truncated, _ = env.step(policy(obs))
            snapshots.append({k: np.array(v) for k, v in obs.items()})
            if terminated or truncated:
                break
        if int(snapshots[-1]["num_nodes"][0]) >= min_nodes:
            env.close()
            return snapshots
    raise AssertionError(f"no {task} validation problem grew {min_nodes} nodes")


def prefix(obs, model):
    """The torch inputs of one observation: nodes, features, parents, tree ids, causal k-NN (float64)."""
    n = int(obs["num_nodes"][0])
    d = model.state_dim
    nodes = torch.as_tensor(obs["nodes"][:n], dtype=torch.float64)
    feats = torch.as_tensor(obs["node_features"][:n], dtype=torch.float64)
    tid = feats[:, 2 * d].long()
    parent = torch.as_tensor(obs["parent"][:n]).long()
    return n, nodes, feats, parent, tid


def torch_mixture(model, obs, temperature):
    """The torch model's node heads, context, mixture weights and shift at one observation."""
    n, nodes, feats, parent, tid = prefix(obs, model)
    knn = causal_knn(nodes, tid, model.knn, model.step_scale, model.periodic)
    with torch.no_grad():
        h = model.embed(nodes, feats, parent, knn)
        key, offset, log_sigma = model.node_heads(h)
        onehot = F.one_hot(tid, model.num_trees).double()
        counts = onehot.sum(0)
        means = (onehot.T @ h) / counts.clamp(min=1)[:, None]
        active = torch.as_tensor(obs["active_tree"]).long()
        start = torch.as_tensor(obs["start"], dtype=torch.float64)[None]
        goal = torch.as_tensor(obs["goal"], dtype=torch.float64)[None]
        q = model.context(start, goal, active, means[None], counts[None])
        weights = torch.softmax(model.logits(q, key, temperature)[0], -1)
        shift = model.shift(q, active)[0]
    return {"key": key.numpy(), "offset": offset.numpy(), "log_sigma": log_sigma.numpy(), "q": q[0].numpy(),
            "weights": weights.numpy(), "shift": shift.numpy()}


def check_mixture_engine(gnn, snapshots, temperature=0.5, decoder=None):
    engine = IncrementalTreeGNN(gnn, capacity=16)           # grows its caches on the way
    fused = IncrementalTreeGNN(gnn, capacity=16)            # the sampler's one call per step
    fused_context = IncrementalTreeGNN(gnn, capacity=16, heads=False)    # the GNN-CVAE's
    checked = 0
    for i, obs in enumerate(snapshots):
        engine.ingest(obs)
        n = int(obs["num_nodes"][0])
        fused_p, _, fused_shift = fused.grown_mixture(obs, fused.new_rows(obs), int(obs["active_tree"][0]), temperature)
        fused_q = fused_context.grown_context(obs, fused_context.new_rows(obs), int(obs["active_tree"][0]))
        if i not in (len(snapshots) // 3, 2 * len(snapshots) // 3, len(snapshots) - 1):
            continue
        ref = torch_mixture(gnn, obs, temperature)
        active = int(obs["active_tree"][0])
        q = engine.context(obs["start"].astype(np.float64), obs["goal"].astype(np.float64), active)
        p, shift = engine.mixture(q, active, temperature)
        assert engine.n == n == fused.n
        # the one compiled call runs the same compiled functions: the same floats, bit for bit
        assert np.array_equal(fused_p, p) and np.array_equal(fused_shift, shift)
        assert np.array_equal(fused.keys[:n], engine.keys[:n]) and np.array_equal(fused.sums, engine.sums)
        assert np.array_equal(fused_q, q)
        np.testing.assert_allclose(engine.keys[:n], ref["key"], atol=TOL)
        np.testing.assert_allclose(engine.offsets[:n], ref["offset"], atol=TOL)
        np.testing.assert_allclose(engine.log_sigma[:n], ref["log_sigma"], atol=TOL)
        np.testing.assert_allclose(q, ref["q"], atol=TOL)
        np.testing.assert_allclose(p, ref["weights"], atol=TOL)
        np.testing.assert_allclose(shift, ref["shift"], atol=TOL)
        if decoder is not None:       # the GNN-CVAE decodes a latent draw with that context
            z = torch.randn(1, decoder.latent_channels, generator=torch.Generator().manual_seed(i), dtype=torch.float64)
            with torch.no_grad():
                mine = decoder.decode(z, torch.as_tensor(q)[None])
                theirs = decoder.decode(z, torch.as_tensor(ref["q"])[None])
            np.testing.assert_allclose(mine.numpy(), theirs.numpy(), atol=TOL)
        checked += 1
    assert checked == 3
    # the context-only engine (the GNN-CVAE's: no node heads) gives the same context, and no mixture
    # (all rows in one batch here: the batch's BLAS products may round otherwise than the increments')
    context_only = IncrementalTreeGNN(gnn, capacity=16, heads=False)
    context_only.ingest(snapshots[-1])
    active = int(snapshots[-1]["active_tree"][0])
    q_only = context_only.context(snapshots[-1]["start"].astype(np.float64), snapshots[-1]["goal"].astype(np.float64),
                                  active)
    np.testing.assert_allclose(q_only, q, rtol=0, atol=1e-12)
    assert not context_only.keys.any() and not context_only.offsets.any()
    with pytest.raises(RuntimeError, match="heads=False"):
        context_only.mixture(q_only, active, temperature)


@pytest.mark.parametrize("task,min_nodes", [("maze2d", 200), ("arm", 60)])
def test_gnn_mixture_engine_equals_the_torch_model(task, min_nodes):
    model, record = load_checkpoint(shipped_checkpoint("gnn", task), expected_kind="tree/gnn")
    snapshots = grown(task, min_nodes)
    assert model.num_trees == (2 if task == "arm" else 1)
    check_mixture_engine(model.double(), snapshots, temperature=record["meta"]["sampler"]["temperature"])


@pytest.mark.parametrize("task", ["maze2d", "pendulum"])
def test_gnn_engine_with_relative_inputs_equals_the_torch_model(task):
    """The position-free variant (``relative_inputs``: offsets to start and goal only; the context's
    start and goal as their wrapped difference), untrained weights, on a grown tree."""
    from agents.tree.models import TreeGNN
    spec = gnn_mp_envs.task_spec(task)
    low, high = spec.state_bounds()
    torch.manual_seed(0)
    model = TreeGNN(2, 32, 2, 6, state_center=((low + high) / 2).tolist(), state_scale=((high - low) / 2).tolist(),
                    feature_scale=[*(high - low), *(high - low), 1.0], step_scale=[spec.step_scale] * 2,
                    periodic=spec.periodic, num_trees=1, relative_inputs=True)
    assert model.input[0].in_features == 5
    check_mixture_engine(model.double(), grown(task, 200))


@pytest.mark.parametrize("task,min_nodes", [("maze2d", 200), ("pendulum", 200), ("arm", 60)])
def test_gnn_cvae_engine_equals_the_torch_model(task, min_nodes):
    model, _ = load_checkpoint(shipped_checkpoint("gnn-cvae", task), expected_kind="tree/gnn-cvae")
    model = model.double()
    check_mixture_engine(model.gnn, grown(task, min_nodes), decoder=model)


def test_scorer_engine_equals_the_torch_model():
    model, _ = load_checkpoint(shipped_checkpoint("gnn", "pendulum"), expected_kind="tree/gnn-scorer")
    model = model.double()
    snapshots = grown("pendulum", 300)
    engine = IncrementalTreeScorer(model, capacity=16)
    rng = np.random.default_rng(0)
    low, high = np.array([-np.pi, -8.0]), np.array([np.pi, 8.0])
    checked = 0
    for i, obs in enumerate(snapshots):
        engine.ingest(obs)
        if i not in (len(snapshots) // 3, 2 * len(snapshots) // 3, len(snapshots) - 1):
            continue
        n, nodes, feats, parent, tid = prefix(obs, model)
        samples = rng.uniform(low, high, size=(16, 2))
        near = engine.nearest(samples, 0)
        s = torch.as_tensor(samples)
        with torch.no_grad():
            knn = model.causal_knn(nodes, tid)
            near_torch = model.nearest(s, nodes)
            goal = torch.as_tensor(obs["goal"], dtype=torch.float64)
            ref = model(nodes, feats, parent, knn, goal, near_torch, torch.full_like(near_torch, n), s)
        np.testing.assert_array_equal(near, near_torch.numpy())
        np.testing.assert_allclose(engine.logits(samples, near), ref.numpy(), atol=TOL)
        checked += 1
    assert checked == 3 and engine.n >= 300


@pytest.mark.parametrize("name,task", [("cvae", "maze2d"), ("cvae", "arm"), ("gnn-cvae", "pendulum")])
def test_decode_for_one_condition_equals_the_full_decoder(name, task):
    """The samplers' decode of many latents for one condition (the condition's first-layer share
    computed once) equals the decoder on the condition repeated per row: in float64 to 1e-12, and
    in the float32 the samplers run to 1e-5."""
    model, _ = load_checkpoint(shipped_checkpoint(name, task), expected_kind=f"tree/{name}")
    width = model.condition_dim if name == "cvae" else model.gnn.hidden_channels
    generator = torch.Generator().manual_seed(0)
    for dtype, tol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        m = model.to(dtype)
        z = torch.randn((300, m.latent_channels), generator=generator, dtype=dtype)
        condition = torch.randn(width, generator=generator, dtype=dtype)
        with torch.inference_mode():
            full = m.decode(z, condition.expand(len(z), -1))
            shared = m.decode_for_one(z, condition)
        assert shared.shape == full.shape == (300, m.state_dim if name == "cvae" else m.gnn.state_dim)
        torch.testing.assert_close(shared, full, rtol=tol, atol=tol)


def test_wrap_pi_is_the_float_modulo_bit_for_bit():
    """The wrapped angle differences without numpy's float modulo equal ``(v + pi) % (2 pi) - pi``
    bit for bit (sign of zero included), for arrays in the exact step's range and beyond it (the
    modulo's fallback), with the edge values of that range, NaN and infinities, float64 and float32;
    and ``wrap_periodic`` equals its ``np.where`` expression on mixed periodic and plain columns."""
    from agents.samplers.base import wrap_periodic, wrap_pi
    rng = np.random.default_rng(0)
    two_pi = 2 * np.pi
    edges = np.array([0.0, -0.0, np.pi, -np.pi, two_pi, -two_pi, 3 * np.pi, -3 * np.pi, np.nextafter(two_pi, 0),
                      np.nextafter(-np.pi, 0), np.nextafter(3 * np.pi, 0), np.nextafter(3 * np.pi, 10), -1e-300, 1e-300,
                      -1e-17, np.nextafter(-two_pi, 0), np.nextafter(-two_pi, -10)])

    def expected(v):
        return (v + np.pi) % two_pi - np.pi

    def same(a, b):
        return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True) and \
            np.array_equal(np.signbit(a), np.signbit(b))

    with np.errstate(invalid="ignore"):      # NaN and inf through the modulo warn, as they should
        for trial in range(300):
            span = [two_pi, 3 * np.pi, 20.0][trial % 3]
            v = rng.uniform(-span, span, (int(rng.integers(1, 30)), int(rng.integers(1, 40))))
            flat = v.reshape(-1)
            flat[:len(edges)] = edges[:len(flat)]
            if trial % 7 == 0:
                flat[-1] = [np.nan, np.inf, -np.inf][trial % 3]
            for arr in (v, v.astype(np.float32)):
                assert same(wrap_pi(arr), expected(arr)), trial
                periodic = rng.uniform(size=arr.shape[-1]) < 0.5
                assert same(wrap_periodic(arr, periodic), np.where(periodic, expected(arr), arr)), trial


def test_compiled_angle_wrap_is_the_float_modulo_bit_for_bit():
    """The compiled per-node loop's wrap of one difference equals ``(v + pi) % (2 pi) - pi`` bit for
    bit (sign of zero included): its exact one-step path, its modulo fallback beyond ``[-2 pi, 4 pi)``,
    the edges of that range, NaN and infinities; plain coordinates pass through."""
    from agents.tree.compiled import _wrapped
    rng = np.random.default_rng(1)
    two_pi = 2 * np.pi
    values = np.concatenate([rng.uniform(-20.0, 20.0, 3000), rng.uniform(-two_pi, two_pi, 3000),
                             [0.0, -0.0, np.pi, -np.pi, two_pi, -two_pi, 3 * np.pi, -3 * np.pi, np.nextafter(3 * np.pi, 0),
                              np.nextafter(-3 * np.pi, 0), np.nextafter(-np.pi, 0), -1e-300, 1e-17, np.inf, -np.inf, np.nan]])
    with np.errstate(invalid="ignore"):
        expected = (values + np.pi) % two_pi - np.pi
    got = np.array([_wrapped(float(v), True) for v in values])
    assert np.array_equal(got, expected, equal_nan=True) and np.array_equal(np.signbit(got), np.signbit(expected))
    assert all(_wrapped(float(v), False) == v for v in values[:100])


def _gelu_reference(values: np.ndarray) -> np.ndarray:
    """The GELU with libm's scalar ``erf`` (Python's ``math.erf``), in the kernels' order."""
    import math
    half = 1.0 / math.sqrt(2.0)
    return np.array([0.5 * v * (1.0 + math.erf(v * half)) for v in values.tolist()])


def _gelu_values() -> np.ndarray:
    """Pre-activations as the GELUs see them, the tails and the edges: lengths not a multiple of four
    come from slicing."""
    rng = np.random.default_rng(2)
    return np.concatenate([rng.normal(0.0, s, 4000) for s in (0.3, 1.0, 3.0)] +
                          [np.linspace(-40.0, 40.0, 4001), [0.0, -0.0, 1e-300, -1e-300, 8.3, -8.3, 1e300, -1e300]])


def test_compiled_gelu_is_libm_erf_to_a_few_ulp_and_keeps_the_layout():
    """The compiled GELU (glibc's vector ``erf`` of four doubles where this machine has it) equals the
    GELU with libm's ``erf`` to 2e-15 absolute (a few ulp), exactly where the reference is 0 or +-x,
    on 1-D runs of any length and on the rows of a 2-D array, in place."""
    from numba import njit

    from agents.tree.compiled import _gelu_into, _gelu_rows

    @njit(cache=False)
    def flat(v):
        _gelu_into(v)

    @njit(cache=False)
    def rows(a):
        _gelu_rows(a)

    values = _gelu_values()
    expected = _gelu_reference(values)
    for n in (1, 3, 4, 5, 63, 64, 65, len(values)):
        got = values[:n].copy()
        flat(got)
        np.testing.assert_allclose(got, expected[:n], rtol=0, atol=2e-15)
    got = values[:64 * 7].reshape(7, 64).copy()
    rows(got)
    np.testing.assert_allclose(got.reshape(-1), expected[:64 * 7], rtol=0, atol=2e-15)
    whole = values.copy()
    flat(whole)
    exact = (expected == 0.0) | (np.abs(values) > 10.0)
    assert np.array_equal(whole[exact], expected[exact])


def test_compiled_gelu_without_the_vector_library_is_libm_bit_for_bit():
    """Where glibc's vector math library (or AVX2) is missing the kernels call libm's ``erf`` one
    value at a time: then the GELU equals the scalar reference bit for bit (compiled here with the
    fallback forced, in a function of its own so no cached kernel is touched)."""
    from numba import njit

    import agents.tree.compiled as compiled
    saved = compiled.VECTOR_ERF
    compiled.VECTOR_ERF = False
    try:
        @njit(cache=False)
        def flat(v):
            compiled._gelu_into(v)

        values = _gelu_values()
        got = values.copy()
        flat(got)
    finally:
        compiled.VECTOR_ERF = saved
    assert np.array_equal(got, _gelu_reference(values))


def test_a_one_tree_gnn_refuses_a_birrt_observation():
    """An RRT-trained GNN (one tree slot) fed a BiRRT observation: a one-line error, not a write
    past its caches (unchecked, the compiled loop wrote tree 1's sums out of bounds)."""
    from agents.samplers import load_sampler
    sampler = load_sampler("gnn", task="maze2d", seed=0)
    assert sampler.engine.trees == 1
    env = gym.make("GNNMP/Maze2DBiRRT-v0", split="val", disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    with pytest.raises(ValueError, match="no slot"):
        for _ in range(50):
            obs, *_ = env.step(sampler.act(obs))
    engine = IncrementalTreeGNN(sampler.model)
    with pytest.raises(ValueError, match="no slot"):
        engine.ingest(obs)
    with pytest.raises(ValueError, match="no slot"):
        engine.context(obs["start"].astype(np.float64), obs["goal"].astype(np.float64), 1)
    # a forward asked for tree 1 of an RRT observation is refused before it embeds anything: a retry for
    # tree 0 gives a fresh engine's floats (the rows were not embedded, nor joined the k-NN's k-d tree, twice)
    env = gym.make("GNNMP/Maze2DRRT-v0", split="val", disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    for _ in range(30):
        obs, *_ = env.step(env.action_space.sample())
    tried, fresh = IncrementalTreeGNN(sampler.model), IncrementalTreeGNN(sampler.model)
    for method, tree in (("grown_mixture", 1), ("grown_mixtures", np.array([0, 1]))):
        with pytest.raises(ValueError, match="no slot"):
            getattr(tried, method)(obs, tried.new_rows(obs), tree, 0.7)
    want = fresh.grown_mixture(obs, fresh.new_rows(obs), 0, 0.7)
    got = tried.grown_mixture(obs, tried.new_rows(obs), 0, 0.7)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_each_forward_asks_about_the_compiled_loop_it_calls(monkeypatch):
    """The single-step and the batch forwards are separate compiled loops and a run uses one: each asks
    about its own right before calling it (asked at construction about the single-step loop, a
    benchmark whose batch loop was cached said "compiling ... about 40 s" on every run)."""
    from agents.samplers import load_sampler
    from agents.tree import compiled, engine as engine_module
    asked = []
    monkeypatch.setattr(engine_module, "announce_compilation", lambda dispatcher, what: asked.append(dispatcher))
    model = load_sampler("gnn", task="maze2d", seed=0).model
    env = gym.make("GNNMP/Maze2DRRT-v0", split="val", disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    single, batch, context = (IncrementalTreeGNN(model), IncrementalTreeGNN(model),
                              IncrementalTreeGNN(model, heads=False))
    assert asked == []
    single.grown_mixture(obs, single.new_rows(obs), 0, 0.7)
    batch.grown_mixtures(obs, batch.new_rows(obs), np.array([0]), 0.7)
    context.grown_context(obs, context.new_rows(obs), 0)
    assert asked == [compiled.mixture_after_rows, compiled.mixtures_after_rows, compiled.context_after_rows]


def test_a_compilation_is_announced_once_and_never_when_cached(tmp_path):
    """The ~40 s first compile prints one line (not a silent hang); a process that finds numba's cache
    for the current source prints nothing. node_mixture stands in for the big loops (it compiles fast)."""
    import subprocess
    import sys
    script = ("import numpy as np\n"
              "from agents.tree.compiled import announce_compilation as a, node_mixture as f\n"
              "first, again = a(f, 'x'), a(f, 'x')\n"
              "f(np.ones((3, 2)), np.ones(2), 0, 1.0, np.ones((2, 2)), np.zeros(2), np.ones(2))\n"
              "print(first, again)\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=str(ROOT))
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, cwd=tmp_path)
            for _ in range(2)]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr[-2000:]
    assert [r.stdout.split() for r in runs] == [["True", "False"], ["False", "False"]]
    assert runs[0].stderr.count("gnn-mp: compiling x (numba; first use") == 1 and "compiling" not in runs[1].stderr


def _knn_oracle(i0, x, tid, states, tree_id, knn, periodic, unit, planner_metric):
    """The causal k-NN by brute force in Python floats: every earlier node of the row's tree, its
    distance by the documented formula, sorted by (distance, index)."""
    import math
    B, d = x.shape
    near = np.zeros((B, max(knn, 1)), np.int64)
    found = np.zeros(B, np.int64)
    for r in range(B):
        scored = []
        for j in range(i0 + r):
            if tree_id[j] != tid[r]:
                continue
            total = 0.0
            for c in range(d):
                if planner_metric:
                    v = abs(float(x[r, c]) - float(states[j, c]))
                    if periodic[c]:
                        v = min(v, 2.0 * math.pi - v)
                    v *= float(unit[c])
                else:
                    v = float(states[j, c]) - float(x[r, c])
                    if periodic[c]:
                        v = (v + math.pi) % (2.0 * math.pi) - math.pi
                    v /= float(unit[c])
                total += v * v
            scored.append((total, j))
        best = sorted(scored)[:knn]
        found[r] = len(best)
        near[r, :len(best)] = [j for _, j in best]
    return near, found


@pytest.mark.parametrize("planner_metric", [False, True])
def test_compiled_causal_knn_is_the_brute_force_answer(planner_metric):
    """The kernels' causal k-NN (two passes over a column copy of the states) returns, row by row,
    the ``knn`` earlier nodes of the row's tree with the smallest distance, the earlier node first
    on ties, as a brute-force sort: wrapped angles, angles outside [-pi, pi) (the wrap's modulo
    fallback), exact ties from repeated states, two trees, fewer earlier nodes than ``knn``."""
    from agents.tree.compiled import _causal_knn
    rng = np.random.default_rng(3)
    n = 400
    states = np.stack([rng.uniform(-np.pi, np.pi, n), rng.uniform(-8.0, 8.0, n), rng.uniform(-1.0, 1.0, n)], 1)
    states[::7] = states[3]                                  # exact ties
    states[5::50, 0] += 4 * np.pi                            # not wrapped: the modulo path
    states = np.round(states, 3)
    tree_id = rng.integers(0, 2, n)
    periodic = np.array([True, False, False])
    unit = np.array([0.4, 0.4, 0.25])
    for i0, B in ((0, 40), (150, 120), (399, 1)):
        x, tid = states[i0:i0 + B].copy(), tree_id[i0:i0 + B].copy()
        for knn in (0, 1, 6):
            got = _causal_knn(i0, x, tid, states, tree_id, knn, periodic, unit, planner_metric)
            want = _knn_oracle(i0, x, tid, states, tree_id, knn, periodic, unit, planner_metric)
            np.testing.assert_array_equal(got[1], want[1])
            for r in range(B):
                np.testing.assert_array_equal(got[0][r, :got[1][r]], want[0][r, :want[1][r]])


def test_the_engines_kd_tree_knn_is_the_brute_force_scan():
    """The engine's causal k-NN from its bucketed k-d trees (:func:`_kd_causal_knn`) against the brute-force
    scan (:func:`_causal_knn`), batch after batch of a growing two-tree graph: the same nodes in the same
    order, exact ties (repeated states, equal distances on a grid) to the earlier node, a wrapped angle and
    angles outside [-pi, pi) (never split on; the exact wrap), fewer earlier nodes than ``knn``."""
    from agents.tree.compiled import _causal_knn, _kd_causal_knn
    from gnn_mp_envs.core.nearest import BUCKET, NearestIndex
    rng = np.random.default_rng(8)
    n, d = 700, 4
    states = np.concatenate([rng.uniform(-np.pi, np.pi, (n, 1)), rng.integers(-3, 4, (n, 2)).astype(float),
                             rng.uniform(-1.0, 1.0, (n, 1))], axis=1)
    states[::9] = states[4]                                  # exact ties
    states[6::40, 0] += 4 * np.pi                            # not wrapped
    tree_id = (rng.random(n) < 0.3).astype(np.int64)
    periodic = np.array([True, False, False, False])
    unit = np.array([0.4, 0.5, 0.5, 0.25])
    index = NearestIndex(n, 2, 1.0 / unit, periodic)
    kd = index.arrays
    i0 = 0
    for B in [1, 3, 40, 1, 150, 5, 300, 200]:
        x, tid = states[i0:i0 + B].copy(), tree_id[i0:i0 + B].copy()
        for knn in (6,):
            want = _causal_knn(i0, x, tid, states, tree_id, knn, periodic, unit, False)
            got = _kd_causal_knn(i0, x, tid, states, knn, periodic, unit, kd)
            np.testing.assert_array_equal(got[1], want[1])
            for r in range(B):
                np.testing.assert_array_equal(got[0][r, :got[1][r]], want[0][r, :want[1][r]], err_msg=f"row {i0 + r}")
        i0 += B
    assert i0 == n and (kd.root >= 0).all() and kd.used[1] > n // BUCKET    # both trees, leaves split


def test_compiled_draw_is_the_numpy_search_and_gaussian():
    """:func:`draw_around_nodes` (a batch's samples from its node mixtures, one compiled call) against the
    numpy it replaced: per sample ``searchsorted(running sums, r (1 - 1e-12), "right")`` capped at the last
    node, then ``states + offsets + shift + sigma_scale exp(log_sigma) z``; exactly the node (with
    ``sigma_scale`` 0 the sample is the node's mean, bit for bit), the Gaussian to rounding. Draws land on
    running sums exactly, between them, past the last one and below the first."""
    from agents.tree.compiled import draw_around_nodes
    rng = np.random.default_rng(4)
    n, d, T, m = 30, 3, 2, 400
    p = rng.random((2, n))
    p[:, 7] = 0.0                                            # a node of no weight: never drawn
    cumulative = np.cumsum(p / p.sum(1, keepdims=True), axis=1)
    cumulative[:, -1] = 1.0 - 1e-13                          # r (1 - 1e-12) can pass the last running sum
    states, offsets = rng.normal(size=(n + 5, d)), rng.normal(size=(n + 5, T, d))
    log_sigma, shifts = rng.normal(size=(n + 5, T, d)), rng.normal(size=(2, d))
    trees = rng.integers(0, 2, m)
    rows = trees.copy()
    r = rng.random(m)
    r[:40] = cumulative[rows[:40], rng.integers(0, n, 40)] / (1 - 1e-12)   # onto a running sum
    r[40:45], r[45:50] = 1.0 - 1e-16, 0.0
    z = rng.normal(size=(m, d))
    nodes = np.array([min(int(np.searchsorted(cumulative[row], v * (1 - 1e-12), "right")), n - 1)
                      for row, v in zip(rows, r)])
    assert 7 not in nodes and (nodes == n - 1).any() and (nodes == 0).any()
    mean = states[nodes] + offsets[nodes, trees] + shifts[rows]
    out = np.empty((m, d))
    draw_around_nodes(cumulative, shifts, rows, trees, r, z, states, offsets, log_sigma, 0.0, out)
    np.testing.assert_array_equal(out, mean + 0.0 * z)
    draw_around_nodes(cumulative, shifts, rows, trees, r, z, states, offsets, log_sigma, 0.7, out)
    np.testing.assert_allclose(out, mean + 0.7 * np.exp(log_sigma[nodes, trees]) * z, rtol=1e-13, atol=1e-13)


def test_compiled_gelu_over_many_rows_equals_one_call_per_row():
    """The kernels take a batch's message GELUs in one call (:func:`_gelu_with` with a shared
    scratch): each value's result depends on that value only, so it is bit for bit one call per
    64-value row, whatever the length and the scratch's previous contents."""
    from numba import njit

    from agents.tree.compiled import _gelu_into, _gelu_with

    @njit(cache=False)
    def whole(v, u):
        _gelu_with(v, u)

    @njit(cache=False)
    def per_row(a):
        for r in range(a.shape[0]):
            _gelu_into(a[r])

    values = _gelu_values()
    for rows in (1, 3, 7):
        a = values[:rows * 64].reshape(rows, 64).copy()
        flat = a.reshape(-1).copy()
        whole(flat[:rows * 64 - 3], np.full(rows * 64 + 4, np.nan))     # a length not a multiple of 4, dirty scratch
        per_row(a)
        assert np.array_equal(flat[:rows * 64 - 3], a.reshape(-1)[:rows * 64 - 3])


@pytest.mark.parametrize("task,min_nodes", [("maze2d", 200), ("arm", 60)])
def test_mixture_prior_is_the_torch_models_log_density(task, min_nodes):
    """``MixturePrior`` (``gnn-pick``'s prior where the picker has none): each candidate's logit is
    its log-density under the GNN's mixture: the torch model's ``-run_nll`` with the candidates as
    labels (temperature and sigma scale 1), and a brute-force sum over nodes and Gaussians at the
    shipped settings."""
    from agents.tree.prior import MixturePrior
    model, record = load_checkpoint(shipped_checkpoint("gnn", task), expected_kind="tree/gnn")
    model = model.double()
    settings = record["meta"]["sampler"]
    snapshots = grown(task, min_nodes)
    rng = np.random.default_rng(0)
    plain = MixturePrior(model)
    shipped = MixturePrior(model, settings["temperature"], settings["sigma_scale"])
    for obs in (snapshots[len(snapshots) // 2], snapshots[-1]):
        n, nodes, feats, parent, tid = prefix(obs, model)
        active = int(obs["active_tree"][0])
        low, high = obs["nodes"][:n].min(0), obs["nodes"][:n].max(0)
        cands = np.concatenate([low + (high - low) * rng.random((6, model.state_dim)),
                                obs["nodes"][:2] + 0.01]).astype(np.float64)
        knn = causal_knn(nodes, tid, model.knn, model.step_scale, model.periodic)
        K = len(cands)
        with torch.no_grad():
            nll = model.run_nll(nodes, feats, parent, tid, knn, torch.as_tensor(obs["start"], dtype=torch.float64)[None],
                                torch.as_tensor(obs["goal"], dtype=torch.float64)[None], torch.full((K,), n),
                                torch.full((K,), active), torch.as_tensor(cands))
        np.testing.assert_allclose(plain(obs, cands, active), -nll.numpy(), rtol=1e-7, atol=1e-6)
        ref = torch_mixture(model, obs, settings["temperature"])
        mu = obs["nodes"][:n].astype(np.float64) + ref["offset"][:, active] + ref["shift"]
        sigma = settings["sigma_scale"] * np.exp(ref["log_sigma"][:, active])
        periodic = model.periodic.numpy()
        brute = []
        for c in cands:
            total = 0.0
            for m in range(n):
                delta = c - mu[m]
                delta = np.where(periodic, (delta + np.pi) % (2 * np.pi) - np.pi, delta)
                total += ref["weights"][m] * np.prod(np.exp(-0.5 * (delta / sigma[m]) ** 2) / (np.sqrt(2 * np.pi) * sigma[m]))
            brute.append(np.log(total) if total > 0 else -np.inf)
        mine = shipped(obs, cands, active)
        finite = np.isfinite(brute)
        assert finite.sum() >= 2
        np.testing.assert_allclose(mine[finite], np.array(brute)[finite], rtol=1e-7, atol=1e-6)
