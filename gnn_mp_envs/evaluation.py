"""Plan problems ``0..N-1`` of a split with a sampler: the one loop and the one seeding rule.

The benchmark, dataset collection for learned samplers, RL evaluation and training-time
evaluation all plan through :func:`plan_problems` (or :func:`plan_problem`, one problem), so
"which problems, which seeds, which counters" is defined once::

    env = evaluation_env("maze2d", split="val")
    records = plan_problems(sampler, env, range(20), seed=0)      # [RunRecord], problem order
    summarize(records)["median_nodes"]

**Seeding rule.** Problem ``i`` of a run with root seed ``s`` is planned with the sampler
reseeded to :func:`problem_seed` ``(s, i)`` (the same for every sampler, distinct across
problems) and the environment reset to that seed with ``options={"index": i}``: the problem
itself is the split's ``i``-th, whatever the seed. A sampler is anything with
``reset(seed)`` and ``act(observation) -> action`` (no torch here).
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Mapping, Protocol

import numpy as np

from gnn_mp_envs.rollout import RunRecord, StepCallback, rollout

#: Seeds are 32-bit (OMPL's RNG takes one; numpy's SeedSequence would take more).
MAX_SEED = 2**32 - 1


class Plannable(Protocol):
    """What :func:`plan_problems` needs of a sampler."""

    def reset(self, seed: int | None = None) -> None: ...
    def act(self, observation: Mapping[str, np.ndarray]) -> np.ndarray: ...


def problem_seed(seed: int, index: int) -> int:
    """Sampler seed of problem ``index``: the same for every sampler, distinct across problems."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def evaluation_env(task: str, split: str = "test", *, planner: str | None = None, scene: str | None = None,
                   max_nodes: int | None = None, render: bool = False, **env_kwargs: Any):
    """The environment samplers are judged on: the task's benchmark variant (or ``planner``'s),
    problems of ``split`` (for tasks with scenes: of ``scene``, by default the split's own, i.e. the
    held-out family for ``"test"`` and the training families otherwise, so nothing is tuned on the
    held-out family), live observation views (``copy_observations=False``: a run reads each
    observation before the next step; a per-step copy of a 20,000-row padded observation would
    dominate the wall time), and without Gymnasium's wrappers: the passive checker would warn about
    exactly those shared views, and ``OrderEnforcing`` costs ~30 us per step (about a third of a
    maze2d planner iteration) for a check the environment makes itself (``step`` before ``reset``
    raises)."""
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401  (registers the built-in ids)
    from gnn_mp_envs.registration import task_spec
    spec = task_spec(task)
    kwargs: dict[str, Any] = {"split": split, "copy_observations": False, **env_kwargs}
    if max_nodes is not None:
        kwargs["max_nodes"] = int(max_nodes)
    if scene is not None:
        kwargs["scene"] = scene
    env = gym.make(spec.env_id_for(planner), render_mode="rgb_array" if render else None,
                   disable_env_checker=True, **kwargs)
    return env.unwrapped


def plan_problem(env: Any, sampler: Plannable, index: int, seed: int, *, max_steps: int | None = None,
                 on_step: StepCallback | None = None,
                 policy: Callable[[Mapping[str, np.ndarray]], np.ndarray] | None = None) -> RunRecord:
    """Plan problem ``index`` of ``env``'s split with ``sampler`` under the seeding rule.

    ``policy`` replaces ``sampler.act`` as the step function (e.g. a wrapper that records the
    samples); the sampler is reseeded either way. An env of ``samples_per_step=K > 1`` takes the
    sampler's ``act_batch(observation, K)``.
    """
    s = problem_seed(seed, index)
    sampler.reset(s)
    if policy is None:
        k = int(getattr(env, "samples_per_step", 1))
        policy = sampler.act if k == 1 else (lambda observation: sampler.act_batch(observation, k))
    return rollout(env, policy, seed=s, options={"index": int(index)}, max_steps=max_steps, on_step=on_step)


def plan_problems(sampler: Plannable, env: Any, indices: Iterable[int], seed: int, *,
                  max_steps: int | None = None, progress: bool = False, desc: str | None = None) -> list[RunRecord]:
    """Plan each problem of ``indices`` (in order) with :func:`plan_problem`; a progress bar on request."""
    indices = list(indices)
    if progress:
        from tqdm.auto import tqdm
        indices = tqdm(indices, desc=desc, unit="problem", leave=False)
    return [plan_problem(env, sampler, i, seed, max_steps=max_steps) for i in indices]


def summarize(records: list[RunRecord]) -> dict[str, float | None]:
    """The figures every evaluation reports: the number of problems, success rate, median / mean
    nodes, median collision checks, median wall time (s), median path length of the solved runs
    (None when none was solved)."""
    if not records:
        raise ValueError("no runs to summarize")
    nodes = np.array([r.nodes_expanded for r in records], float)
    lengths = [r.path_length for r in records if r.path_length is not None]
    return {"problems": len(records), "success_rate": float(np.mean([r.success for r in records])),
            "median_nodes": float(np.median(nodes)), "mean_nodes": float(nodes.mean()),
            "median_collision_checks": float(np.median([r.collision_checks for r in records])),
            "median_wall_time_s": float(np.median([r.wall_time_s for r in records])),
            "median_path_length": float(np.median(lengths)) if lengths else None}


__all__ = ["MAX_SEED", "Plannable", "evaluation_env", "plan_problem", "plan_problems", "problem_seed", "summarize"]
