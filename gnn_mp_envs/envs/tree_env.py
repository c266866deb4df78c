"""One Gymnasium environment for every planning task: the growing tree is the observation,
the next sample is the action."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gnn_mp_envs.core.planners import PLANNERS, checked_balance, make_planner
from gnn_mp_envs.core.problem import InvalidProblemError, Problem
from gnn_mp_envs.envs.observation import GraphObservation, keep_freed_heap, obstacle_shape, observation_space
from gnn_mp_envs.registration import make_task, task_spec
from gnn_mp_envs.tasks.base import SPLIT_SEEDS
from gnn_mp_envs.utils.compiled import lazy_njit

_add_reduce, _maximum, _minimum, _isfinite = np.add.reduce, np.maximum, np.minimum, math.isfinite

#: Keys ``reset(options=...)`` understands (anything else is a typo and is refused).
RESET_OPTIONS = frozenset({"problem", "index"})
#: Largest node budget accepted: the padded observation and tree arrays of 2 million 6-D
#: nodes already take ~0.5 GB; larger budgets are almost certainly a typo.
MAX_NODES_LIMIT = 2_000_000
#: Largest ``samples_per_step``: a batch beyond this is a typo (its action alone would be megabytes).
MAX_SAMPLES_PER_STEP = 65_536


def _clip_finite(action: np.ndarray, low: np.ndarray, high: np.ndarray, out: np.ndarray) -> bool:
    """``out`` = ``action`` (as float64) clipped to ``[low, high]``, as ``np.minimum(np.maximum(action,
    low), high)``; False when an entry is NaN or infinite. One compiled pass instead of four numpy calls
    on every step."""
    for i in range(action.shape[0]):
        v = float(action[i])
        if not math.isfinite(v):
            return False
        v = np.maximum(v, low[i])
        out[i] = np.minimum(v, high[i])
    return True


#: :func:`_clip_finite` compiled (numba), or None without numba.
compiled_clip_finite = lazy_njit(_clip_finite)


def integer(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an int in ``[minimum, maximum]``; a ValueError naming ``name`` otherwise
    (floats with a fractional part, strings, bools and NaN are refused, not truncated)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if isinstance(value, (float, np.floating)) and not (math.isfinite(value) and float(value).is_integer()):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if value < minimum or (maximum is not None and value > maximum):
        bound = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum:,}]"
        raise ValueError(f"{name} must be {bound}, got {value:,}")
    return value


def real(name: str, value: Any) -> float:
    """``value`` as a finite float; a ValueError naming ``name`` otherwise."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out) or isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return out


