"""Planning runs: one sampler on one problem, and every sampler on every problem (serially or
in worker processes). Each run goes through :func:`gnn_mp_envs.rollout.rollout`."""

from __future__ import annotations

import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Iterable

import numpy as np

from train.benchmark.args import (BenchmarkArgs, BenchmarkError, env_kwargs_for, import_modules, is_ompl,
                                  problem_seed, task_spec_for, validate_args)

_ENVS: dict[str, Any] = {}
_SAMPLERS: dict[tuple, Any] = {}


def cached_env(env_id: str, env_kwargs: dict[str, Any], render: bool = False):
    """One env per (id, kwargs) and process: building the arm's simulator is not free."""
    import gymnasium as gym
    import gnn_mp_envs  # noqa: F401  (registers the ids)
    key = json.dumps([env_id, env_kwargs, render], sort_keys=True)
    if key not in _ENVS:
        # Live observation views are shared between steps on purpose: Gymnasium's passive
        # checker would warn about exactly that, once per env.
        _ENVS[key] = gym.make(env_id, render_mode="rgb_array" if render else None,
                              disable_env_checker=not env_kwargs.get("copy_observations", True), **env_kwargs)
    return _ENVS[key]


def cached_sampler(name: str, task: str, low: np.ndarray, high: np.ndarray, checkpoint: str | None = None):
    """One sampler per (name, task, bounds, checkpoint) and process; reseeded every episode."""
    from agents.samplers import load_sampler
    key = (name, task, tuple(low.tolist()), tuple(high.tolist()), checkpoint)
    if key not in _SAMPLERS:
        extra = {"checkpoint": checkpoint} if checkpoint is not None else {}
        _SAMPLERS[key] = load_sampler(name, low, high, task=task, seed=0, **extra)
    return _SAMPLERS[key]


def run_episode(task: str, env_id: str, env_kwargs: dict[str, Any], sampler_name: str, index: int,
                seed: int, checkpoint: str | None = None,
                snapshot_iterations: Iterable[int] = ()) -> dict[str, Any]:
    """Plan problem ``index`` with one sampler; the record of counters (and optional snapshots)."""
    from gnn_mp_envs.rollout import rollout
    snapshots_at = set(snapshot_iterations)
    env = cached_env(env_id, env_kwargs, render=bool(snapshots_at))
    sampler = cached_sampler(sampler_name, task, env.action_space.low, env.action_space.high, checkpoint)
    sample_seed = problem_seed(seed, index)
    snapshots: list[tuple[int, int, np.ndarray]] = []

    def snapshot(_obs: Any, info: dict[str, Any], done: bool) -> None:
        if info["iterations"] in snapshots_at and not done:
            snapshots.append((info["iterations"], info["nodes_expanded"], env.render()))

    sampler.reset(sample_seed)
    run = rollout(env, sampler.act, seed=sample_seed, options={"index": index},
                  on_step=snapshot if snapshots_at else None)
    record = {"sampler": sampler_name, "problem": int(index), "seed": sample_seed, **run.counters()}
    record.pop("env_time_s")   # the JSON schema (docs/results.md) reports planning wall time only
    if snapshots_at:
        snapshots.append((run.iterations, run.nodes_expanded, env.render()))
        record["snapshots"] = snapshots
    return record


def _run_episode_job(job: tuple) -> dict[str, Any]:
    return run_episode(*job)


def _warm_up_worker(task: str, env_id: str, env_kwargs: dict[str, Any],
                    samplers: list[tuple[str, str | None]], modules: list[str]) -> None:
    """Worker initializer: import plugin modules, build the env and samplers and run one
    inference each, so that lazy imports and first-call costs stay out of the measured wall
    time (as in a serial run)."""
    import_modules(modules)
    env = cached_env(env_id, env_kwargs)
    obs, _ = env.reset(seed=0, options={"index": 0})
    for name, checkpoint in samplers:
        cached_sampler(name, task, env.action_space.low, env.action_space.high, checkpoint).act(obs)


def checkpoint_of(args: BenchmarkArgs, name: str) -> str | None:
    path = args.checkpoints.get(name)
    return None if path is None else str(path)


def check_env_and_samplers(task: str, env_id: str, env_kwargs: dict[str, Any],
                           samplers: list[tuple[str, str | None]]) -> None:
    """Build the env and every sampler once up front so bad input fails before the progress bar;
    one inference each warms up lazy imports (as the workers' initializer does)."""
    try:
        env = cached_env(env_id, env_kwargs)
    except ImportError as exc:
        raise BenchmarkError(f"task {task!r} is not available: {exc}") from None
    except (ValueError, TypeError) as exc:
        raise BenchmarkError(f"cannot build {env_id} with {env_kwargs}: {exc}") from None
    obs, _ = env.reset(seed=0, options={"index": 0})
    for name, checkpoint in samplers:
        try:
            cached_sampler(name, task, env.action_space.low, env.action_space.high, checkpoint).act(obs)
        except FileNotFoundError as exc:
            raise BenchmarkError(f"sampler {name!r}: missing checkpoint ({exc})") from None
        except (ValueError, OSError, RuntimeError, KeyError) as exc:
            raise BenchmarkError(f"sampler {name!r} cannot be loaded for task {task!r}: {exc}") from None


def run_benchmark(args: BenchmarkArgs) -> dict[str, Any]:
    """Run every sampler on the same problems; returns the report (see :func:`build_report`)."""
    from tqdm import tqdm

    from train.benchmark.ompl_rows import run_ompl_rows
    from train.benchmark.stats import build_report

    validate_args(args)
    env_id, env_kwargs = task_spec_for(args.task).env_id, env_kwargs_for(args)
    indices = list(range(args.problems))
    learned = [(n, checkpoint_of(args, n)) for n in args.samplers if not is_ompl(n)]
    check_env_and_samplers(args.task, env_id, env_kwargs, learned)
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in args.samplers}

    for name in args.samplers:   # first: an unsupported OMPL combination fails before the long part
        if is_ompl(name):
            if args.progress:
                print(f"{name}: {len(indices)} problems through the OMPL runner ...", file=sys.stderr)
            runs[name] = run_ompl_rows(args, name, indices)

    jobs = [(args.task, env_id, env_kwargs, name, i, args.seed, checkpoint)
            for name, checkpoint in learned for i in indices]
    bar = tqdm(total=len(jobs), desc=f"{args.task}", unit="run", disable=not args.progress, file=sys.stderr)
    if args.workers == 1:
        for job in jobs:
            record = _run_episode_job(job)
            runs[record["sampler"]].append(record)
            bar.update(1)
    else:
        context = multiprocessing.get_context("spawn")   # torch + fork can deadlock
        with ProcessPoolExecutor(max_workers=args.workers, mp_context=context, initializer=_warm_up_worker,
                                 initargs=(args.task, env_id, env_kwargs, learned, args.modules)) as pool:
            futures = [pool.submit(_run_episode_job, job) for job in jobs]
            for future in as_completed(futures):
                record = future.result()
                runs[record["sampler"]].append(record)
                bar.update(1)
    bar.close()

    for name in runs:
        runs[name].sort(key=lambda r: r["problem"])
    return build_report(args, runs)
