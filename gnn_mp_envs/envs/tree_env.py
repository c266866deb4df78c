"""One Gymnasium environment for every planning task: the growing tree is the observation,
the next sample is the action."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gnn_mp_envs.core.planners import PLANNERS, make_planner
from gnn_mp_envs.core.problem import InvalidProblemError, Problem
from gnn_mp_envs.envs.observation import GraphObservation, keep_freed_heap, observation_space
from gnn_mp_envs.registration import make_task, task_spec
from gnn_mp_envs.tasks.base import SPLIT_SEEDS

class TreePlanningEnv(gym.Env):
    """Sampling-based planning as an MDP: each step is one RRT/BiRRT iteration.

    ## Description
    ``reset`` draws a planning problem (start, goal, obstacles) from the task family and
    roots the tree(s) at the start (RRT) or at start and goal (BiRRT). Each ``step``
    takes the next sample as its action and runs one planner iteration with it:
    nearest node -> steer toward the sample -> counted validity checks -> add node
    (BiRRT: greedily connect the other tree to the new node, then swap trees) -> goal
    test. Any sampler, uniform, learned or an RL policy, drives the same planner.

    ## Action space
    ``Box(low, high, (d,), float32)``: a state in the task's sampling bounds, not
    normalised (wrap with ``gymnasium.wrappers.RescaleAction`` for [-1, 1] policies).
    Out-of-bounds actions are clipped to the bounds; a NaN/inf action or one of the wrong
    shape raises ``ValueError``. For BiRRT the action extends the tree named by the
    observation's ``active_tree``.

    ## Observation space
    The tree as a graph padded to ``max_nodes`` (see :mod:`gnn_mp_envs.envs.observation`):
    ``nodes``, ``node_features`` = ``[x_init - x_n, x_goal - x_n, tree_id]``, ``parent``,
    ``mask``, ``num_nodes``, ``start``, ``goal``, ``active_tree``. Rows are written in
    place as nodes are added; by default each step returns a copy.

    ## Rewards
    ``-step_penalty`` every step, ``-collision_check_cost`` per validity check the step
    made, and ``+success_reward`` on the step that finds a path.

    ## Starting state
    A tree holding only its root(s). ``reset(seed=s)`` reproduces the problem and tree;
    ``reset(options={"problem": p})`` plans a given problem (a task ``Problem`` or a dict
    such as ``{"start": ..., "goal": ..., "walls": ...}``); ``reset(options={"index": i})``
    plans the i-th problem of the env's ``split`` (``"test"``: the held-out problems).

    ## Episode end
    ``terminated`` when a start-to-goal path is found. ``truncated`` when the tree holds
    ``max_nodes`` nodes or after ``max_steps`` iterations.

    ## Info
    ``is_success``, ``nodes_expanded`` (tree nodes, roots included), ``edges`` (edges
    checked, successful or not), ``collision_checks`` (validity checks, one per state,
    exact segment tests count one), ``iterations``, ``path_length`` (sum of edge costs:
    Euclidean length for geometric tasks, seconds for the pendulum; inf until solved) and,
    on success, ``path`` (states, start to goal), ``path_controls`` and ``path_nodes`` (the path's
    node indices in the observation's rows).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, task: str = "maze2d", planner: str = "rrt", max_nodes: int | None = None,
                 max_steps: int | None = None, split: str = "train",
                 task_kwargs: dict[str, Any] | None = None, render_mode: str | None = None,
                 step_penalty: float = 1.0, success_reward: float = 10.0,
                 collision_check_cost: float = 0.0, copy_observations: bool = True) -> None:
        if planner not in PLANNERS:
            raise ValueError(f"unknown planner {planner!r}; known: {sorted(PLANNERS)}")
        if split not in SPLIT_SEEDS:
            raise ValueError(f"unknown split {split!r}; known: {sorted(SPLIT_SEEDS)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.task = make_task(task, **(task_kwargs or {}))
        if planner not in self.task.planners:
            raise ValueError(f"task {task!r} supports planners {self.task.planners}, not {planner!r}")
        self.max_nodes = task_spec(task).max_nodes if max_nodes is None else int(max_nodes)
        if self.max_nodes < 2:
            raise ValueError(f"max_nodes must be >= 2, got {self.max_nodes}")
        self.max_steps = 4 * self.max_nodes if max_steps is None else int(max_steps)
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        self.planner_name = planner
        self.split = split
        self.render_mode = render_mode
        self.step_penalty = float(step_penalty)
        self.success_reward = float(success_reward)
        self.collision_check_cost = float(collision_check_cost)
        self.copy_observations = bool(copy_observations)
        if self.copy_observations:
            keep_freed_heap()

        low, high = self.task.state_bounds()
        self.state_dim = int(low.shape[0])
        self._low = np.asarray(low, dtype=np.float32)
        self._high = np.asarray(high, dtype=np.float32)
        self.action_space = spaces.Box(self._low, self._high, dtype=np.float32)
        self.observation_space = observation_space(self._low, self._high, self.max_nodes)
        self._obs = GraphObservation(self.state_dim, self.max_nodes)
        self.problem: Problem | None = None
        self.planner = None

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = options or {}
        if "problem" in options:
            problem = self.task.make_problem(options["problem"])
            if problem.state_dim != self.state_dim:
                raise InvalidProblemError(
                    f"problem has state dimension {problem.state_dim}, env expects {self.state_dim}")
        else:
            index = options.get("index")
            if index is None:
                index = int(self.np_random.integers(2**31 - 1))
            problem = self.task.problem(self.split, int(index))
        problem.reset_counters()
        self.problem = problem
        self.planner = make_planner(self.planner_name, problem, self.max_nodes)
        self._obs.reset(problem, self.planner.tree)
        return self._observation(), self._info()

    def step(self, action):
        if self.planner is None:
            raise RuntimeError("call reset() before step()")
        sample = self._check_action(action)
        checks_before = self.problem.collision_checks
        result = self.planner.step(sample)
        for i in result.added:
            self._obs.add(self.planner.tree, i)
        self._obs.active_tree[0] = self.planner.active_tree
        reward = (-self.step_penalty
                  - self.collision_check_cost * (self.problem.collision_checks - checks_before)
                  + (self.success_reward if result.solved else 0.0))
        terminated = self.planner.solved
        truncated = (not terminated) and (self.planner.tree.full or self.planner.iterations >= self.max_steps)
        return self._observation(), reward, terminated, truncated, self._info()

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self.planner is None:
            raise RuntimeError("call reset() before render()")
        sol = self.planner.solution
        return self.task.render_rgb(self.problem, self.planner.tree, None if sol is None else sol.states)

    def close(self) -> None:
        self.task.close()
        super().close()

    # ------------------------------------------------------------------ helpers
    def _check_action(self, action) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (self.state_dim,):
            raise ValueError(f"action must have shape ({self.state_dim},) within bounds "
                             f"low={self._low.tolist()} high={self._high.tolist()}; got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite (shape ({self.state_dim},), bounds "
                             f"low={self._low.tolist()} high={self._high.tolist()}); got {a.tolist()}")
        return np.clip(a, self.problem.low, self.problem.high)

    def _observation(self) -> dict:
        return self._obs.as_dict(copy=self.copy_observations)

    def _info(self) -> dict[str, Any]:
        p, pl = self.problem, self.planner
        info: dict[str, Any] = {
            "is_success": pl.solved,
            "nodes_expanded": len(pl.tree),
            "edges": p.edges_checked,
            "collision_checks": p.collision_checks,
            "iterations": pl.iterations,
            "path_length": pl.solution.length if pl.solved else float("inf"),
        }
        if pl.solved:
            info["path"] = pl.solution.states.copy()
            info["path_controls"] = pl.solution.controls.copy()
            info["path_nodes"] = pl.solution.nodes.copy()
        return info
