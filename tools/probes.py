"""What the speed probes in ``tools/`` share: a problem whose goal test never fires (so a tree can
grow to any size) and a tree grown to a given size with uniform samples.

The probes live outside the package: they measure, they are not part of the library. Run them
from the repository root, e.g. ``.venv/bin/python -m tools.bench_env --help``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

import gnn_mp_envs  # noqa: F401  (registers the environments)
from gnn_mp_envs.core.problem import Problem
from gnn_mp_envs.registration import task_spec


def goal_free(problem: Problem) -> Problem:
    """A copy of ``problem`` whose goal test never fires: RRT keeps growing its tree (BiRRT still
    ends when its two trees connect). Measurement only."""
    cls = type(problem)
    free = type(f"GoalFree{cls.__name__}", (cls,), {"in_goal": lambda self, x: False,
                                                     "goal_connection": lambda self, x: None})
    copy = object.__new__(free)
    copy.__dict__.update(problem.__dict__)
    return copy


def goal_free_env(task: str, split: str, index: int, *, max_nodes: int, **kwargs: Any):
    """The task's benchmark env (unwrapped), reset to a goal-free copy of problem ``index`` of ``split``
    with a step budget large enough to fill ``max_nodes``; returns ``(env, observation)``."""
    env = gym.make(task_spec(task).env_id, split=split, max_nodes=max_nodes, max_steps=1000 * max_nodes,
                   **kwargs).unwrapped
    obs, _ = env.reset(options={"problem": goal_free(env.task.problem(split, index))})
    return env, obs


def grow(task: str, nodes: int, index: int, seed: int, split: str = "val",
         max_nodes: int | None = None) -> dict[str, np.ndarray]:
    """A copy of the observation of ``task``'s problem ``index`` grown to ``nodes`` nodes with uniform
    samples (``default_rng([seed, index])``) and the goal test off."""
    capacity = task_spec(task).max_nodes if max_nodes is None else max_nodes
    if nodes > capacity:
        raise ValueError(f"{nodes} nodes do not fit the {task} env's max_nodes={capacity}")
    env, obs = goal_free_env(task, split, index, max_nodes=capacity)
    rng = np.random.default_rng([seed, index])
    low, high = env.action_space.low, env.action_space.high
    try:
        while int(obs["num_nodes"][0]) < nodes:
            obs, _, terminated, truncated, _ = env.step(rng.uniform(low, high).astype(np.float32))
            if (terminated or truncated) and int(obs["num_nodes"][0]) < nodes:
                # BiRRT (the arm) ends when its two trees connect, whatever the goal test says
                why = "solved" if terminated else "stopped"
                raise RuntimeError(f"{task} problem {index}: the planner {why} at {int(obs['num_nodes'][0])} "
                                   f"nodes, before {nodes}")
        return {k: np.array(v) for k, v in obs.items()}
    finally:
        env.close()
