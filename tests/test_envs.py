"""The Gymnasium environments: API checkers, determinism, validity of paths, bad input."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

from gnn_mp_envs.core.problem import InvalidProblemError
from gnn_mp_envs.envs.tree_env import TreePlanningEnv
from gnn_mp_envs.tasks.maze2d import Maze2DTask
from gnn_mp_envs.rollout import rollout
from tests.helpers import run_uniform, uniform_policy

ENV_IDS = ["GNNMP/Maze2DRRT-v0", "GNNMP/Maze2DBiRRT-v0", "GNNMP/PendulumRRT-v0"]


def run_episode(env, seed, rng_seed=0, max_steps=100_000):
    return run_uniform(env, seed=seed, rng_seed=rng_seed, max_steps=max_steps)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gymnasium_checker(env_id):
    env = gym.make(env_id, max_nodes=300)
    gym_check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sb3_checker(env_id):
    from stable_baselines3.common.env_checker import check_env
    check_env(gym.make(env_id, max_nodes=300).unwrapped, warn=False)


def checker_warnings(check, env) -> set[str]:
    """The kinds of warning a checker gives (see docs/environments.md, "What the checkers say")."""
    import warnings
    kinds = {"infinity": "infinite bounds", "normalized": "action box not [-1, 1]",
             "unconventional shape": "2-D observation entries"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check(env)
    found = set()
    for w in caught:
        text = str(w.message)
        matched = [kind for key, kind in kinds.items() if key in text]
        assert matched or "is a wrapper" in text, f"an undocumented checker warning: {text[:200]}"
        found.update(matched)
    return found


@pytest.mark.parametrize("task, env_id, normalized", [("maze2d", "GNNMP/Maze2DRRT-v0", True),
                                                      ("pendulum", "GNNMP/PendulumRRT-v0", False),
                                                      ("arm", "GNNMP/ArmBiRRT-v0", False)])
def test_the_checkers_warn_about_exactly_what_the_docs_explain(task, env_id, normalized):
    """The warnings of Gymnasium's and SB3's checkers are the three documented,
    by-design ones; the only unbounded key is ``obstacles``; make_rl_env's envs have the [-1, 1]
    action box RL libraries want."""
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    from gnn_mp_envs.envs.wrappers import make_rl_env
    env = gym.make(env_id, max_nodes=300, disable_env_checker=True)
    unbounded = [k for k, space in env.observation_space.spaces.items()
                 if hasattr(space, "low") and not (np.isfinite(space.low).all() and np.isfinite(space.high).all())]
    assert unbounded == ["obstacles"]
    gym_kinds = {"infinite bounds"} | (set() if normalized else {"action box not [-1, 1]"})
    assert checker_warnings(lambda e: gym_check_env(e, skip_render_check=True), env.unwrapped) == gym_kinds
    assert checker_warnings(lambda e: sb3_check_env(e, skip_render_check=True), env.unwrapped) == {
        "action box not [-1, 1]", "2-D observation entries"}
    env.close()
    rl_env = make_rl_env(task)
    assert checker_warnings(lambda e: sb3_check_env(e, skip_render_check=True), rl_env) == {"2-D observation entries"}
    rl_env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_torchrl_specs(env_id):
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs
    check_env_specs(GymEnv(env_id, max_nodes=300), seed=0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_same_seed_same_observations(env_id):
    env_a, env_b = gym.make(env_id, max_nodes=2000), gym.make(env_id, max_nodes=2000)
    obs_a, _, _ = run_episode(env_a, seed=7, max_steps=200)
    obs_b, _, _ = run_episode(env_b, seed=7, max_steps=200)
    for k in obs_a:
        np.testing.assert_array_equal(obs_a[k], obs_b[k])
    obs_c, _, _ = run_episode(env_a, seed=8, max_steps=200)
    assert not np.array_equal(obs_a["goal"], obs_c["goal"])


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_observation_matches_tree(env_id):
    """The in-place observation equals one rebuilt from the planner's tree."""
    env = gym.make(env_id).unwrapped
    obs, info, _ = run_episode(env, seed=3, max_steps=300)
    tree, problem = env.planner.tree, env.problem
    n = len(tree)
    assert obs["num_nodes"][0] == n and obs["mask"].sum() == n and not obs["mask"][n:].any()
    np.testing.assert_allclose(obs["nodes"][:n], tree.states[:n], rtol=1e-6, atol=1e-6)
    d = problem.state_dim
    np.testing.assert_allclose(obs["node_features"][:n, :d], problem.difference(problem.start, tree.states[:n]), atol=1e-5)
    np.testing.assert_allclose(obs["node_features"][:n, d:2 * d], problem.difference(problem.goal, tree.states[:n]), atol=1e-5)
    np.testing.assert_array_equal(obs["node_features"][:n, 2 * d], tree.tree_id[:n])
    np.testing.assert_array_equal(obs["parent"][:n], tree.parent[:n])
    assert info["nodes_expanded"] == n


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_returned_path_is_valid(env_id):
    env = gym.make(env_id).unwrapped
    for seed in range(5):
        _, info, terminated = run_episode(env, seed=seed, rng_seed=seed)
        assert terminated and info["is_success"]
        problem = env.problem
        path = info["path"]
        assert np.allclose(path[0], problem.start) and problem.in_goal(path[-1])
        assert problem.path_valid(path, info["path_controls"])
        assert np.isfinite(info["path_length"]) and info["path_length"] > 0
        assert info["collision_checks"] >= info["edges"] >= 1


