"""Planner core: tree store, RRT/BiRRT bookkeeping and exact maze geometry."""

import numpy as np
import pytest

from gnn_mp_envs.core.planners import BiRRT, RRT, make_planner
from gnn_mp_envs.core.tree import TreeStore
from gnn_mp_envs.tasks.maze2d import Maze2DProblem, Maze2DTask, MazeMap
from gnn_mp_envs.tasks.pendulum import PendulumTask


class _Euclid:
    nn_boxsize = None

    def distance(self, s, x):
        return np.linalg.norm(s - x, axis=-1)

    def nearest_row(self, s, x):
        d = self.distance(s, x)
        return int(d.argmin()), float(d.min())

    def nn_embed(self, s):
        return s


@pytest.mark.parametrize("n", [400, 5000])  # below and above the k-d tree threshold
def test_nearest_matches_brute_force_per_tree(n):
    rng = np.random.default_rng(0)
    store = TreeStore(n, 3, num_trees=2)
    metric = _Euclid()
    for k in range(n):
        store.add(rng.random(3), -1, int(rng.integers(2)))
        if k % 97 == 0:  # interleave queries with inserts, as a planner does
            x = rng.random(3)
            members = np.flatnonzero(store.tree_id[:store.size] == 0)
            assert store.nearest(x, 0, metric) == members[np.argmin(metric.distance(store.states[members], x))]
    for _ in range(50):
        x = rng.random(3)
        for t in (0, 1):
            members = np.flatnonzero(store.tree_id[:store.size] == t)
            expected = members[np.argmin(metric.distance(store.states[members], x))]
            assert store.nearest(x, t, metric) == expected


def test_a_small_trees_compiled_nearest_node_is_the_first_argmin_of_the_problems_distance():
    """Below the k-d tree's threshold, a problem naming its metric (the pendulum: weighted, one angle
    wrapped) gets its nearest node in one compiled call: per tree, the first node of least
    ``problem.distance`` (the brute-force oracle), also among exact ties, and the node the scan through
    ``problem.nearest_row`` picks."""
    problem = PendulumTask().problem("test", 0)
    rng = np.random.default_rng(4)
    store = TreeStore(900, 2, num_trees=2)
    assert store._scan is not None
    for k in range(900):
        x = problem.sample_uniform(rng) if k % 7 else store.states[int(rng.integers(max(store.size, 1)))].copy()
        store.add(x, -1, int(rng.integers(2)))      # every 7th a copy of an earlier node: ties
    for _ in range(300):
        x = problem.sample_uniform(rng)
        x[0] = rng.choice([-np.pi + 1e-3, np.pi - 1e-3, x[0]])
        for t in (0, 1):
            members = np.flatnonzero(store.tree_id[:store.size] == t)
            expected = members[int(np.argmin(problem.distance(store.states[members], x)))]
            got = store.nearest(x, t, problem)
            assert type(got) is int and got == expected
            scan, store._scan = store._scan, None
            assert store.nearest(x, t, problem) == got
            store._scan = scan


def test_nearest_respects_pendulum_angle_wrap():
    problem = PendulumTask().problem("test", 0)
    rng = np.random.default_rng(2)
    store = TreeStore(3000, 2)
    for _ in range(3000):
        store.add(problem.sample_uniform(rng), -1, 0)
    for _ in range(200):
        x = problem.sample_uniform(rng)
        x[0] = rng.choice([-np.pi + 1e-3, np.pi - 1e-3, x[0]])
        d = problem.distance(store.states[:3000], x)
        assert d[store.nearest(x, 0, problem)] == pytest.approx(d.min())


