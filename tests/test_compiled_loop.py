"""The compiled planning loop (gnn_mp_envs.core.loop) against its reference, the Python planner: the same
samples grow the same trees, node for node; the k-d index against a brute-force scan; and an action
of K samples against K actions of one."""

from __future__ import annotations

import numpy as np
import pytest

from gnn_mp_envs.core.nearest import BUCKET, NearestIndex
from gnn_mp_envs.core.planners import make_planner
from gnn_mp_envs.core.problem import _nearest_row_loop
from gnn_mp_envs.registration import make_task


# ---------------------------------------------------------------------- the k-d index
@pytest.mark.parametrize("dim, periodic", [(2, (False, False)), (2, (True, False)), (7, (False,) * 7),
                                           (8, (False,) * 8)])
def test_the_index_answers_the_scans_first_argmin(dim, periodic):
    """Exactly the scan's answer (the first node at the least distance, the distance to the bit), with
    duplicate nodes, queries on nodes and on a lattice (ties between distinct nodes), as the tree grows."""
    rng = np.random.default_rng(dim)
    periodic = np.array(periodic)
    weights = rng.uniform(0.2, 2.0, dim)
    n = 1500
    states = np.round(rng.uniform(-3, 3, (n, dim)), 1)          # a lattice: many exact ties
    states[700:720] = states[100]                                # duplicates
    index = NearestIndex(n, 2, weights, periodic)
    tree_of = rng.integers(0, 2, n)
    checked = 0
    for i in range(n):
        index.insert(i, int(tree_of[i]), states)
        if i % 50 == 49:
            for q in np.concatenate([rng.uniform(-3.5, 3.5, (10, dim)), np.round(rng.uniform(-3, 3, (10, dim)), 1),
                                     states[rng.integers(0, i + 1, 5)]]):
                for tree in (0, 1):
                    rows = np.flatnonzero(tree_of[:i + 1] == tree)
                    if not len(rows):
                        continue
                    j, d = _nearest_row_loop(states[rows], q, weights, periodic)
                    assert index.nearest(q, tree, states) == (rows[j], d)
                    checked += 1
    assert checked > 1000