def test_maze_path_is_collision_free_when_densely_resampled():
    env = gym.make("GNNMP/Maze2DRRT-v0").unwrapped
    _, info, _ = run_episode(env, seed=11)
    path, maze = info["path"], env.problem.maze
    t = np.linspace(0, 1, 200)[:, None]
    for a, b in zip(path[:-1], path[1:]):
        assert maze.is_free(a + t * (b - a)).all()


@pytest.mark.parametrize("bad", [np.array([np.nan, 0.5]), np.array([0.5, np.inf]), np.zeros(3), np.zeros((1, 2))])
def test_bad_actions_raise_value_error(bad):
    env = gym.make("GNNMP/Maze2DRRT-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(bad)


def test_the_compiled_observation_row_is_numpys_row_bit_for_bit():
    """Where a problem's ``difference`` is the plain ``a - b`` (maze2d, the arms), ``GraphObservation.add``
    writes a node's row in one compiled pass: every array of the observation equals the numpy path's
    (the float64 differences rounded to float32) over whole BiRRT and RRT runs; the pendulum's wrapped
    differences keep the numpy path."""
    from gnn_mp_envs.envs.observation import GraphObservation
    for env_id, kwargs in (("GNNMP/Maze2DRRT-v0", {}), ("GNNMP/Maze2DBiRRT-v0", {}),
                           ("GNNMP/PendulumRRT-v0", {"max_nodes": 300})):
        env = gym.make(env_id, **kwargs).unwrapped
        obs, _ = env.reset(seed=3)
        assert (env._obs._write is None) == (env_id == "GNNMP/PendulumRRT-v0")
        sampler = np.random.default_rng(3)
        for _ in range(150):
            obs, _, terminated, truncated, _ = env.step(sampler.uniform(env._low, env._high).astype(np.float32))
            if terminated or truncated:
                break
        oracle = GraphObservation(env.state_dim, env.max_nodes, env._obs.obstacles.shape)
        oracle.reset(env.problem, env.planner.tree, env.task.obstacle_rows(env.problem))
        oracle._write = None
        oracle.num_nodes[0] = 0
        for i in range(len(env.planner.tree)):
            oracle.add(env.planner.tree, i)
        oracle.active_tree[0] = env.planner.active_tree
        got, want = env._obs.as_dict(), oracle.as_dict()
        assert len(env.planner.tree) > 20
        for key in want:
            assert got[key].dtype == want[key].dtype and np.array_equal(got[key], want[key]), (env_id, key)
        env.close()


def test_the_compiled_action_clip_is_numpys_clip_bit_for_bit():
    """``step`` clips a sampler's float array in one compiled pass (``compiled_clip_finite``; the same
    loop in Python without numba): the values of ``np.minimum(np.maximum(action, low), high)`` in
    float64, for float32 and float64 actions inside, on and beyond the bounds, and False for any NaN
    or infinite entry (the step then refuses the action)."""
    from gnn_mp_envs.envs.tree_env import compiled_clip_finite
    clip = compiled_clip_finite()
    assert clip is not None
    rng = np.random.default_rng(5)
    for trial in range(2000):
        d = int(rng.integers(1, 8))
        low = rng.uniform(-3, 0, d)
        high = low + rng.uniform(0, 3, d)
        action = rng.uniform(low - 1, high + 1)
        if trial % 3 == 0:
            action[rng.integers(d)] = rng.choice([low[0], high[0], -0.0, 0.0])
        action = action.astype(np.float32 if trial % 2 else np.float64)
        bad = trial % 5 == 0
        if bad:
            action[rng.integers(d)] = rng.choice([np.nan, np.inf, -np.inf])
        for loop in (clip, compiled_clip_finite.__wrapped__):
            out = np.full(d, 7.0)
            ok = loop(action, low, high, out)
            assert ok is not bad, trial
            if not bad:
                np.testing.assert_array_equal(out, np.minimum(np.maximum(action.astype(np.float64), low), high))


def test_out_of_bounds_actions_are_clipped():
    env = gym.make("GNNMP/Maze2DRRT-v0").unwrapped
    env.reset(seed=0)
    env.step(np.array([5.0, -5.0], dtype=np.float32))
    n = len(env.planner.tree)
    assert np.all(env.planner.tree.states[:n] >= 0.0) and np.all(env.planner.tree.states[:n] <= 1.0)


def test_given_problem_is_planned_and_bad_problems_raise():
    env = gym.make("GNNMP/Maze2DRRT-v0").unwrapped
    spec = {"start": [0.1, 0.5], "goal": [0.9, 0.5], "walls": [[0.45, 0.0, 0.55, 0.45], [0.45, 0.55, 0.55, 1.0]]}
    obs, _ = env.reset(options={"problem": spec})
    np.testing.assert_allclose(obs["start"], [0.1, 0.5])
    with pytest.raises(InvalidProblemError, match="collision"):
        env.reset(options={"problem": dict(spec, start=[0.5, 0.2])})
    with pytest.raises(InvalidProblemError, match="shape"):
        env.reset(options={"problem": dict(spec, start=[0.1, 0.5, 0.0])})
    with pytest.raises(InvalidProblemError, match="start"):
        env.reset(options={"problem": {"goal": [0.9, 0.5]}})


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="planner"):
        TreePlanningEnv(task="maze2d", planner="prm")
    with pytest.raises(ValueError, match="task"):
        TreePlanningEnv(task="nope")
    with pytest.raises(ValueError, match="supports planners"):
        TreePlanningEnv(task="pendulum", planner="birrt")
    with pytest.raises(ValueError, match="max_nodes"):
        TreePlanningEnv(task="maze2d", max_nodes=0)
    with pytest.raises(ValueError, match="max_steps"):
        TreePlanningEnv(task="maze2d", max_steps=0)


