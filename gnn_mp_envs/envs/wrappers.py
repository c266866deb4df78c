"""RL-sized environments: a bounded view of the tree, actions in ``[-1, 1]``, one helper.

The planning envs pad the tree to ``max_nodes`` rows (5,000 for maze2d, 20,000 for the
pendulum), which is what a sampler wants but not what an RL buffer should store: SB3's SAC
asks for 93 GiB for its default replay buffer on maze2d. :class:`TreeViewWrapper` presents
the same keys and layout padded to ``K`` rows instead:

* the view holds the roots (the start; for BiRRT also the goal root) and the ``K - r`` most
  recently added nodes, in increasing index order, as rows ``0..n_view-1`` (the layout of
  :mod:`gnn_mp_envs.envs.observation`: real rows first, padding zero);
* ``parent`` is remapped to view rows; a parent outside the view becomes ``-1`` (the node is
  then the root of a fragment: its edge is cut, nothing else changes);
* ``num_nodes`` and ``mask`` describe the view; ``node_features`` (``[x_init - x_n,
  x_goal - x_n, tree_id]``), ``start``, ``goal``, ``active_tree`` and ``obstacles`` are
  copied unchanged.

So :class:`agents.nn.encoders.TreeEncoder` reads a view exactly like a full observation, and a
sampler trained on views reuses :func:`tree_view` on the full observation the benchmark
gives it. Everything here is numpy; no torch.

    env = make_rl_env("maze2d", view_nodes=64, split="train")   # view + actions in [-1, 1]
    obs, info = env.reset(seed=0)                                # obs["nodes"].shape == (64, 2)
    a = env.action_space.sample()                                # in [-1, 1]^d
    low, high = env.unwrapped.action_space.low, ...              # what a = +-1 means: the state box
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, Callable, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import RescaleAction, TimeLimit, TransformReward

from gnn_mp_envs.registration import ACTIONS, RL_MAX_EPISODE_STEPS, rl_env_id
from gnn_mp_envs.envs.candidates import (DEFAULT_CANDIDATES, DEFAULT_LOCAL_SCALE, DEFAULT_TARGET_SCALE,
                                         CandidatePickWrapper, wrap_into_box)

#: Default number of rows of the view (roots + most recent nodes).
DEFAULT_VIEW_NODES = 64
#: The action box the RL policies act in (:func:`make_rl_env` rescales it to the state box).
ACTION_LOW, ACTION_HIGH = -1.0, 1.0
#: How a policy action in [-1, 1]^d becomes a state (``make_rl_env(action_frame=...)``).
ACTION_FRAMES = ("absolute", "target")


def view_rows(parent: np.ndarray, num_nodes: int, view_nodes: int) -> np.ndarray:
    """Indices (increasing) of the tree rows a ``view_nodes``-row view keeps.

    The roots (rows ``< num_nodes`` whose parent is ``-1``) come first in priority, then the
    most recent rows; with ``num_nodes <= view_nodes`` every real row is kept.
    """
    n = int(num_nodes)
    if n <= view_nodes:
        return np.arange(n)
    roots = np.flatnonzero(np.asarray(parent[:n]) < 0)
    if roots.size >= view_nodes:         # more roots than rows: keep the first ones
        return roots[:view_nodes]
    # the window of recent rows grows by the roots that fall inside it (at most r passes)
    window = view_nodes - roots.size
    while True:
        older = roots[roots < n - window]
        if view_nodes - older.size == window:
            break
        window = view_nodes - older.size
    return np.concatenate([older, np.arange(n - window, n)])


def tree_view(obs: Mapping[str, np.ndarray], view_nodes: int = DEFAULT_VIEW_NODES) -> dict[str, np.ndarray]:
    """The ``view_nodes``-row view of one (unbatched) padded observation; new arrays.

    Same keys, dtypes and layout as the full observation, with ``N`` replaced by
    ``view_nodes``; see the module docstring for what is kept and how parents are remapped.
    """
    k = int(view_nodes)
    nodes, feats, parent = obs["nodes"], obs["node_features"], np.asarray(obs["parent"])
    n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
    rows = view_rows(parent, n, k)
    m = rows.size
    out_nodes = np.zeros((k, nodes.shape[-1]), dtype=nodes.dtype)
    out_feats = np.zeros((k, feats.shape[-1]), dtype=feats.dtype)
    out_parent = np.full(k, -1, dtype=parent.dtype)
    out_mask = np.zeros(k, dtype=np.asarray(obs["mask"]).dtype)
    out_nodes[:m] = nodes[rows]
    out_feats[:m] = feats[rows]
    if m:
        # old row -> view row; parents not in the view (and roots, -1) map to -1
        old_parent = parent[rows]
        pos = np.searchsorted(rows, old_parent)
        pos = np.minimum(pos, m - 1)
        inside = (old_parent >= 0) & (rows[pos] == old_parent)
        out_parent[:m] = np.where(inside, pos, -1)
    out_mask[:m] = 1
    out = {
        "nodes": out_nodes,
        "node_features": out_feats,
        "parent": out_parent,
        "mask": out_mask,
        "num_nodes": np.array([m], dtype=np.asarray(obs["num_nodes"]).dtype),
    }
    for key in obs:
        if key not in out:
            out[key] = np.array(obs[key], copy=True)
    return out


def view_space(space: spaces.Dict, view_nodes: int = DEFAULT_VIEW_NODES) -> spaces.Dict:
    """The observation space of :func:`tree_view` for a full observation space ``space``."""
    k = int(view_nodes)
    out = {}
    for key, sub in space.spaces.items():
        if key in ("nodes", "node_features"):
            out[key] = spaces.Box(sub.low[:1].repeat(k, 0), sub.high[:1].repeat(k, 0), dtype=sub.dtype)
        elif key == "parent":
            out[key] = spaces.Box(-1, k - 1, shape=(k,), dtype=sub.dtype)
        elif key == "mask":
            out[key] = spaces.MultiBinary(k)
        elif key == "num_nodes":
            out[key] = spaces.Box(0, k, shape=(1,), dtype=sub.dtype)
        else:
            out[key] = sub
    return spaces.Dict(out)


class TreeViewWrapper(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Present a bounded ``view_nodes``-row view of the tree (same keys and layout).

    ``info`` is unchanged: ``nodes_expanded`` and the other counters describe the whole tree.
    """

    def __init__(self, env: gym.Env, view_nodes: int = DEFAULT_VIEW_NODES) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, view_nodes=view_nodes)
        gym.ObservationWrapper.__init__(self, env)
        if int(view_nodes) < 2:
            raise ValueError(f"view_nodes must be >= 2, got {view_nodes}")
        self.view_nodes = int(view_nodes)
        self.observation_space = view_space(env.observation_space, self.view_nodes)

    def observation(self, observation: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return tree_view(observation, self.view_nodes)


class ProgressReward(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Potential-based shaping (Ng et al. 1999) of the planning reward: progress toward the target.

    ``reward += coef * (gamma * phi(s') - phi(s))`` with ``phi = -D / distance(start, goal)`` and
    ``phi = 0`` once the path is found. ``D`` is the gap the planner still has to close under its
    own metric: for RRT the smallest distance from a tree node to the goal; for BiRRT the smallest
    distance between a node of the start tree and a node of the goal tree (the trees meet when it
    closes). It rewards samples whose extension closes the gap, a per-step signal the sparse
    reward lacks, and leaves the optimal policy of the discounted MDP unchanged (use the agent's
    ``gamma``). Wrap the planning env itself (it reads the planner's tree).
    """

    def __init__(self, env: gym.Env, coef: float, gamma: float = 0.99) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, coef=coef, gamma=gamma)
        gym.Wrapper.__init__(self, env)
        self.coef, self.gamma = float(coef), float(gamma)
        self._seen, self._best, self._phi, self._scale = 0, np.inf, 0.0, 1.0

    def _update(self) -> float:
        base = self.env.unwrapped
        tree, problem = base.planner.tree, base.problem
        n = len(tree)
        if n > self._seen:
            states, ids = tree.states[:n], tree.tree_id[:n]
            if getattr(base.planner, "num_trees", 1) == 1:
                self._best = min(self._best, float(problem.distance(states[self._seen:n], problem.goal).min()))
            else:
                # every new node against the other tree's nodes (old and new: each pair once)
                for i in range(self._seen, n):
                    others = states[:n][ids[:n] != ids[i]]
                    if len(others):
                        self._best = min(self._best, float(problem.distance(others, states[i]).min()))
            self._seen = n
        return -self._best / self._scale

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        problem = self.env.unwrapped.problem
        self._seen, self._best = 0, np.inf
        self._scale = max(float(problem.distance(problem.start[None], problem.goal)[0]), 1e-9)
        self._phi = self._update()
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        phi = 0.0 if terminated else self._update()
        reward = float(reward) + self.coef * (self.gamma * phi - self._phi)
        self._phi = phi
        return obs, reward, terminated, truncated, info


def _scaled_reward(scale: float, reward: Any) -> float:
    """``reward * scale`` as a float: the reward ``make_rl_env(reward_scale=...)`` hands to the agent
    (returns of order 1 keep the value loss from swamping the policy's share of a clipped gradient);
    a module-level function, so the wrapped env pickles (``partial`` of it, not a lambda)."""
    return float(reward) * scale


class UniformMixAction(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """With probability ``p``, replace the agent's action by a uniform one over the action box.

    The classical learned-sampler mixture (a fraction of uniform samples keeps the planner
    probabilistically complete) applied during training, so the policy learns where to put
    the *other* samples; the sampler then mixes at the same rate (``uniform_mix``). The draws
    come from the wrapper's own generator, seeded by ``reset(seed=...)``.
    """

    def __init__(self, env: gym.Env, p: float) -> None:
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"p must be in [0, 1], got {p}")
        gym.utils.RecordConstructorArgs.__init__(self, p=p)
        gym.ActionWrapper.__init__(self, env)
        self.p = float(p)
        self._rng = np.random.default_rng()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), 0x5EED])
        return super().reset(seed=seed, options=options)

    def action(self, action):
        if self.p > 0.0 and self._rng.random() < self.p:
            box = self.action_space
            return self._rng.uniform(box.low, box.high).astype(box.dtype)
        return action


def policy_action_to_state(action: np.ndarray, frame: str, low: np.ndarray, high: np.ndarray,
                           target: np.ndarray | None = None, periodic: np.ndarray | None = None) -> np.ndarray:
    """A policy action in ``[-1, 1]^d`` -> a state, before clipping: the one action map of
    training (:func:`make_rl_env`) and of the RL sampler. Computed in the dtype of ``low``.

    ``frame="absolute"``: the box rescaled (``RescaleAction``'s map); ``frame="target"``: an
    offset from ``target`` (the active tree's) in units of the box span, ``target + a * (high - low)``.
    ``periodic`` (a bool mask): those coordinates wrapped into ``[low, high)``.
    """
    low = np.asarray(low)
    high = np.asarray(high, dtype=low.dtype)
    span = high - low
    a = np.minimum(np.maximum(np.asarray(action, dtype=low.dtype), ACTION_LOW), ACTION_HIGH)   # np.clip
    if frame == "absolute":
        x = low + span * (a - ACTION_LOW) / (ACTION_HIGH - ACTION_LOW)
    elif frame == "target":
        x = np.asarray(target, dtype=low.dtype) + a * span
    else:
        raise ValueError(f"action_frame must be one of {ACTION_FRAMES}, got {frame!r}")
    if periodic is not None and np.any(periodic):
        x = wrap_into_box(x, low, span, periodic)
    return x


class TargetRelativeAction(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """Actions in ``[-1, 1]^d`` as offsets from the active tree's target, in units of the box span.

    ``state = clip(normalize(target + a * (high - low)))`` (:func:`policy_action_to_state`),
    ``target`` the goal (RRT, BiRRT's start tree) or the start (BiRRT's goal tree), ``normalize``
    the problem's (wraps the pendulum's angle). ``a = 0`` samples the target itself, so an
    untrained policy (``loc = 0``) starts as a Gaussian goal bias and RL learns the spread and
    where else to sample; ``|a| = 1`` reaches the whole box from any target.
    """

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.ActionWrapper.__init__(self, env)
        box = env.action_space
        self._low, self._high = box.low.astype(np.float64), box.high.astype(np.float64)
        d = box.shape[0]
        self.action_space = spaces.Box(np.full(d, ACTION_LOW, np.float32), np.full(d, ACTION_HIGH, np.float32))

    def action(self, action):
        if np.shape(action) != self._low.shape:      # before any arithmetic: one line, not numpy's broadcast error
            raise ValueError(f"action must have shape {self._low.shape} in [{ACTION_LOW:g}, {ACTION_HIGH:g}] (an "
                             f"offset from the active tree's target in box spans); got shape {np.shape(action)}")
        base = self.env.unwrapped
        problem = base.problem
        target = problem.start if int(base.planner.active_tree) == 1 else problem.goal
        x = problem.normalize(policy_action_to_state(action, "target", self._low, self._high, target))
        return np.clip(x, self._low, self._high).astype(np.float32)


def scale_action(action: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """A policy action in ``[-1, 1]^d`` -> a state in ``[low, high]`` (``RescaleAction``'s map)."""
    return policy_action_to_state(action, "absolute", np.asarray(low, np.float64), high).astype(np.float32)


#: The RL reward when the task's ``TaskSpec.rl_reward`` says nothing else: a node costs one, blocked
#: iterations cost nothing but their checks (the benchmark counts nodes, not iterations), success
#: earns ten (``TreePlanningEnv``'s reward keywords).
RL_REWARD = {"step_penalty": 0.0, "node_cost": 1.0, "collision_check_cost": 0.0, "success_reward": 10.0}
#: The uniform mixture when none is given: the classical half for continuous policies; none
#: for pickers, whose candidates include uniform states already.
DEFAULT_UNIFORM_MIX = {"pick": 0.0, "box": 0.5}


def candidate_settings(task: str, count: int = DEFAULT_CANDIDATES, local_scale: float = DEFAULT_LOCAL_SCALE,
                       target_scale: float = DEFAULT_TARGET_SCALE) -> dict[str, Any]:
    """The :class:`~gnn_mp_envs.envs.candidates.CandidateSet` keyword arguments of ``task``: the
    candidate env's (:func:`make_rl_env` with ``action="pick"``) and its sampler's; the extension
    scale, periodic coordinates and metric come from the task's ``TaskSpec`` (``step_scale`` None:
    the step size of the task's first training problem)."""
    from gnn_mp_envs.registration import make_task, task_spec
    spec = task_spec(task)
    low, _ = spec.state_bounds()
    step = spec.step_scale
    if step is None:
        instance = make_task(task, **({"scene": spec.training_scene()} if spec.scenes else {}))
        try:
            step = float(instance.problem("train", 0).step_size)
        finally:
            instance.close()
    return {"count": int(count), "step_scale": float(step), "periodic": spec.periodic_mask(len(low)).tolist(),
            "metric_weights": None if spec.metric_weights is None else [float(w) for w in spec.metric_weights],
            "local_scale": float(local_scale), "target_scale": float(target_scale)}


def make_rl_env(task: str, view_nodes: int | None = DEFAULT_VIEW_NODES, split: str = "train", *,
                planner: str | None = None, action: str = "pick", candidates: int = DEFAULT_CANDIDATES,
                local_scale: float = DEFAULT_LOCAL_SCALE, target_scale: float = DEFAULT_TARGET_SCALE,
                candidate_prior: Callable[[], Any] | None = None, scale_actions: bool = True, uniform_mix: float | None = None,
                action_frame: str = "target", progress_reward: float = 10.0, gamma: float = 0.99,
                reward_scale: float = 0.01, max_episode_steps: int | None = RL_MAX_EPISODE_STEPS,
                **env_kwargs: Any) -> gym.Env:
    """The environment of ``gnn-mp train rl`` (its defaults are this function's) and of the
    registered RL ids (``GNNMP/<Env>-RLPick-v0``, ``-RLBox-v0``, :func:`rl_env_id`).

    ``task``'s benchmark environment (``planner="rrt"``/``"birrt"`` picks another registered
    variant), problems of ``split`` (``"train"`` to learn, ``"val"`` to tune), then:

    * the reward: the env's (``step_penalty``, ``node_cost``, ``collision_check_cost``,
      ``success_reward``; defaults: :data:`RL_REWARD` updated by the task's ``TaskSpec.rl_reward``),
      with ``progress_reward > 0``
      :class:`ProgressReward` (potential-based shaping with the agent's ``gamma``), multiplied
      by ``reward_scale`` (Gymnasium's ``TransformReward``);
    * ``action="pick"``: :class:`~gnn_mp_envs.envs.candidates.CandidatePickWrapper`, ``Discrete(candidates)``
      actions over the step's candidate states (features relative to the tree in the observation;
      ``candidate_prior``, a zero-argument factory of a
      :class:`~gnn_mp_envs.envs.candidates.CandidatePrior`, adds its logit of each candidate as the
      last feature column);
      ``action="box"``: ``[-1, 1]^d`` actions, offsets from the active tree's target
      (``action_frame="target"``, :class:`TargetRelativeAction`) or the rescaled box
      (``"absolute"``; ``scale_actions=False`` keeps state-space actions);
    * ``uniform_mix``: that fraction of the samples replaced by uniform states, as the sampler
      does (None: :data:`DEFAULT_UNIFORM_MIX` of the action);
    * :class:`TreeViewWrapper` (``view_nodes=None``: the full padded observation);
    * ``TimeLimit(max_episode_steps)`` (None: the env's own limits only).

    ``env_kwargs`` go to the environment: ``step_penalty``, ``collision_check_cost``,
    ``success_reward`` (the reward, see ``docs/rl.md``), ``max_nodes``, ``max_steps``,
    ``scene``, ``task_kwargs``. Observations are not copied by the env
    (``copy_observations=False``): the view is a fresh copy already.
    """
    from gnn_mp_envs.registration import task_spec

    spec = task_spec(task)
    env_id = spec.env_id_for(planner)
    env_kwargs.setdefault("copy_observations", view_nodes is None)
    for key, value in {**RL_REWARD, **spec.rl_reward}.items():
        env_kwargs.setdefault(key, value)
    if action not in ACTIONS:
        raise ValueError(f"action must be one of {ACTIONS}, got {action!r}")
    if action_frame not in ACTION_FRAMES:
        raise ValueError(f"action_frame must be one of {ACTION_FRAMES}, got {action_frame!r}")
    if candidate_prior is not None and action != "pick":
        raise ValueError(f"candidate_prior scores a picker's candidates (action='pick'), not action={action!r}")
    budget = int(env_kwargs.get("max_nodes", spec.max_nodes))
    if view_nodes is not None and (isinstance(view_nodes, bool) or not isinstance(view_nodes, (int, np.integer))
                                   or not 2 <= view_nodes <= budget):
        raise ValueError(f"view_nodes must be an integer in [2, {budget}] (the tree's node budget) or None, "
                         f"got {view_nodes!r}")
    uniform_mix = DEFAULT_UNIFORM_MIX[action] if uniform_mix is None else uniform_mix
    if not (isinstance(uniform_mix, (int, float)) and 0.0 <= uniform_mix <= 1.0):     # NaN fails too
        raise ValueError(f"uniform_mix must be a number in [0, 1], got {uniform_mix!r}")
    if not (isinstance(reward_scale, (int, float)) and math.isfinite(reward_scale) and reward_scale > 0):
        raise ValueError(f"reward_scale must be a finite number > 0, got {reward_scale!r}")
    if max_episode_steps is not None and (isinstance(max_episode_steps, bool) or int(max_episode_steps) < 1):
        raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
    env = gym.make(env_id, split=split, disable_env_checker=True, **env_kwargs)
    if uniform_mix > 0.0 and action == "box":
        env = UniformMixAction(env, uniform_mix)      # state-space samples: uniform over the box
    if progress_reward > 0.0:
        env = ProgressReward(env, progress_reward, gamma)
    if reward_scale != 1.0:
        env = TransformReward(env, partial(_scaled_reward, float(reward_scale)))
    if action == "pick":
        env = CandidatePickWrapper(env, uniform_mix, candidate_prior,
                                   **candidate_settings(task, candidates, local_scale, target_scale))
    if view_nodes is not None:
        env = TreeViewWrapper(env, view_nodes)
    if action == "box" and scale_actions:
        if action_frame == "target":
            env = TargetRelativeAction(env)
        else:
            d = env.action_space.shape[0]
            env = RescaleAction(env, np.full(d, ACTION_LOW, np.float32), np.full(d, ACTION_HIGH, np.float32))
    if max_episode_steps is not None:
        env = TimeLimit(env, int(max_episode_steps))
    return env


__all__ = ["ACTIONS", "ACTION_FRAMES", "ACTION_HIGH", "ACTION_LOW", "DEFAULT_UNIFORM_MIX", "DEFAULT_VIEW_NODES",
           "ProgressReward", "RL_MAX_EPISODE_STEPS", "RL_REWARD", "candidate_settings", "rl_env_id",
           "TargetRelativeAction", "TreeViewWrapper", "UniformMixAction", "make_rl_env", "policy_action_to_state",
           "scale_action", "tree_view", "view_rows", "view_space"]
