"""Planning runs: one sampler on one problem, and every sampler on every problem (serially, in
the worker processes or on the Ray actors of :mod:`train.workers`). Each run goes through
:func:`gnn_mp_envs.evaluation.plan_problem`."""

from __future__ import annotations

import json
import sys
import time
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Iterable

import numpy as np

from gnn_mp_envs.core.problem import PATH_CHECK_REFINE, verdict
from train.benchmark.args import (
    BenchmarkArgs,
    BenchmarkError,
    env_kwargs_for,
    is_external,
    is_ompl,
    is_vamp,
    validate_args,
)
from train.args import UsageError
from train.workers import SharedPool, WorkerPool

#: Per-process caches of the worker state: one env per (id, kwargs), one sampler per (name, task,
#: checkpoint); building the arm's simulator or a learned sampler is not free.
_ENVS: dict[str, Any] = {}
_SAMPLERS: dict[tuple, Any] = {}


def cached_env(task: str, env_kwargs: dict[str, Any], render: bool = False):
    """The benchmark env of ``task`` (:func:`gnn_mp_envs.evaluation.evaluation_env`), one per process and kwargs."""
    from gnn_mp_envs.evaluation import evaluation_env
    key = json.dumps([task, env_kwargs, render], sort_keys=True)
    if key not in _ENVS:
        _ENVS[key] = warmed_up(evaluation_env(task, render=render, **env_kwargs))
    return _ENVS[key]


def warmed_up(env: Any) -> Any:
    """``env`` after one untimed step of its first problem: a process's first step loads the planner's
    compiled loop and checker from numba's cache (or compiles them), which would otherwise land in the
    first timed run of the first row. Every run resets the env with its own seed. A step that
    fails here fails again in the timed run, which names the sampler and problem: nothing is lost."""
    try:
        env.reset(seed=0, options={"index": 0})
        env.step(env.action_space.sample())
    except (Exception, SystemExit):      # noqa: BLE001  (reported by the run that meets it)
        pass
    return env


#: Draws of a new sampler before its timed runs: with a uniform share of 0.5, its model's path is
#: compiled outside the timing with probability 1 - 0.5**8.
WARM_UP_DRAWS = 8


def cached_sampler(name: str, task: str, checkpoint: str | None = None, env: Any = None,
                   settings: tuple[tuple[str, Any], ...] = ()):
    """One sampler per (name, task, checkpoint) and process; reseeded every episode. A new one draws
    samples for ``env``'s first problem (:data:`WARM_UP_DRAWS` steps' and, where it plans in batches, a
    batch), so lazy imports and compilation stay out of the measured wall time (the benchmark reseeds
    it and resets the env before each problem)."""
    import json

    from agents.registry import SAMPLERS, load_sampler, sampler_for_checkpoint
    key = (name, task, checkpoint, json.dumps(settings, sort_keys=True))   # values may be dicts (unhashable)
    if key not in _SAMPLERS:
        # a row of the user's own name (--checkpoint mine=PATH): the sampler that runs the file's kind
        base = name if name in SAMPLERS or checkpoint is None else sampler_for_checkpoint(checkpoint)
        sampler = load_sampler(base, task=task, seed=0, checkpoint=checkpoint, **dict(settings))
        if env is not None:
            obs = env.reset(seed=0, options={"index": 0})[0]
            for _ in range(WARM_UP_DRAWS):        # each source of the mixture drawn at least once, almost surely
                sampler.act(obs)
            if getattr(sampler, "samples_per_step", 1) > 1:      # a batch's own path (one forward for several samples)
                sampler.act_batch(obs, max(sampler.samples_per_step, WARM_UP_DRAWS))
        _SAMPLERS[key] = sampler
    return _SAMPLERS[key]