class TreePlanningEnv(gym.Env):
    """Sampling-based planning as an MDP: each step is one RRT/BiRRT iteration.

    ## Description
    ``reset`` draws a planning problem (start, goal, obstacles) from the task family and
    roots the tree(s) at the start (RRT) or at start and goal (BiRRT). Each ``step``
    takes the next sample as its action and runs one planner iteration with it:
    nearest node -> steer toward the sample -> counted validity checks -> add node
    (BiRRT: greedily connect the other tree to the new node, then swap trees) -> goal
    test. Any sampler, uniform, learned or an RL policy, drives the same planner.
    With ``samples_per_step=K`` an action is ``K`` samples, consumed in order as ``K`` steps would
    (BiRRT alternating trees), in one compiled call where the problem's steer and checks are
    compiled (:mod:`gnn_mp_envs.core.loop`), until a solution, a full tree or the iteration
    budget; the observation and info come after the batch (``info["samples_consumed"]``).
    ``balance=True`` (BiRRT only) balances the two trees as VAMP's RRT-Connect does: the trees swap
    after a sample only while the other holds fewer than twice the nodes of the one just extended,
    so a tree boxed in (a goal inside a shelf) gets the samples until it has grown.

    ## Action space
    ``Box(low, high, (d,), float32)``: a state in the task's sampling bounds, not
    normalised (wrap with ``gymnasium.wrappers.RescaleAction`` for [-1, 1] policies); with
    ``samples_per_step=K > 1``, ``(K, d)``: ``K`` such states.
    Out-of-bounds actions are clipped to the bounds; a NaN/inf action or one of the wrong
    shape raises ``ValueError``. For BiRRT the action extends the tree named by the
    observation's ``active_tree`` (sample ``k`` of a batch: the tree ``k`` swaps later; with
    ``balance``, the tree the sizes pick then, which a sampler cannot know before the batch).

    ## Observation space
    The tree as a graph padded to ``max_nodes`` (see :mod:`gnn_mp_envs.envs.observation`):
    ``nodes``, ``node_features`` = ``[x_init - x_n, x_goal - x_n, tree_id]``, ``parent``,
    ``mask``, ``num_nodes``, ``start``, ``goal``, ``active_tree``, ``obstacles`` (the problem's
    obstacles, a row each, for conditional samplers). Rows are written in
    place as nodes are added; by default each step returns a copy.

    ## Rewards
    ``-step_penalty`` every step (every sample consumed), ``-node_cost`` per node the step added,
    ``-collision_check_cost`` per validity check the step made, and ``+success_reward`` on the step that
    finds a path.

    ## Starting state
    A tree holding only its root(s). ``reset(seed=s)`` reproduces the problem and tree;
    ``reset(options={"problem": p})`` plans a given problem (a task ``Problem`` or a dict
    such as ``{"start": ..., "goal": ..., "walls": ...}``); ``reset(options={"index": i})``
    plans the i-th problem of the env's ``split`` (``"test"``: the held-out problems); other
    option keys are refused. Tasks with scene families (the arm) take ``scene=``; without
    one, ``split="test"`` plans the held-out family and the other splits the training ones.
    Tasks with several collision checkers (the robots) take ``checker=`` (``"spheres"`` or ``"pybullet"``,
    :data:`gnn_mp_envs.robots.checkers.CHECKERS`; default: the task's, ``TaskSpec.checkers[0]``).

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
                 max_steps: int | None = None, split: str = "train", scene: str | None = None,
                 task_kwargs: dict[str, Any] | None = None, render_mode: str | None = None,
                 step_penalty: float = 1.0, success_reward: float = 10.0,
                 collision_check_cost: float = 0.0, copy_observations: bool = True, node_cost: float = 0.0,
                 checker: str | None = None, samples_per_step: int = 1, balance: bool = False) -> None:
        spec = task_spec(task)
        if planner not in PLANNERS:
            raise ValueError(f"unknown planner {planner!r}; known: {sorted(PLANNERS)}")
        #: BiRRT's trees balanced (:class:`~gnn_mp_envs.core.planners.BiRRT`): the next sample extends the smaller
        #: tree while the other holds twice its nodes (the observation's ``active_tree`` says which).
        self.balance = checked_balance(planner, balance)
        if split not in SPLIT_SEEDS:
            raise ValueError(f"unknown split {split!r}; known: {sorted(SPLIT_SEEDS)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.max_nodes = spec.max_nodes if max_nodes is None else integer("max_nodes", max_nodes, 2, MAX_NODES_LIMIT)
        self.max_steps = 4 * self.max_nodes if max_steps is None else integer("max_steps", max_steps, 1)
        #: Samples an action holds (1: one state per step).
        self.samples_per_step = integer("samples_per_step", samples_per_step, 1, MAX_SAMPLES_PER_STEP)
        self.step_penalty = real("step_penalty", step_penalty)
        self.success_reward = real("success_reward", success_reward)
        self.collision_check_cost = real("collision_check_cost", collision_check_cost)
        self.node_cost = real("node_cost", node_cost)
        task_kwargs = dict(task_kwargs or {})
        if spec.scenes:
            if scene is not None and task_kwargs.get("scene", scene) != scene:
                raise ValueError(f"scene={scene!r} and task_kwargs['scene']={task_kwargs['scene']!r} disagree")
            # Held-out problems come from the held-out scene family, training and validation
            # problems from the training families, unless a scene is named.
            task_kwargs.setdefault("scene", spec.default_scene(split) if scene is None else scene)
            if task_kwargs["scene"] not in spec.scenes:
                raise ValueError(f"unknown scene {task_kwargs['scene']!r} for task {task!r}; "
                                 f"known: {', '.join(spec.scenes)}")
        elif scene is not None:
            raise ValueError(f"task {task!r} has no scenes (scene={scene!r})")
        if checker is not None and not spec.checkers:
            raise ValueError(f"task {task!r} has one collision checker (checker={checker!r})")
        if checker is not None and task_kwargs.get("checker", checker) != checker:
            raise ValueError(f"checker={checker!r} and task_kwargs['checker']={task_kwargs['checker']!r} disagree")
        if spec.checkers:                         # the name goes to the task, which makes the checker of it
            task_kwargs.setdefault("checker", checker or spec.checkers[0])
        self.scene = task_kwargs.get("scene")
        self.task = make_task(task, **task_kwargs)
        #: The name of the planner's collision checker (None: the task has only one).
        self.checker = self.task.checker.name if spec.checkers else None
        if planner not in self.task.planners:
            self.task.close()
            raise ValueError(f"task {task!r} supports planners {self.task.planners}, not {planner!r}")
        self.planner_name = planner
        self.split = split
        self.render_mode = render_mode
        self.copy_observations = bool(copy_observations)
        if self.copy_observations:
            keep_freed_heap()

        low, high = self.task.state_bounds()
        self.state_dim = int(low.shape[0])
        self._low = np.asarray(low, dtype=np.float32)
        self._high = np.asarray(high, dtype=np.float32)
        k = self.samples_per_step
        if k == 1:
            self.action_space = spaces.Box(self._low, self._high, dtype=np.float32)
            self._action_shape = (self.state_dim,)
        else:
            self.action_space = spaces.Box(np.tile(self._low, (k, 1)), np.tile(self._high, (k, 1)), dtype=np.float32)
            self._action_shape = (k, self.state_dim)
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None    # the problem's bounds, one row per sample
        self._clip = compiled_clip_finite()
        obstacles = obstacle_shape(self.task.max_obstacles, self.task.obstacle_width)
        self.observation_space = observation_space(self._low, self._high, self.max_nodes, obstacles)
        self._obs = GraphObservation(self.state_dim, self.max_nodes, obstacles)
        self.problem: Problem | None = None
        self.planner = None
        self._closed = False

    # ------------------------------------------------------------------ gym API
    def _check_open(self, call: str) -> None:
        """After :meth:`close` the task's resources (the arm's and Panda's simulator) are gone: one clear
        error instead of the simulator's own ("Not connected to physics server")."""
        if getattr(self, "_closed", False):
            name = self.spec.id if self.spec is not None else type(self).__name__
            raise RuntimeError(f"{call}() on a closed environment ({name}): make a new one with gym.make")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self._check_open("reset")
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - RESET_OPTIONS)
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; known: {sorted(RESET_OPTIONS)}")
        if "problem" in options and "index" in options:
            raise ValueError("reset options 'problem' and 'index' exclude each other")
        if "problem" in options:
            problem = self.task.make_problem(options["problem"])
            if problem.state_dim != self.state_dim:
                raise InvalidProblemError(
                    f"problem has state dimension {problem.state_dim}, env expects {self.state_dim}")
        else:
            index = options.get("index")
            if index is None:
                index = int(self.np_random.integers(self.task.num_problems(self.split) or 2**31 - 1))
            problem = self.task.problem(self.split, integer("options['index']", index, 0))
        problem.reset_counters()
        self.problem = problem
        self.planner = make_planner(self.planner_name, problem, self.max_nodes, self.balance)
        k = self.samples_per_step
        self._bounds = ((problem.low, problem.high) if k == 1 else
                        (np.tile(problem.low, k), np.tile(problem.high, k)))
        self._obs.reset(problem, self.planner.tree, self.task.obstacle_rows(problem))
        return self._observation(), self._info()

    def step(self, action):
        if self._closed:
            self._check_open("step")
        planner = self.planner
        if planner is None:
            raise RuntimeError("call reset() before step()")
        samples = self._check_action(action)
        problem, obs = self.problem, self._obs
        checks_before = problem.collision_checks
        result = planner.run(samples if samples.ndim == 2 else samples[None], self.max_steps - planner.iterations)
        if result.added:                          # appended in index order: one run of rows
            obs.add_rows(planner.tree, result.added[0], result.added[-1] + 1)
        obs.active_tree[0] = planner.active_tree
        reward = (-self.step_penalty * result.consumed
                  - self.collision_check_cost * (problem.collision_checks - checks_before)
                  - (self.node_cost * len(result.added) if self.node_cost else 0.0)
                  + (self.success_reward if result.solved else 0.0))
        terminated = planner.solution is not None
        truncated = (not terminated) and (planner.tree.full or planner.iterations >= self.max_steps)
        info = self._info()
        if self.samples_per_step > 1:
            info["samples_consumed"] = result.consumed
        return obs.as_dict(copy=self.copy_observations), reward, terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            gym.logger.warn("render() without a render mode returns None; make the env with "
                            "render_mode='rgb_array' to get images")
            return None
        if self.planner is None:
            raise RuntimeError("call reset() before render()")
        sol = self.planner.solution
        return self.task.render_rgb(self.problem, self.planner.tree, None if sol is None else sol.states)

    def close(self) -> None:
        self.task.close()
        self._closed = True
        super().close()

    def export_tree(self) -> dict[str, np.ndarray]:
        """The tree(s) of the current episode as plain numpy arrays (copies), to keep or save
        (``np.savez(file, **env.unwrapped.export_tree())``); ``agents.nn.graph.tree_data`` turns
        them into a PyTorch Geometric ``Data``. ``n`` nodes in insertion order (the observation's
        rows), ``d`` the state dimension, ``c`` the control dimension (0 for geometric tasks):

        * ``states`` ``(n, d)`` float64, ``parent`` ``(n,)`` int64 (-1 for a root),
          ``tree_id`` ``(n,)`` int64 (0: the start's tree, 1: BiRRT's goal tree),
          ``cost`` ``(n,)`` float64 (cost-to-come from the node's root), ``controls`` ``(n, c)``
          float64 (the control of the edge into the node; zeros for a root);
        * ``edges`` ``(n - roots, 2)`` int64: ``[parent, child]`` per tree edge, children in order;
        * ``start``, ``goal`` ``(d,)`` float64; ``path_nodes`` ``(k,)`` int64: the returned path's
          nodes, start to goal (empty until solved; BiRRT's path crosses from one tree to the other
          once, an edge of neither tree).
        """
        self._check_open("export_tree")
        if self.planner is None:
            raise RuntimeError("call reset() before export_tree()")
        tree, n = self.planner.tree, self.planner.tree.size
        parent = tree.parent[:n].copy()
        children = np.flatnonzero(parent >= 0)
        sol = self.planner.solution
        return {"states": tree.states[:n].copy(), "parent": parent, "tree_id": tree.tree_id[:n].copy(),
                "cost": tree.cost[:n].copy(), "controls": tree.controls[:n].copy(),
                "edges": np.stack([parent[children], children], axis=1).astype(np.int64),
                "start": np.array(self.problem.start, dtype=np.float64),
                "goal": np.array(self.problem.goal, dtype=np.float64),
                "path_nodes": (np.zeros(0, np.int64) if sol is None else np.asarray(sol.nodes, np.int64).copy())}

    # ------------------------------------------------------------------ helpers
    def _check_action(self, action) -> np.ndarray:
        low, high = self._bounds
        shape = self._action_shape
        if type(action) is np.ndarray and action.dtype.kind == "f":     # a sampler's float array: the common case
            if self._clip is not None and action.shape == shape:    # compiled: check and clip in one pass
                out = np.empty(shape)
                if self._clip(action.reshape(-1), low, high, out.reshape(-1)):
                    return out
            a = action.astype(np.float64, copy=False)
        else:
            if np.iscomplexobj(action):
                raise ValueError(f"action must be real (shape {shape}); got a complex {type(action).__name__}")
            a = np.asarray(action, dtype=np.float64)
        if a.shape != shape:
            raise ValueError(f"action must have shape {shape} within bounds "
                             f"low={self._low.tolist()} high={self._high.tolist()}; got shape {a.shape}")
        # A finite sum means finite entries (NaN and inf propagate); an overflowing sum of finite
        # entries takes the exact test. One reduction instead of two.
        if not _isfinite(_add_reduce(a.reshape(-1))) and not (a.min() > -math.inf and a.max() < math.inf):
            raise ValueError(f"action must be finite (shape {shape}, bounds "
                             f"low={self._low.tolist()} high={self._high.tolist()}); got {a.tolist()}")
        return _minimum(_maximum(a.reshape(-1), low), high).reshape(shape)   # np.clip, without its overhead

    def _observation(self) -> dict:
        return self._obs.as_dict(copy=self.copy_observations)

    def _info(self) -> dict[str, Any]:
        p, pl = self.problem, self.planner
        sol = pl.solution
        info: dict[str, Any] = {
            "is_success": sol is not None,
            "nodes_expanded": pl.tree.size,
            "edges": p.edges_checked,
            "collision_checks": p.collision_checks,
            "iterations": pl.iterations,
            "path_length": math.inf if sol is None else sol.length,
        }
        if sol is not None:
            info["path"] = sol.states.copy()
            info["path_controls"] = sol.controls.copy()
            info["path_nodes"] = sol.nodes.copy()
        return info
