"""The one episode loop: a policy (any callable from observation to action) plans one problem.

The benchmark, the bench scripts, dataset collection for learned samplers and the tests all
run episodes through :func:`rollout` (or :func:`run_steps` when they manage resets
themselves), so "what one planning run is" and what it reports is defined once::

    record = rollout(env, sampler.act, options={"index": 3}, seed=7)
    record.success, record.nodes_expanded, record.collision_checks, record.path_nodes

A policy is ``policy(observation) -> action``; a sampler's ``act`` is one. Wall time covers
the planning loop only (policy calls and ``env.step``), not ``reset``, which generates the
problem; ``env_time_s`` is the part spent inside ``env.step``.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping

import numpy as np

Policy = Callable[[Mapping[str, np.ndarray]], np.ndarray]
#: ``on_step(observation, info, done)`` after every step (``done``: the episode ended with
#: it); return True to stop early.
StepCallback = Callable[[Mapping[str, np.ndarray], dict[str, Any], bool], "bool | None"]


@dataclass
class StepsResult:
    """What :func:`run_steps` ends with."""

    observation: Mapping[str, np.ndarray]
    info: dict[str, Any]
    steps: int
    terminated: bool
    truncated: bool
    wall_time_s: float
    env_time_s: float


@dataclass
class RunRecord:
    """The counters of one planning run (one problem, one policy)."""

    success: bool
    nodes_expanded: int
    edges: int
    collision_checks: int
    iterations: int
    path_length: float | None   # None when not solved (never NaN or inf: JSON-safe)
    wall_time_s: float          # planning loop: policy calls + env.step
    env_time_s: float           # the part spent inside env.step
    path_nodes: list[int] | None = None

    def counters(self) -> dict[str, Any]:
        """The record as a JSON-friendly dict (without the path's node indices)."""
        out = asdict(self)
        out.pop("path_nodes")
        return out


def run_steps(env: Any, policy: Policy, observation: Mapping[str, np.ndarray], max_steps: int | None = None,
              on_step: StepCallback | None = None, info: dict[str, Any] | None = None) -> StepsResult:
    """Step ``env`` with ``policy`` from ``observation`` until the episode ends, ``max_steps``
    steps were taken, or ``on_step`` returns True."""
    steps, env_time, terminated, truncated = 0, 0.0, False, False
    info = {} if info is None else info
    clock = time.perf_counter
    start = clock()
    while max_steps is None or steps < max_steps:
        action = policy(observation)
        t0 = clock()
        observation, _, terminated, truncated, info = env.step(action)
        env_time += clock() - t0
        steps += 1
        done = terminated or truncated
        if (on_step is not None and on_step(observation, info, done)) or done:
            break
    return StepsResult(observation, info, steps, bool(terminated), bool(truncated), clock() - start, env_time)


def rollout(env: Any, policy: Policy, *, seed: int | None = None, options: dict[str, Any] | None = None,
            max_steps: int | None = None, on_step: StepCallback | None = None) -> RunRecord:
    """Reset ``env`` (``seed``, ``options`` as ``env.reset``) and plan until the episode ends."""
    observation, info = env.reset(seed=seed, options=options)
    result = run_steps(env, policy, observation, max_steps=max_steps, on_step=on_step, info=info)
    return record_of(result)


def record_of(result: StepsResult) -> RunRecord:
    """The :class:`RunRecord` of an episode's last ``info``."""
    info = result.info
    success = bool(info["is_success"])
    length = float(info["path_length"]) if success else None
    return RunRecord(
        success=success, nodes_expanded=int(info["nodes_expanded"]), edges=int(info["edges"]),
        collision_checks=int(info["collision_checks"]), iterations=int(info["iterations"]),
        path_length=length if length is not None and math.isfinite(length) else None,
        wall_time_s=result.wall_time_s, env_time_s=result.env_time_s,
        path_nodes=[int(i) for i in info["path_nodes"]] if success and "path_nodes" in info else None)