def run_episode(task: str, env_kwargs: dict[str, Any], sampler_name: str, index: int, seed: int,
                checkpoint: str | None = None, settings: tuple[tuple[str, Any], ...] = (),
                snapshot_iterations: Iterable[int] = (), recheck: bool = True,
                keep_path: bool = False) -> dict[str, Any]:
    """Plan problem ``index`` with one sampler; the record of counters (and optional snapshots).
    ``recheck=False`` leaves the returned path's re-check to :func:`recheck_episode` (the record
    carries the path until then). ``keep_path``: the record keeps the returned path (``path``, and
    ``path_controls`` where the task has controls; None when not solved), as ``--save-paths`` does."""
    from gnn_mp_envs.evaluation import plan_problem, problem_seed
    snapshots_at = set(snapshot_iterations)
    env = cached_env(task, env_kwargs, render=bool(snapshots_at))
    sampler = cached_sampler(sampler_name, task, checkpoint, env, settings)
    batch = int(getattr(sampler, "samples_per_step", 1))
    if batch > 1 and not snapshots_at:       # the batch the sampler asks for (images need every iteration)
        env = cached_env(task, {**env_kwargs, "samples_per_step": batch})
    snapshots: list[tuple[int, int, np.ndarray]] = []

    def snapshot(_obs: Any, info: dict[str, Any], done: bool) -> None:
        if info["iterations"] in snapshots_at and not done:
            snapshots.append((info["iterations"], info["nodes_expanded"], env.render()))

    try:
        run = plan_problem(env, sampler, index, seed, on_step=snapshot if snapshots_at else None)
    except (Exception, SystemExit) as exc:    # a NaN action, a plugin's KeyError or sys.exit: this row fails
        raise BenchmarkError(f"sampler {sampler_name!r} on {task} problem {index}: {fault(exc)}") from None
    record = {"sampler": sampler_name, "problem": int(index), "seed": problem_seed(seed, index), **run.counters(),
              "family": getattr(env.problem, "family", None)}   # the problem's scene family (tables per family)
    # where the planning loop's wall time went: inside env.step (the planner) and outside it (the sampler)
    record["planner_time_s"] = record.pop("env_time_s")
    record["sampler_time_s"] = max(run.wall_time_s - run.env_time_s, 0.0)
    record["path_valid"] = record["path_valid_fine"] = None
    solution = env.planner.solution if run.success else None
    if solution is not None:
        if recheck:
            _recheck(task, env.problem, record, solution.states, solution.controls)
        else:
            record[_PATH] = (solution.states, solution.controls)
    if keep_path:
        record.update(path_record(solution))
    if snapshots_at:
        snapshots.append((run.iterations, run.nodes_expanded, env.render()))
        record["snapshots"] = snapshots
    return record


def path_record(solution: Any) -> dict[str, Any]:
    """A run's returned path as the report stores it (``--save-paths``): ``path`` the states, start to
    goal, ``path_controls`` row *i* the control of the edge into state *i* (row 0 zeros; None for a
    geometric task); both None when not solved."""
    if solution is None:
        return {"path": None, "path_controls": None}
    controls = np.asarray(solution.controls)
    return {"path": np.asarray(solution.states, dtype=np.float64).tolist(),
            "path_controls": controls.astype(np.float64).tolist() if controls.size else None}


#: Key of a record's returned path until :func:`recheck_episode` re-checks it (never in a report).
_PATH = "_path_to_recheck"


def recheck_episode(task: str, env_kwargs: dict[str, Any], record: dict[str, Any]) -> dict[str, Any]:
    """The re-check of a record :func:`run_episode` made with ``recheck=False``: its problem is made
    again (the split's ``record["problem"]``-th) and its path re-checked; the record, with its verdicts."""
    if _PATH not in record:
        return record
    env = cached_env(task, env_kwargs)
    states, controls = record.pop(_PATH)
    _recheck(task, env.task.problem(env.split, record["problem"]), record, states, controls)
    return record