def test_truncation_at_node_budget():
    env = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=20)
    _, info, terminated = run_uniform(env, seed=0, max_steps=10_000)
    assert not terminated and env.unwrapped.planner.tree.full
    assert info["nodes_expanded"] == 20 and not info["is_success"]


def test_reward_is_step_penalty_plus_success_bonus():
    env = gym.make("GNNMP/Maze2DRRT-v0", step_penalty=1.0, success_reward=10.0)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    rewards = []
    while True:
        _, r, terminated, truncated, _ = env.step(rng.uniform(0, 1, 2).astype(np.float32))
        rewards.append(r)
        if terminated or truncated:
            break
    assert terminated and rewards[-1] == 9.0 and set(rewards[:-1]) == {-1.0}


@pytest.mark.parametrize("env_id", ["GNNMP/Maze2DBiRRT-v0", "GNNMP/PendulumRRT-v0"])
def test_render_draws_an_image(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    run_episode(env, seed=0)
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 5  # not a blank canvas


def test_test_split_is_fixed_and_disjoint_from_train():
    task = Maze2DTask()
    a, b = task.problem("test", 4), task.problem("test", 4)
    np.testing.assert_array_equal(a.start, b.start)
    np.testing.assert_array_equal(a.maze.walls, b.maze.walls)
    assert not np.array_equal(task.problem("train", 4).start, a.start)


def _solve_rate(env_id, n, seed0=0):
    env = gym.make(env_id, split="test").unwrapped
    solved = sum(rollout(env, uniform_policy(env, seed0 + i), options={"index": i}).success for i in range(n))
    return solved / n


def test_uniform_rrt_solves_heldout_maze2d():
    """At least 95% of held-out Maze2D problems within 5,000 nodes."""
    assert _solve_rate("GNNMP/Maze2DRRT-v0", 100) >= 0.95


def test_uniform_rrt_solves_heldout_pendulum():
    """At least 90% of held-out pendulum problems within 20,000 nodes."""
    assert _solve_rate("GNNMP/PendulumRRT-v0", 30) >= 0.90


@pytest.mark.parametrize("env_id,problem", [
    ("GNNMP/Maze2DRRT-v0", {"start": [0.1, 0.5], "goal": [0.9, 0.5], "wals": [[0.45, 0.0, 0.55, 1.0]]}),
    ("GNNMP/PendulumRRT-v0", {"start": [0.0, 0.0], "goal": [3.1, 0.0], "torque": 5.0}),
])
def test_a_typo_in_a_problem_dict_is_refused(env_id, problem):
    """A misspelt key would plan another problem than the one meant (an empty square, here): refused."""
    from gnn_mp_envs.core.problem import InvalidProblemError
    env = gym.make(env_id, disable_env_checker=True)
    with pytest.raises(InvalidProblemError, match="unknown key"):
        env.reset(options={"problem": problem})


def test_compiled_pendulum_steer_is_the_python_steer_bit_for_bit():
    """The numba steer (what the env runs when numba is installed, as in this test environment) gives
    the Python steer's edge, control and collision-check count exactly: random and wrapped states,
    targets far outside the box, speeds at the validity bound, two torque limits (non-finite samples
    never reach the steer: the env refuses them)."""
    from gnn_mp_envs.tasks.pendulum import MAX_SPEED, PendulumProblem, compiled_steer_loop
    assert compiled_steer_loop() is not None
    rng = np.random.default_rng(7)
    special = [0.0, np.pi, -np.pi, np.nextafter(np.pi, 0), MAX_SPEED, -MAX_SPEED, np.nextafter(MAX_SPEED, 9)]
    outcomes = set()
    for torque in (1.962, 2.943):
        problem = PendulumProblem(np.zeros(2), np.array([np.pi, 0.0]), torque)
        for k in range(3000):
            if k % 3 == 0:
                a, b = rng.uniform([-np.pi, -8], [np.pi, 8]), rng.uniform([-np.pi, -8], [np.pi, 8])
            elif k % 3 == 1:
                a, b = rng.uniform([-12, -9], [12, 9]), rng.uniform([-20, -30], [20, 30])
            else:
                a, b = rng.choice(special, 2), rng.choice(special, 2)
            before = problem.collision_checks
            fast = problem.steer(a, b)
            fast_checks = problem.collision_checks - before
            slow = problem.steer_python(a, b)
            assert problem.collision_checks - before - fast_checks == fast_checks
            assert (fast is None) == (slow is None), (a, b)
            outcomes.add(fast is None)
            if fast is not None:
                assert fast.state.tobytes() == slow.state.tobytes() and fast.cost == slow.cost
                assert fast.control.tobytes() == slow.control.tobytes(), (a, b)
    assert outcomes == {True, False}      # both valid and blocked edges were compared


@pytest.mark.parametrize("env_id", ["GNNMP/PandaMBM-v0", "GNNMP/ArmBiRRT-v0"])
def test_an_empty_scene_name_is_refused_not_the_default(env_id):
    """``scene=""`` is an unknown scene (it used to fall back to the split's default scene)."""
    import gymnasium as gym
    with pytest.raises(ValueError, match="unknown scene ''"):
        gym.make(env_id, scene="", disable_env_checker=True)


@pytest.mark.parametrize("bad", ["0.5", True, float("nan"), -1.0, None])
def test_a_pendulum_problem_dict_takes_a_number_as_max_torque(bad):
    """``max_torque`` of a hand-made pendulum problem is a finite positive number: a string or a
    bool (which float() would take) is refused in one line."""
    import gymnasium as gym

    from gnn_mp_envs.core.problem import InvalidProblemError
    env = gym.make("GNNMP/PendulumRRT-v0", disable_env_checker=True)
    with pytest.raises(InvalidProblemError, match="max_torque"):
        env.reset(options={"problem": {"start": [3.0, 0.0], "goal": [0.0, 0.0], "max_torque": bad}})
    env.reset(options={"problem": {"start": [3.0, 0.0], "goal": [0.0, 0.0], "max_torque": 2}})