@pytest.mark.parametrize("case", ["equal nodes", "all periodic", "shuffled inserts", "one coordinate"])
def test_the_index_answers_the_scans_first_argmin_where_leaves_cannot_split(case):
    """Leaves that cannot split (more equal nodes than a block holds; only periodic coordinates), nodes
    inserted out of index order (and again), and nodes that differ on one coordinate only: the scan's
    answer, as the tree grows; an empty tree, a NaN and an infinite query as the scan answers them."""
    rng = np.random.default_rng(7)
    dim = 1 if case == "one coordinate" else 3
    n = 400
    states = rng.uniform(-3, 3, (n, dim))
    periodic = np.full(dim, case == "all periodic")
    if case == "equal nodes":
        states[50:50 + 3 * BUCKET] = states[7]                   # several blocks' worth of one state
    if case == "one coordinate":
        states = np.round(states, 1)                             # many equal values, no other coordinate
    weights = rng.uniform(0.5, 2.0, dim)
    order = rng.permutation(n) if case == "shuffled inserts" else np.arange(n)
    index = NearestIndex(n, 1, weights, periodic)
    assert index.nearest(np.zeros(dim), 0, states) == (-1, np.inf)
    for m, i in enumerate(order):
        index.insert(int(i), 0, states)
        if case == "shuffled inserts":
            index.insert(int(order[m // 2]), 0, states)             # again: nothing changes
        rows = np.sort(order[:m + 1])
        for q in np.concatenate([rng.uniform(-4, 4, (3, dim)), states[rng.choice(rows, 2)]]):
            j, d = _nearest_row_loop(states[rows], q, weights, periodic)
            assert index.nearest(q, 0, states) == (rows[j], d)
    for q in (np.full(dim, np.nan), np.full(dim, np.inf)):
        j, d = _nearest_row_loop(states, q, weights, periodic)
        got = index.nearest(q, 0, states)
        assert got[0] == j and (got[1] == d or (np.isnan(got[1]) and np.isnan(d)))


def test_an_index_grown_by_taking_a_smaller_one_answers_as_the_scan():
    """A larger index that takes a smaller one's nodes (the tree GNN's engine grows so), then more nodes:
    the scan's answers; ``clear`` empties it; one of a larger capacity or other trees is refused."""
    rng = np.random.default_rng(3)
    n, dim = 600, 5
    states = rng.uniform(-2, 2, (n, dim))
    weights, periodic = rng.uniform(0.5, 2.0, dim), np.zeros(dim, dtype=bool)
    small = NearestIndex(150, 2, weights, periodic)
    tree_of = rng.integers(0, 2, n)
    for i in range(150):
        small.insert(i, int(tree_of[i]), states)
    grown = NearestIndex(n, 2, weights, periodic)
    grown.take(small)
    for i in range(150, n):
        grown.insert(i, int(tree_of[i]), states)
    for q in rng.uniform(-2.5, 2.5, (200, dim)):
        for tree in (0, 1):
            rows = np.flatnonzero(tree_of == tree)
            j, d = _nearest_row_loop(states[rows], q, weights, periodic)
            assert grown.nearest(q, tree, states) == (rows[j], d)
    grown.clear()
    assert grown.nearest(states[0], 0, states) == (-1, np.inf)
    with pytest.raises(ValueError, match="at most its capacity"):
        small.take(grown)
    with pytest.raises(ValueError, match="as many trees"):
        NearestIndex(n, 1, weights, periodic).take(small)


def test_a_node_of_equal_distance_but_larger_square_still_wins_by_its_index():
    """Two nodes whose squared distances differ by rounding but whose distances are equal: the first
    one in insertion order wins, also when its square is the larger and the other node is met first."""
    rng = np.random.default_rng(0)
    angle = rng.uniform(0.3, 1.2, 20000)
    points = np.stack([np.cos(angle), np.sin(angle)], axis=1) * 1.7          # squares in [2, 4)
    square = points[:, 0] * points[:, 0] + points[:, 1] * points[:, 1]
    order = np.argsort(np.sqrt(square), kind="stable")
    pairs = [(order[k], order[k + 1]) for k in range(len(order) - 1)
             if np.sqrt(square[order[k]]) == np.sqrt(square[order[k + 1]]) and square[order[k]] != square[order[k + 1]]]
    assert len(pairs) > 10
    weights, periodic, x = np.ones(2), np.zeros(2, dtype=bool), np.zeros(2)
    for small, large in pairs[:50]:
        larger = points[large] if square[large] > square[small] else points[small]
        smaller = points[small] if square[large] > square[small] else points[large]
        # the root splits on the first coordinate; x's side holds the smaller square, met first
        states = np.array([[-0.1, 100.0], [-larger[0], larger[1]], smaller])
        index = NearestIndex(3, 1, weights, periodic)
        for i in range(3):
            index.insert(i, 0, states)
        j, d = _nearest_row_loop(states, x, weights, periodic)
        assert j == 1
        assert index.nearest(x, 0, states) == (j, d)


# ---------------------------------------------------------------------- the loop against the reference
CASES = [("maze2d", "rrt", 6), ("maze2d", "birrt", 6), ("panda-mbm", "birrt", 4), ("panda-mbm", "rrt", 2),
         ("ur5-mbm", "birrt", 3), ("fetch-mbm", "birrt", 2), ("maze2d", "birrt-balanced", 6),
         ("panda-mbm", "birrt-balanced", 3), ("ur5-mbm", "birrt-balanced", 2), ("fetch-mbm", "birrt-balanced", 2)]


def _grow(planner, samples, batch):
    """Feed ``samples`` ``batch`` at a time (``run``) or one at a time (``step``: batch 0) until solved or full."""
    if batch == 0:
        for s in samples:
            planner.step(s)
            if planner.solution is not None or planner.tree.full:
                break
        return
    at = 0
    while at < len(samples) and planner.solution is None and not planner.tree.full:
        at += planner.run(samples[at:at + batch]).consumed


@pytest.mark.parametrize("task, planner, problems", CASES)
def test_the_compiled_loop_grows_the_reference_trees(task, planner, problems):
    t = make_task(task)
    try:
        for i in range(problems):
            pa, pb = t.problem("test", i), t.problem("test", i)
            name, balance = planner.split("-")[0], planner.endswith("-balanced")
            a, b = make_planner(name, pa, 3000, balance), make_planner(name, pb, 3000, balance)
            assert b.compiled and a.balance == b.balance == balance
            rng = np.random.default_rng(i)
            samples = rng.uniform(pa.low, pa.high, (1500, pa.state_dim))
            samples[::9] = pa.goal                   # goal-biased samples: the goal tests and connections
            samples[5::11] = pa.start
            _grow(a, samples, 0)
            _grow(b, samples, 37)
            n = a.tree.size
            assert b.tree.size == n and a.iterations == b.iterations and a.active_tree == b.active_tree
            for name in ("states", "parent", "cost", "tree_id"):
                np.testing.assert_array_equal(getattr(a.tree, name)[:n], getattr(b.tree, name)[:n], err_msg=name)
            assert (pa.collision_checks, pa.edges_checked) == (pb.collision_checks, pb.edges_checked)
            assert (a.solution is None) == (b.solution is None)
            if a.solution is not None:
                np.testing.assert_array_equal(a.solution.states, b.solution.states)
                np.testing.assert_array_equal(a.solution.nodes, b.solution.nodes)
                assert a.solution.length == b.solution.length
    finally:
        t.close()


def test_a_planner_asks_about_compiling_the_loop_it_then_calls(monkeypatch):
    """A first use compiles the loop with the problem's steer and checks (a minute or more for the sphere
    checker): a planner, made ready to plan when it is made, asks then whether to say so about the loop its
    runs call, and its runs do not ask again for the same kernel."""
    import gnn_mp_envs.core.planners as planners
    t = make_task("maze2d")
    try:
        asked = []
        monkeypatch.setattr(planners, "announce_compilation", lambda dispatcher, *words: asked.append(dispatcher))
        planner = make_planner("rrt", t.problem("test", 0), 100)
        loop = planner._loop
        assert loop is not None and asked == [loop] and planner._table is not None
        calls = []
        planner._loop = lambda *args: calls.append(1) or loop(*args)
        planner.run(np.full((3, 2), 0.5))
        planner.run(np.full((3, 2), 0.4))
        assert asked == [loop] and calls == [1, 1]  # the same kernel: asked once per planner, its loop called
    finally:
        t.close()


def test_problems_without_compiled_checks_run_the_python_planner():
    for task, kwargs in (("pendulum", {}), ("panda-mbm", {"checker": "pybullet"})):
        t = make_task(task, **kwargs)
        p = t.problem("test", 0)
        planner = make_planner("rrt", p, 100)
        assert p.compiled_kernel() is None and not planner.compiled
        t.close()


# ---------------------------------------------------------------------- batches of samples in the env
@pytest.mark.parametrize("task, balance", [("maze2d", False), ("pendulum", False), ("arm", False),
                                           ("panda-mbm", False), ("ur5-mbm", False), ("fetch-mbm", False),
                                           ("panda-mbm", True), ("fetch-mbm", True)])
def test_64_samples_per_step_give_the_counters_of_one(task, balance):
    """The same uniform stream, 64 samples an action or one: the same runs, counter for counter (BiRRT's
    balanced trees too: a step's observation names the tree the next sample extends)."""
    from agents.samplers import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    extra = {"balance": True} if balance else {}
    one, batch = evaluation_env(task, **extra), evaluation_env(task, samples_per_step=64, **extra)
    sampler = load_sampler("uniform", task=task, seed=0)
    problems = {"fetch-mbm": 2, "arm": 2, "ur5-mbm": 3}.get(task, 4)
    for i in range(problems):
        a, b = plan_problem(one, sampler, i, 0).counters(), plan_problem(batch, sampler, i, 0).counters()
        for key in ("success", "nodes_expanded", "edges", "collision_checks", "iterations", "path_length"):
            assert a[key] == b[key], (task, i, key)
    one.close()
    batch.close()


def test_an_action_of_k_samples():
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401
    env = gym.make("GNNMP/Maze2DBiRRT-v0", split="test", samples_per_step=8)
    assert env.action_space.shape == (8, 2)
    obs, info = env.reset(options={"index": 0})
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert 1 <= info["samples_consumed"] <= 8 and info["iterations"] == info["samples_consumed"]
    assert reward == -1.0 * info["samples_consumed"] + (10.0 if terminated else 0.0)
    with pytest.raises(ValueError, match=r"action must have shape \(8, 2\)"):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match="must be finite"):
        env.step(np.full((8, 2), np.nan))
    env.close()
    for bad in (0, 2.5, 10**9):
        with pytest.raises(ValueError, match="samples_per_step must be"):
            gym.make("GNNMP/Maze2DRRT-v0", samples_per_step=bad)


def test_a_problem_that_overrides_a_method_in_python_runs_the_python_planner():
    """A subclass with its own goal test (tools.probes.goal_free) must be planned by the planner that calls
    it, not by a compiled loop that would test the goal its own way."""
    from tools.probes import goal_free
    t = make_task("maze2d")
    p = goal_free(t.problem("test", 0))
    planner = make_planner("rrt", p, 2000)
    assert p.compiled_kernel() is not None and not planner.compiled
    planner.run(np.repeat(p.goal[None], 5, axis=0))      # the goal itself, five times: never "reached"
    assert planner.solution is None and planner.iterations == 5


def test_a_sampler_that_overrides_act_is_batched_through_its_act():
    from agents.samplers.baselines import UniformSampler

    class Halved(UniformSampler):
        def act(self, obs):
            return super().act(obs) / 2

    obs = {"start": np.zeros(2, np.float32), "goal": np.ones(2, np.float32), "active_tree": np.zeros(1, np.int64),
           "node_features": np.zeros((4, 5), np.float32), "num_nodes": np.array([1])}
    halved, plain = Halved(np.zeros(2), np.ones(2), 3), UniformSampler(np.zeros(2), np.ones(2), 3)
    assert halved.samples_per_step == 1 and plain.samples_per_step == 64
    np.testing.assert_array_equal(halved.act_batch(obs, 4), plain.act_batch(obs, 4) / 2)


def test_balanced_trees_extend_the_smaller_tree_while_the_other_holds_twice_its_nodes():
    """The rule (VAMP's RRT-Connect, tree ratio 1), by hand: after extending tree ``a``, the next sample goes to
    the other tree unless that one holds at least twice ``a``'s nodes; without balance the trees alternate. A
    planned episode: the observation's ``active_tree`` after every step is that rule applied to its tree sizes."""
    from gnn_mp_envs.core.loop import next_tree
    rule = next_tree.py_func
    sizes = np.array([3, 6])
    assert rule(0, 1, sizes, True) == 0 and rule(1, 0, sizes, True) == 0         # 6 >= 2 * 3: tree 0 again
    assert rule(0, 1, np.array([3, 5]), True) == 1 and rule(0, 1, sizes, False) == 1
    assert rule(1, 0, np.array([1, 1]), True) == 0
    from agents.samplers import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env
    env = evaluation_env("fetch-mbm", "val", balance=True)
    sampler = load_sampler("uniform", task="fetch-mbm", seed=1)
    obs, _ = env.reset(seed=1, options={"index": 3})
    swaps = stays = 0
    for _ in range(400):
        extended = int(obs["active_tree"][0])
        obs, _, terminated, truncated, _ = env.step(sampler.act(obs))
        if terminated or truncated:
            break
        sizes = np.bincount(obs["node_features"][: int(obs["num_nodes"][0]), -1].astype(int), minlength=2)
        assert obs["active_tree"][0] == rule(extended, 1 - extended, sizes, True)
        swaps, stays = swaps + (obs["active_tree"][0] != extended), stays + (obs["active_tree"][0] == extended)
    assert swaps and stays                                       # both happened: the test saw the rule act
    env.close()


def test_balance_is_refused_where_there_is_one_tree():
    from gnn_mp_envs.evaluation import evaluation_env
    with pytest.raises(ValueError, match="balance applies to BiRRT's two trees"):
        evaluation_env("maze2d", planner="rrt", balance=True)
    with pytest.raises(ValueError, match="balance must be True or False"):
        evaluation_env("maze2d", planner="birrt", balance="yes")
    t = make_task("maze2d")
    with pytest.raises(ValueError, match="balance applies to BiRRT's two trees; planner 'rrt'"):
        make_planner("rrt", t.problem("test", 0), 100, True)
    t.close()