def _recheck(task: str, problem: Any, record: dict[str, Any], states: np.ndarray, controls: np.ndarray) -> None:
    """Every returned path re-checked edge by edge with the problem's own checker (uncounted): a planner
    or checker fault shows as False; and, independently of the planner's edge checks, at
    PATH_CHECK_REFINE times its resolution (what the resolution skipped over shows as path_valid_fine
    False). Only a real True counts (a plugin task's NaN is no verdict)."""
    try:
        record["path_valid"] = verdict(problem.path_valid(states, controls))
        record["path_valid_fine"] = verdict(problem.path_valid(states, controls, refine=PATH_CHECK_REFINE))
    except (Exception, SystemExit) as exc:
        raise BenchmarkError(f"task {task}'s path_valid on problem {record['problem']}: {fault(exc)}") from None


def fault(exc: BaseException) -> str:
    """One line about an exception of plugin code: its message (with its type unless a ValueError,
    TypeError, RuntimeError or IndexError, whose messages say what is wrong)."""
    lines = str(exc).strip().splitlines()
    message = lines[0] if lines else ""
    if isinstance(exc, (ValueError, TypeError, RuntimeError, IndexError)) and message:
        return message
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def _run_episode_job(job: tuple) -> dict[str, Any]:
    return run_episode(*job)


def _recheck_episode_job(job: tuple) -> dict[str, Any]:
    return recheck_episode(*job)


def checkpoint_of(args: BenchmarkArgs, name: str) -> str | None:
    path = args.checkpoints.get(name)
    return None if path is None else str(path)


def check_env_and_samplers(task: str, env_kwargs: dict[str, Any], samplers: list[tuple],
                           problems: int | None = None) -> None:
    """Build the env and every sampler once up front so bad input fails before the progress bar
    (also ``problems`` beyond the split's size); one inference each warms up lazy imports (as the
    workers' initializer does)."""
    try:
        env = cached_env(task, env_kwargs)
    except ImportError as exc:
        raise BenchmarkError(f"task {task!r} is not available: {exc}") from None
    except (ValueError, TypeError) as exc:
        raise BenchmarkError(f"cannot build the {task} environment with {env_kwargs}: {exc}") from None
    size = env.task.num_problems(env.split)
    if problems is not None and size is not None and problems > size:
        scene = f" scene {env.scene!r}" if env.scene is not None else ""
        raise BenchmarkError(f"--problems {problems}: split {env.split!r} of {task}{scene} has {size} problems")
    for name, checkpoint, settings in samplers:
        try:
            cached_sampler(name, task, checkpoint, env, settings)
        except FileNotFoundError as exc:
            raise BenchmarkError(f"sampler {name!r}: missing checkpoint ({exc})") from None
        except (ValueError, TypeError, OSError, RuntimeError) as exc:
            raise BenchmarkError(f"sampler {name!r} cannot be loaded for task {task!r}: {exc}") from None
        except (Exception, SystemExit) as exc:     # a plugin's factory: its KeyError, sys.exit, ...
            raise BenchmarkError(f"sampler {name!r} cannot be loaded for task {task!r}: {fault(exc)}") from None