@pytest.mark.parametrize("task", [PendulumTask(), Maze2DTask()], ids=["pendulum", "maze2d"])
def test_nearest_row_is_numpy_argmin_of_distance_bit_for_bit(task):
    """The planner's nearest scan (``Problem.nearest_row``: compiled where the problem names its metric,
    as the pendulum does; the same loop in Python without numba) returns numpy's first argmin of
    ``distance`` and that distance exactly: ties (repeated rows), float32 queries as samplers send,
    queries on a row, and angle differences on the wrap's edges (0, +-pi, +-2 pi)."""
    from gnn_mp_envs.core.problem import compiled_nearest_row
    problem = task.problem("val", 0)
    if task.name == "maze2d":
        # maze2d declares its plain Euclidean metric as the loop's unweighted case (its exact k-d index and
        # the compiled planning loop use it)
        np.testing.assert_array_equal(problem.nearest_metric[0], np.ones(2))
        assert not problem.nearest_metric[1].any()
    assert problem.nearest_metric is not None and compiled_nearest_row() is not None
    python_loop = compiled_nearest_row.__wrapped__
    rng = np.random.default_rng(3)
    for trial in range(3000):
        n = int(rng.integers(1, 300))
        states = rng.uniform(problem.low, problem.high, (n, problem.state_dim))
        if trial % 3 == 0:
            states[rng.integers(n, size=n // 2)] = states[0]
        x = rng.uniform(problem.low, problem.high)
        if trial % 4 == 0:
            x = states[int(rng.integers(n))].copy()
        if trial % 7 == 0 and task.name == "pendulum":      # differences of exactly 0, +-pi, +-2 pi
            x[0] = rng.choice([-np.pi, 0.0, np.pi])
            states[:, 0] = rng.choice([-np.pi, 0.0, np.pi, np.nextafter(np.pi, 0)], n)
        if trial % 2:
            x = x.astype(np.float32)
        d = problem.distance(states, x)
        expected = (int(d.argmin()), float(d[d.argmin()]))
        assert problem.nearest_row(states, x) == expected, trial
        assert python_loop(states, x, *problem.nearest_metric) == expected, trial


def test_cost_to_come_accumulates_along_parents():
    store = TreeStore(10, 2)
    a = store.add(np.zeros(2), -1, 0)
    b = store.add(np.ones(2), a, 0, cost=2.0)
    c = store.add(np.ones(2) * 2, b, 0, cost=3.0)
    assert store.cost[c] == pytest.approx(5.0)
    assert store.path_to_root(c) == [a, b, c]


def test_a_solutions_nodes_are_the_walks_up_both_trees():
    """``path_nodes`` (compiled) against walks in Python over a random forest: from a root down to ``head``,
    then from ``tail``'s parent up to its root (``tail`` itself left out: BiRRT's meeting node)."""
    from gnn_mp_envs.core.tree import path_nodes

    rng = np.random.default_rng(3)
    parent = np.full(300, -1, dtype=np.int64)
    for i in range(300):
        if i >= 2 and rng.random() > 0.02:          # a few more roots than the two trees'
            parent[i] = rng.integers(0, i)

    def up(i: int) -> list[int]:
        out = []
        while i >= 0:
            out.append(i)
            i = int(parent[i])
        return out

    for _ in range(200):
        head, tail = (int(v) for v in rng.integers(0, 300, size=2))
        assert path_nodes(parent, head, -1).tolist() == up(head)[::-1]
        assert path_nodes(parent, head, tail).tolist() == up(head)[::-1] + up(tail)[1:]
    assert path_nodes(parent, 0, 1).tolist() == [0]       # two roots meeting: the second is left out


def test_segment_test_agrees_with_dense_sampling():
    rng = np.random.default_rng(1)
    maze = MazeMap(walls=[[0.4, 0.0, 0.45, 0.6], [0.1, 0.7, 0.3, 0.75]], blobs=[[0.7, 0.3, 0.08]])
    p = rng.random((2000, 2))
    q = np.clip(p + rng.normal(0, 0.15, (2000, 2)), 0, 1)
    exact = maze.segments_free(p, q)
    t = np.linspace(0, 1, 400)
    dense = np.array([maze.is_free(a + t[:, None] * (b - a)).all() for a, b in zip(p, q)])
    # Dense sampling can only miss a hit, never invent one.
    assert not np.any(exact & ~dense)
    assert np.mean(exact == dense) > 0.995


def test_axis_parallel_segments_hit_walls():
    maze = MazeMap(walls=[[0.4, 0.0, 0.6, 1.0]])
    p = np.array([[0.1, 0.5], [0.1, 0.5], [0.5, 0.1]])
    q = np.array([[0.9, 0.5], [0.3, 0.5], [0.5, 0.9]])
    assert maze.segments_free(p, q).tolist() == [False, True, False]


def solve_uniform(planner, problem, seed=0, on_step=None):
    """Drive ``planner`` with uniform samples until it finds a path."""
    rng = np.random.default_rng(seed)
    while not planner.solved:
        if on_step is not None:
            on_step(planner)
        planner.step(problem.sample_uniform(rng))
    return planner.solution


def test_rrt_path_is_valid_and_connects_start_to_goal():
    problem = Maze2DTask().problem("test", 3)
    sol = solve_uniform(RRT(problem, 5000), problem)
    assert np.allclose(sol.states[0], problem.start)
    assert np.allclose(sol.states[-1], problem.goal)
    assert problem.path_valid(sol.states)
    assert sol.length == pytest.approx(np.linalg.norm(np.diff(sol.states, axis=0), axis=1).sum())


def test_birrt_alternates_trees_and_joins_them():
    problem = Maze2DTask().problem("test", 5)
    active = []
    sol = solve_uniform(BiRRT(problem, 5000), problem, on_step=lambda pl: active.append(pl.active_tree))
    assert active[:4] == [0, 1, 0, 1]
    assert np.allclose(sol.states[0], problem.start) and np.allclose(sol.states[-1], problem.goal)
    steps = np.linalg.norm(np.diff(sol.states, axis=0), axis=1)
    assert np.all(steps > 0) and np.all(steps <= problem.step_size + 1e-9)
    assert sol.length == pytest.approx(steps.sum())
    assert problem.path_valid(sol.states)


def test_birrt_rejects_kinodynamic_problems():
    with pytest.raises(ValueError, match="kinodynamic"):
        make_planner("birrt", PendulumTask().problem("test", 0), 100)


def test_blocked_motion_adds_no_node_and_counts_checks():
    maze = MazeMap(walls=[[0.45, 0.0, 0.55, 1.0]])  # no gap: unsolvable
    problem = Maze2DProblem(maze, [0.43, 0.5], [0.8, 0.5])
    planner = RRT(problem, 100)
    result = planner.step(np.array([0.8, 0.5]))  # the first step of 0.05 would enter the wall
    assert result.added == [] and len(planner.tree) == 1
    assert problem.collision_checks == 1 and problem.edges_checked == 1
    result = planner.step(np.array([0.43, 0.9]))  # along the wall: free
    assert len(result.added) == 1


def test_birrt_connects_when_the_other_tree_already_holds_the_target():
    """Sampling a root of the other tree must join the trees, not stall on a zero-length motion."""
    problem = Maze2DProblem(MazeMap(), [0.5, 0.5], [0.53125, 0.5])
    planner = BiRRT(problem, 50)
    for _ in range(4):
        target = problem.goal if planner.active_tree == 0 else problem.start
        if planner.step(target.copy()).solved:
            break
    assert planner.solved
    np.testing.assert_allclose(planner.solution.states[[0, -1]], [problem.start, problem.goal])
    assert planner.solution.length == pytest.approx(0.03125)


def test_pendulum_edges_reintegrate_to_stored_states():
    problem = PendulumTask().problem("test", 0)
    sol = solve_uniform(RRT(problem, 20000), problem)
    assert problem.in_goal(sol.states[-1])
    assert problem.path_valid(sol.states, sol.controls)
    # Tampering with a control breaks the re-check: the check is not vacuous.
    bad = sol.controls.copy()
    bad[1] = -bad[1] if bad[1, 0] != 0 else bad[1] + 1.0
    assert not problem.path_valid(sol.states, bad)


def test_one_segment_test_equals_the_vectorised_one():
    """MazeMap.segment_free (plain floats, the planner's per-edge test) gives segments_free's answer
    on random, axis-parallel, degenerate and wall-grazing segments of 100 held-out maps."""
    from gnn_mp_envs.tasks.maze2d import Maze2DTask
    task, rng = Maze2DTask(), np.random.default_rng(0)
    for i in range(100):
        maze = task.problem("test", i).maze
        p = rng.uniform(-0.05, 1.05, (200, 2))
        q = p + rng.normal(0.0, 0.06, (200, 2))
        q[:40, 0] = p[:40, 0]                                   # vertical
        q[40:60] = p[40:60]                                     # a point
        w = maze.walls[i % len(maze.walls)]
        p[60:80], q[60:80] = w[:2], w[2:]                       # corner to corner
        p[80:100], q[80:100] = [w[0], -0.01], [w[0], 1.01]      # along a wall's face
        # ending just short of or just inside a face, or running beside it, by 1e-12 .. 1e-8 (the bounding-box
        # rejection's margin is 1e-9): the answers near the rounding scale must not change
        gap = 10.0 ** rng.uniform(-12, -8, 100)
        y = rng.uniform(w[1], w[3], 100)
        p[100:150] = np.column_stack([w[0] - 0.03 * rng.random(50), y[:50]])
        q[100:150] = np.column_stack([w[0] + gap[:50] * rng.choice([-1, 1], 50), y[:50] + rng.normal(0, 0.01, 50)])
        p[150:200] = np.column_stack([w[0] - gap[50:], w[1] - 0.02 * rng.random(50)])
        q[150:200] = np.column_stack([w[0] - gap[50:] * rng.random(50), w[3] + 0.02 * rng.random(50)])
        want = maze.segments_free(p, q)
        assert [maze.segment_free(a, b) for a, b in zip(p, q)] == want.tolist()
        assert 0 < want.sum() < len(want)


def test_maze_pair_distance_is_the_base_metric_bit_for_bit():
    from gnn_mp_envs.core.problem import Problem
    from gnn_mp_envs.tasks.maze2d import Maze2DTask
    problem, rng = Maze2DTask().problem("test", 0), np.random.default_rng(1)
    a, b = rng.uniform(0, 1, (5000, 2)), rng.uniform(0, 1, (5000, 2))
    base = [float(Problem.distance(problem, x[None], y)[0]) for x, y in zip(a, b)]
    assert [problem.pair_distance(x, y) for x, y in zip(a, b)] == base
    # rows against one state (the nearest-node scan) and one state against one
    assert problem.distance(a, b[0]).tolist() == Problem.distance(problem, a, b[0]).tolist()
    assert float(problem.distance(a[0], b[0])) == float(Problem.distance(problem, a[0], b[0]))


def test_pendulum_steer_in_floats_is_the_vectorised_rule_bit_for_bit():
    """PendulumProblem.steer (plain floats) against the rule written with the problem's numpy parts:
    rollout every torque, argmin of distance(ends, target), is_state_valid of the kept states in order."""
    from gnn_mp_envs.tasks.pendulum import PendulumProblem, rollout
    problem, rng = PendulumProblem(np.zeros(2), np.array([3.0, 0.2])), np.random.default_rng(3)
    blocked = 0
    for i in range(2000):
        a = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-8.5, 8.5)])    # some starts already too fast
        b = a.copy() if i % 7 == 0 else np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-8, 8)])
        traj = rollout(a[0], a[1], problem._controls)
        best = int(np.argmin(problem.distance(traj[-1], b)))
        valid = problem.is_state_valid(traj[:, best])
        bad = np.flatnonzero(~valid)
        checks = problem.collision_checks
        edge = problem.steer(a, b)
        assert problem.collision_checks - checks == (bad[0] + 1 if bad.size else len(valid))
        if bad.size:
            blocked += 1
            assert edge is None
        else:
            assert np.array_equal(edge.state, problem.normalize(traj[-1, best]))
            assert edge.control.tolist() == [problem._controls[best]]
    assert 0 < blocked < 2000


def test_pendulum_distance_and_goal_test_are_the_difference_rule_bit_for_bit():
    from gnn_mp_envs.tasks.pendulum import PendulumProblem
    rng = np.random.default_rng(5)
    problem = PendulumProblem(np.zeros(2), np.array([3.0, 0.2]))
    states = np.column_stack([rng.uniform(-np.pi, np.pi, 4000), rng.uniform(-8, 8, 4000)])
    states[:200] = problem.goal + rng.uniform(-0.2, 0.2, (200, 2))      # around the goal box's edges
    x = states[7]
    want = np.sqrt(np.einsum("...i,...i->...", problem.difference(states, x) * problem._weights,
                             problem.difference(states, x) * problem._weights))
    assert problem.distance(states, x).tolist() == want.tolist()
    assert float(problem.distance(states[3], x)) == float(want[3])
    d = problem.difference(states, problem.goal)
    inside = (np.abs(d[:, 0]) <= 0.15) & (np.abs(d[:, 1]) <= 0.5)
    assert [problem.in_goal(s) for s in states] == inside.tolist() and 0 < inside.sum() < 200