def run_benchmark(args: BenchmarkArgs, pool: WorkerPool | None = None) -> dict[str, Any]:
    """Run every sampler on the same problems; returns the report (see :func:`build_report`).
    ``pool``: the worker processes to use (a suite passes one for all its tasks); by default
    ``--workers`` > 1 starts a pool for this call."""
    from tqdm import tqdm

    from train.benchmark.ompl_rows import run_ompl_rows
    from train.benchmark.stats import build_report

    validate_args(args)
    env_kwargs = env_kwargs_for(args)
    indices = list(range(args.problems))
    learned = [(n, checkpoint_of(args, n), args.sampler_settings(n)) for n in args.samplers if not is_external(n)]
    check_env_and_samplers(args.task, env_kwargs, learned, args.problems)
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in args.samplers}

    for name in args.samplers:   # first: an unsupported OMPL combination fails before the long part
        if is_ompl(name):
            runs[name] = run_ompl_rows(args, name, indices)
        elif is_vamp(name):          # VAMP's paths wait for the re-check below, as ours do
            from train.benchmark.vamp_rows import run_vamp_rows
            runs[name] = run_vamp_rows(args, name, indices, cached_env(args.task, env_kwargs), _PATH)

    # sampler-major: a worker runs one sampler over the problems, warm, as a user plans with it. Tried
    # problem-major (every sampler per problem in turn): the switching cost the learned rows their
    # caches, maze2d gnn 1.12-1.17x uniform's wall time against 0.89-0.91x (two alternated runs each).
    # The returned paths are re-checked after all timed runs, not between them: the re-check's pybullet
    # work at 10x the resolution evicted the next run's caches (docs/journal, 2026-12-05, the re-check).
    jobs = [(args.task, env_kwargs, name, i, args.seed, checkpoint, settings, (), False, args.save_paths)
            for name, checkpoint, settings in learned for i in indices]
    if not args.recheck:       # never silently: success without the re-check is the planner's word
        tqdm.write(f"{args.task}: {NO_RECHECK}", file=sys.stderr)
    bar = tqdm(total=len(jobs), desc=f"{args.task}", unit="run", disable=not args.progress, file=sys.stderr)

    def finished(record: dict[str, Any]) -> None:
        runs[record["sampler"]].append(record)
        bar.update(1)

    def rechecked(record: dict[str, Any]) -> None:
        row = runs[record["sampler"]]
        row[next(k for k, r in enumerate(row) if r["problem"] == record["problem"])] = record
        bar.update(1)

    def dispatch(own: WorkerPool | SharedPool) -> None:
        """Both phases on one set of workers (processes or Ray actors, or this process): the timed runs,
        then the re-checks of their paths."""
        own.run(jobs, finished, _run_episode_job)
        rechecks = [(args.task, env_kwargs, r) for row in runs.values() for r in row if _PATH in r]
        if rechecks and args.recheck:
            tqdm.write(f"{args.task}: re-checking the {len(rechecks)} returned paths edge by edge at the planner's "
                       f"resolution and {PATH_CHECK_REFINE}x finer (untimed; --no-recheck skips it)", file=sys.stderr)
            start = time.perf_counter()
            bar.reset(total=len(rechecks))
            bar.set_description(f"{args.task} re-check")
            own.run(rechecks, rechecked, _recheck_episode_job)
            recheck_s.append(time.perf_counter() - start)

    reason, recheck_s = None, []
    try:
        if pool is not None and args.ray is None:        # a suite's pool, shared by its tasks
            dispatch(pool)
        else:                                           # Ray, processes (no more than the jobs) or none
            with SharedPool(args.workers, args.ray, args.modules) as own:
                dispatch(own)
    except KeyboardInterrupt:
        reason = "interrupted"
    except BrokenProcessPool:
        reason = "a worker process died (killed by a signal or out of memory)"
    except UsageError as exc:           # a failing sampler (a BenchmarkError), or Ray's
        reason = str(exc)
    finally:
        bar.close()
        if recheck_s:
            print(f"{args.task}: re-check done in {recheck_s[0]:.1f} s", file=sys.stderr)
        for row in runs.values():       # a run stopped before its re-check keeps no verdict
            for r in row:
                r.pop(_PATH, None)

    for name in runs:
        runs[name].sort(key=lambda r: r["problem"])
    report = build_report(args, runs)
    if reason is not None:
        done = sum(len(r) for r in runs.values())
        raise BenchmarkIncomplete(f"{reason}; {done} of {len(jobs) + len(indices) * sum(map(is_external, args.samplers))} "
                                  "runs finished", {**report, "partial": True}, interrupted=reason == "interrupted")
    return report


#: What ``--no-recheck`` announces (and the table's note says).
NO_RECHECK = ("--no-recheck: the returned paths are not re-checked; success counts every path the planner "
              "returned (unverified)")


class BenchmarkIncomplete(BenchmarkError):
    """The benchmark stopped early (Ctrl-C, a dead worker, a failing sampler); ``report``
    holds the runs that finished, marked ``"partial": true``."""

    def __init__(self, message: str, report: dict[str, Any], interrupted: bool = False) -> None:
        super().__init__(message)
        self.report = report
        self.interrupted = interrupted
