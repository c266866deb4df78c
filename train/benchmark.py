"""Benchmark samplers side by side on the held-out problems of a task.

Every sampler plans the same problems (``split="test"``, indices ``0..N-1``) with the
same per-problem seed, derived from ``--seed`` and the problem index. The planner, its
node budget and its counters are those of :class:`~gnn_mp_envs.envs.tree_env.TreePlanningEnv`;
OMPL planners (``ompl-rrtconnect``, ``ompl-rrt``, ``ompl-kpiece``) run the same problems
through the isolated runner of :mod:`gnn_mp_envs.baselines.ompl_runner`.

    gnn-mp benchmark --task maze2d --samplers uniform,goal-bias --problems 30 --seed 0 \\
        --json results/maze2d.json --plot results/maze2d.png
    gnn-mp benchmark --suite default --out results/      # what `make benchmark` runs

The ``--json`` schema is documented in ``docs/results.md``.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

#: The counters every run reports, in table order.
METRICS: tuple[str, ...] = ("nodes_expanded", "edges", "collision_checks", "path_length", "wall_time_s")
#: Metrics summarised over successful runs only (a failed run has no path).
SUCCESS_ONLY_METRICS: frozenset[str] = frozenset({"path_length"})
#: Prefix of OMPL planner rows; the rest of the name is the OMPL planner.
OMPL_PREFIX = "ompl-"
#: OMPL planners each task can run (geometric tasks: RRTConnect; pendulum: control-based planners).
OMPL_PLANNERS: dict[str, tuple[str, ...]] = {
    "maze2d": ("rrtconnect", "rrt"),
    "arm": ("rrtconnect", "rrt"),
    "pendulum": ("rrt", "kpiece"),
}
#: Scene benchmarked when --scene is not given: the arm's held-out scene family (train-a/-b are for training).
DEFAULT_SCENES: dict[str, str] = {"arm": "test"}
OMPL_INSTALL_HINT = "OMPL is not installed; install the optional extra with `pip install -e .[ompl]`"


class BenchmarkError(Exception):
    """A user-facing error (bad flags, unknown names, missing files): printed as one line."""


@dataclass
class BenchmarkArgs:
    """Flags of one benchmark run (one task, several samplers)."""

    task: str = "maze2d"
    samplers: list[str] = field(default_factory=lambda: ["uniform", "goal-bias"])
    problems: int = 20
    seed: int = 0
    max_nodes: int | None = None
    scene: str | None = None
    workers: int = 1
    json: Path | None = None
    plot: Path | None = None
    render: Path | None = None
    ompl_log: Path | None = None
    ompl_time_limit: float = 10.0
    checkpoints: dict[str, Path] = field(default_factory=dict)   # sampler name -> checkpoint file
    sampler_modules: list[str] = field(default_factory=list)     # imported first: they register samplers
    progress: bool = True


# ---------------------------------------------------------------------------- set-up
def env_id_for(task: str) -> str:
    from gnn_mp_envs.registration import TASK_ENV_IDS
    try:
        return TASK_ENV_IDS[task]
    except KeyError:
        raise BenchmarkError(f"unknown task {task!r}; known: {', '.join(sorted(TASK_ENV_IDS))}") from None


def env_kwargs_for(args: BenchmarkArgs) -> dict[str, Any]:
    """Keyword arguments of ``gym.make`` for the benchmark env (held-out split).

    Observations are live views (``copy_observations=False``): a run reads each one before
    the next step, and a per-step copy of a 20,000-row padded observation would otherwise
    dominate the measured wall time.
    """
    kwargs: dict[str, Any] = {"split": "test", "copy_observations": False}
    if args.max_nodes is not None:
        kwargs["max_nodes"] = int(args.max_nodes)
    if args.scene is not None:
        kwargs["task_kwargs"] = {"scene": args.scene}
    return kwargs


def problem_seed(seed: int, index: int) -> int:
    """Sampler seed of problem ``index``: the same for every sampler, distinct across problems."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def is_ompl(name: str) -> bool:
    return name.startswith(OMPL_PREFIX)


def known_sampler_names(task: str) -> list[str]:
    from agents.samplers import available_samplers
    return available_samplers() + [OMPL_PREFIX + p for p in OMPL_PLANNERS.get(task, ())]


def import_sampler_modules(modules: list[str]) -> None:
    """Import modules that call ``register_sampler`` (in the main process and in every worker)."""
    import importlib
    for module in modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise BenchmarkError(f"cannot import sampler module {module!r}: {exc}") from None


def validate_args(args: BenchmarkArgs) -> None:
    """Reject bad flags before any planning starts (one-line messages); fills in the default scene."""
    env_id_for(args.task)
    import_sampler_modules(args.sampler_modules)
    if args.scene is not None and args.task not in DEFAULT_SCENES:
        raise BenchmarkError(f"--scene applies to {', '.join(sorted(DEFAULT_SCENES))} only, not {args.task!r}")
    if args.scene is None:
        args.scene = DEFAULT_SCENES.get(args.task)
    if args.problems < 1:
        raise BenchmarkError(f"--problems must be >= 1, got {args.problems}")
    if args.seed < 0:
        raise BenchmarkError(f"--seed must be >= 0, got {args.seed}")
    if args.workers < 1:
        raise BenchmarkError(f"--workers must be >= 1, got {args.workers}")
    if args.max_nodes is not None and args.max_nodes < 2:
        raise BenchmarkError(f"--max-nodes must be >= 2, got {args.max_nodes}")
    if args.ompl_time_limit <= 0:
        raise BenchmarkError(f"--ompl-time-limit must be > 0, got {args.ompl_time_limit}")
    if not args.samplers:
        raise BenchmarkError("--samplers is empty")
    if len(set(args.samplers)) != len(args.samplers):
        raise BenchmarkError(f"--samplers lists a name twice: {','.join(args.samplers)}")
    known = known_sampler_names(args.task)
    for name in args.samplers:
        if is_ompl(name) and name not in known:
            supported = ", ".join(OMPL_PREFIX + p for p in OMPL_PLANNERS.get(args.task, ())) or "none"
            raise BenchmarkError(f"OMPL planner {name!r} is not available for task {args.task!r} "
                                 f"(supported: {supported})")
        if name not in known:
            raise BenchmarkError(f"unknown sampler {name!r}; known: {', '.join(known)}")
    for name, path in args.checkpoints.items():
        if name not in args.samplers:
            raise BenchmarkError(f"--checkpoint given for {name!r}, which is not in --samplers")
        if not Path(path).is_file():
            raise BenchmarkError(f"missing checkpoint for sampler {name!r}: {path} is not a file")
        if not os.access(path, os.R_OK):
            raise BenchmarkError(f"checkpoint of sampler {name!r} is not readable: {path}")
    for flag, path, is_dir in (("--json", args.json, False), ("--plot", args.plot, False),
                               ("--render", args.render, True), ("--ompl-log", args.ompl_log, True)):
        if path is not None:
            check_output_path(flag, Path(path), is_dir)
    if any(is_ompl(n) for n in args.samplers):
        check_ompl()


def check_output_path(flag: str, path: Path, is_dir: bool) -> None:
    """Fail before planning when an output cannot be written (wrong kind, parent is a file, no access)."""
    if path.exists() and path.is_dir() != is_dir:
        raise BenchmarkError(f"{flag} {path}: expected a {'directory' if is_dir else 'file'}")
    parent = path if (is_dir and path.exists()) else path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise BenchmarkError(f"{flag} {path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK):
        raise BenchmarkError(f"{flag} {path}: {parent} is not writable")


def check_ompl() -> None:
    """Fail early (before any planning) when OMPL rows cannot run."""
    try:
        from gnn_mp_envs.baselines import ompl_runner  # noqa: F401
    except ImportError as exc:
        raise BenchmarkError(f"the OMPL runner is not available in this checkout ({exc})") from None
    if not ompl_installed():
        raise BenchmarkError(OMPL_INSTALL_HINT)


def ompl_installed() -> bool:
    """Whether OMPL's Python bindings are installed (they are only imported in the runner's subprocess)."""
    from gnn_mp_envs.baselines.ompl_runner import ompl_available as installed
    return installed()


# ---------------------------------------------------------------------------- one run
_ENVS: dict[str, Any] = {}
_SAMPLERS: dict[tuple, Any] = {}


def _cached_env(env_id: str, env_kwargs: dict[str, Any], render: bool = False):
    """One env per (id, kwargs) and process: building the arm's simulator is not free."""
    import gymnasium as gym
    import gnn_mp_envs  # noqa: F401  (registers the ids)
    key = json.dumps([env_id, env_kwargs, render], sort_keys=True)
    if key not in _ENVS:
        _ENVS[key] = gym.make(env_id, render_mode="rgb_array" if render else None, **env_kwargs)
    return _ENVS[key]


def _cached_sampler(name: str, task: str, low: np.ndarray, high: np.ndarray, checkpoint: str | None = None):
    """One sampler per (name, task, bounds, checkpoint) and process; reseeded every episode."""
    from agents.samplers import load_sampler
    key = (name, task, tuple(low.tolist()), tuple(high.tolist()), checkpoint)
    if key not in _SAMPLERS:
        extra = {"checkpoint": checkpoint} if checkpoint is not None else {}
        _SAMPLERS[key] = load_sampler(name, low, high, task=task, seed=0, **extra)
    return _SAMPLERS[key]


def _finite_or_none(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def run_episode(task: str, env_id: str, env_kwargs: dict[str, Any], sampler_name: str, index: int,
                seed: int, checkpoint: str | None = None,
                snapshot_iterations: Iterable[int] = ()) -> dict[str, Any]:
    """Plan problem ``index`` with one sampler; the record of counters (and optional snapshots)."""
    snapshots_at = set(snapshot_iterations)
    env = _cached_env(env_id, env_kwargs, render=bool(snapshots_at))
    low, high = env.action_space.low, env.action_space.high
    sampler = _cached_sampler(sampler_name, task, low, high, checkpoint)
    sample_seed = problem_seed(seed, index)
    snapshots: list[tuple[int, int, np.ndarray]] = []

    sampler.reset(sample_seed)
    obs, info = env.reset(seed=sample_seed, options={"index": index})
    start_time = time.perf_counter()   # planning only: problem generation (reset) is not timed
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(sampler.act(obs))
        done = terminated or truncated
        if info["iterations"] in snapshots_at and not done:
            snapshots.append((info["iterations"], info["nodes_expanded"], env.render()))
    wall_time = time.perf_counter() - start_time
    if snapshots_at:
        snapshots.append((info["iterations"], info["nodes_expanded"], env.render()))

    record = {
        "sampler": sampler_name, "problem": int(index), "seed": sample_seed,
        "success": bool(info["is_success"]),
        "nodes_expanded": int(info["nodes_expanded"]), "edges": int(info["edges"]),
        "collision_checks": int(info["collision_checks"]), "iterations": int(info["iterations"]),
        "path_length": _finite_or_none(info["path_length"]) if info["is_success"] else None,
        "wall_time_s": wall_time,
    }
    if snapshots_at:
        record["snapshots"] = snapshots
    return record


def _run_episode_job(job: tuple) -> dict[str, Any]:
    return run_episode(*job)


def _warm_up_worker(task: str, env_id: str, env_kwargs: dict[str, Any],
                    samplers: list[tuple[str, str | None]], sampler_modules: list[str]) -> None:
    """Worker initializer: register plugin samplers, build the env and samplers and run one
    inference each, so that lazy imports and first-call costs stay out of the measured wall
    time (as in a serial run)."""
    import_sampler_modules(sampler_modules)
    env = _cached_env(env_id, env_kwargs)
    obs, _ = env.reset(seed=0, options={"index": 0})
    for name, checkpoint in samplers:
        _cached_sampler(name, task, env.action_space.low, env.action_space.high, checkpoint).act(obs)


def _ompl_record(planner_row: str, index: int, seed: int, result: dict[str, Any]) -> dict[str, Any]:
    """Map one result of the OMPL runner (see ``ompl_runner.solve_problem``) onto a benchmark record."""
    def as_int(x: Any) -> int | None:
        return None if x is None else int(x)

    success = bool(result.get("solved"))
    return {
        "sampler": planner_row, "problem": int(index), "seed": seed, "success": success,
        "nodes_expanded": as_int(result.get("nodes")),            # OMPL planner-data vertices
        "edges": as_int(result.get("edges_checked")),
        "collision_checks": as_int(result.get("collision_checks")),
        "iterations": None,
        "path_length": _finite_or_none(result.get("path_length")) if success else None,
        "wall_time_s": _finite_or_none(result.get("time")),       # OMPL's solve() time
        "ompl": {k: v for k, v in result.items() if isinstance(v, (int, float, str, bool))},
    }


def run_ompl_rows(args: BenchmarkArgs, planner_row: str, indices: list[int]) -> list[dict[str, Any]]:
    """Plan ``indices`` with an OMPL planner through the isolated runner (one subprocess per call)."""
    try:
        from gnn_mp_envs.baselines import ompl_runner
    except ImportError as exc:
        raise BenchmarkError(f"the OMPL runner is not available in this checkout ({exc})") from None
    planner = planner_row[len(OMPL_PREFIX):]
    task_kwargs = {"scene": args.scene} if args.scene is not None else None
    try:
        results = ompl_runner.run_ompl(args.task, indices, split="test", task_kwargs=task_kwargs,
                                       planner=planner, time_limit=args.ompl_time_limit, seed=args.seed)
    except ompl_runner.OMPLUnavailableError:
        raise BenchmarkError(OMPL_INSTALL_HINT) from None
    except (ValueError, NotImplementedError, RuntimeError) as exc:
        raise BenchmarkError(f"{planner_row} on {args.task}: {exc}".replace("\n", " ")) from None
    # OMPL's RNG is seeded once per runner call (with --seed + 1), so the run's seed is --seed.
    return [_ompl_record(planner_row, i, args.seed, r) for i, r in zip(indices, results)]


def ompl_available() -> bool:
    """Whether the OMPL runner exists and OMPL's Python bindings can be imported."""
    try:
        check_ompl()
    except BenchmarkError:
        return False
    return True


# ---------------------------------------------------------------------------- statistics
def summarize(values: list[float | None]) -> dict[str, float | None]:
    """median, mean, q25, q75 of the finite values; all None when there are none."""
    data = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)
    if data.size == 0:
        return {"median": None, "mean": None, "q25": None, "q75": None}
    q25, median, q75 = np.percentile(data, [25, 50, 75])
    return {"median": float(median), "mean": float(data.mean()), "q25": float(q25), "q75": float(q75)}


def sampler_summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Success rate and per-metric statistics of one sampler's runs."""
    summary: dict[str, Any] = {"success_rate": float(np.mean([r["success"] for r in records]))}
    for metric in METRICS:
        runs = [r for r in records if r["success"]] if metric in SUCCESS_ONLY_METRICS else records
        summary[metric] = summarize([r[metric] for r in runs])
    return summary


def build_report(args: BenchmarkArgs, runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """The ``--json`` document (schema in docs/results.md)."""
    import gymnasium as gym
    env_id = env_id_for(args.task)
    max_nodes = args.max_nodes or gym.spec(env_id).kwargs.get("max_nodes")
    return {
        "task": args.task,
        "problems": int(args.problems),
        "seed": int(args.seed),
        "results": {name: sampler_summary(runs[name]) for name in args.samplers},
        "env_id": env_id,
        "split": "test",
        "max_nodes": None if max_nodes is None else int(max_nodes),
        "scene": args.scene,
        "samplers": list(args.samplers),
        "runs": {name: [{k: v for k, v in r.items() if k != "snapshots"} for r in runs[name]]
                 for name in args.samplers},
    }


# ---------------------------------------------------------------------------- output
def _fmt(x: float | None, digits: int) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}f}"


def _cell(stats: dict[str, float | None], digits: int = 0, scale: float = 1.0) -> str:
    if stats["median"] is None:
        return "-"
    m, lo, hi = (stats[k] * scale for k in ("median", "q25", "q75"))
    return f"{_fmt(m, digits)} [{_fmt(lo, digits)}, {_fmt(hi, digits)}]"


def format_table(report: dict[str, Any]) -> str:
    """A fixed-width table: success rate and median [q25, q75] per metric."""
    header = ["sampler", "success", "nodes expanded", "edges", "collision checks", "path length*",
              "wall time [ms]"]
    rows = [header]
    for name, s in report["results"].items():
        rows.append([name, f"{100 * s['success_rate']:.0f}%", _cell(s["nodes_expanded"]), _cell(s["edges"]),
                     _cell(s["collision_checks"]), _cell(s["path_length"], 2), _cell(s["wall_time_s"], 0, 1e3)])
    widths = [max(len(r[c]) for r in rows) for c in range(len(header))]
    lines = ["  ".join(cell.ljust(w) if c == 0 else cell.rjust(w) for c, (cell, w) in enumerate(zip(r, widths)))
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    title = (f"{report['task']} ({report['env_id']}, max_nodes={report['max_nodes']}"
             + (f", scene={report['scene']}" if report.get("scene") else "")
             + f"): {report['problems']} held-out problems, seed {report['seed']}")
    note = ("median [q25, q75]; *path length over successful runs only; "
            "wall time = planning loop incl. sampler inference (OMPL: solve time)")
    return "\n".join([title, *lines, note])


def plot_report(report: dict[str, Any], path: Path) -> None:
    """Box plots per sampler in the style of the paper: nodes expanded, path length (+ checks for the arm)."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    panels = [("nodes_expanded", "nodes expanded", False), ("path_length", "path length (solved)", True)]
    if report["task"] == "arm":
        panels.append(("collision_checks", "collision checks", False))
    names = list(report["results"])
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels) + 0.6, 3.6), squeeze=False)
    for ax, (metric, label, success_only) in zip(axes[0], panels):
        data = []
        for name in names:
            runs = report["runs"][name]
            values = [r[metric] for r in runs if r[metric] is not None and (r["success"] or not success_only)]
            data.append(values if values else [np.nan])
        ax.boxplot(data, showfliers=True)
        ax.set_xticks(range(1, len(names) + 1), names, rotation=30, ha="right")
        ax.set_title(label)
        ax.grid(axis="y", alpha=0.3)
    rates = ", ".join(f"{n}: {100 * report['results'][n]['success_rate']:.0f}%" for n in names)
    # Two lines: the success rates of four or more samplers overflow a one-line title.
    fig.suptitle(f"{report['task']}: {report['problems']} held-out problems\nsuccess {rates}", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def snapshot_schedule(max_nodes: int) -> list[int]:
    """Iterations at which tree-growth snapshots are drawn (the final tree is always added)."""
    return [i for i in (25, 100, 400, 1600, 6400) if i < 4 * max_nodes]


def save_tree_growth(path: Path, title: str, snapshots: list[tuple[int, int, np.ndarray]]) -> None:
    """A strip of env.render() images: the tree at a few iterations and at the end."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(snapshots), figsize=(2.6 * len(snapshots), 2.9), squeeze=False)
    for ax, (iteration, nodes, image) in zip(axes[0], snapshots):
        ax.imshow(image)
        ax.set_title(f"iter {iteration}, {nodes} nodes", fontsize=8)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def render_growth(args: BenchmarkArgs, directory: Path, index: int = 0) -> list[Path]:
    """Tree-growth strips of problem ``index`` for every (non-OMPL) sampler; returns the files written."""
    import gymnasium as gym
    env_id, env_kwargs = env_id_for(args.task), env_kwargs_for(args)
    max_nodes = args.max_nodes or gym.spec(env_id).kwargs.get("max_nodes", 5000)
    written = []
    for name in args.samplers:
        if is_ompl(name):
            continue
        record = run_episode(args.task, env_id, env_kwargs, name, index, args.seed,
                             _checkpoint(args, name), snapshot_schedule(max_nodes))
        outcome = "solved" if record["success"] else "not solved"
        path = directory / f"{args.task}_{name}_problem{index}.png"
        save_tree_growth(path, f"{args.task}, {name}, test problem {index} ({outcome})", record["snapshots"])
        written.append(path)
    return written


def write_ompl_logs(args: BenchmarkArgs, report: dict[str, Any], directory: Path) -> Path | None:
    """All rows in OMPL's benchmark log format (for Planner Arena), via the runner's log writer."""
    try:
        from gnn_mp_envs.baselines.ompl_log import write_ompl_log
    except ImportError as exc:
        raise BenchmarkError(f"the OMPL log writer is not available in this checkout ({exc})") from None
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{args.task}.log"
    results_by_planner = {name: [_as_ompl_run(r) for r in report["runs"][name]] for name in args.samplers}
    total_time = sum(r["time"] or 0.0 for runs in results_by_planner.values() for r in runs)
    settings = {name: {"max_nodes": report["max_nodes"]} for name in args.samplers if not is_ompl(name)}
    experiment = f"gnn-mp {report['env_id']}" + (f" scene {args.scene}" if args.scene else "")
    write_ompl_log(path, experiment, results_by_planner, time_limit=args.ompl_time_limit, seed=args.seed,
                   total_time=total_time, planner_settings=settings)
    return path


def _as_ompl_run(record: dict[str, Any]) -> dict[str, Any]:
    """A benchmark record in the OMPL runner's keys (which the log writer maps to OMPL property names)."""
    run = dict(record.get("ompl", {}))   # OMPL rows: the runner's own fields (status, approximate, ...)
    for key in ("task", "split", "index", "planner"):
        run.pop(key, None)
    run.update({
        "solved": record["success"], "time": record["wall_time_s"], "path_length": record["path_length"],
        "nodes": record["nodes_expanded"], "edges_checked": record["edges"],
        "collision_checks": record["collision_checks"], "problem": record["problem"],
    })
    if record.get("iterations") is not None:
        run["iterations"] = record["iterations"]
    return run


# ---------------------------------------------------------------------------- main loop
def run_benchmark(args: BenchmarkArgs) -> dict[str, Any]:
    """Run every sampler on the same problems; returns the report (see :func:`build_report`)."""
    validate_args(args)
    from tqdm import tqdm

    env_id, env_kwargs = env_id_for(args.task), env_kwargs_for(args)
    indices = list(range(args.problems))
    learned = [(n, _checkpoint(args, n)) for n in args.samplers if not is_ompl(n)]
    _check_env_and_samplers(args.task, env_id, env_kwargs, learned)
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
                                 initargs=(args.task, env_id, env_kwargs, learned, args.sampler_modules)) as pool:
            futures = [pool.submit(_run_episode_job, job) for job in jobs]
            for future in as_completed(futures):
                record = future.result()
                runs[record["sampler"]].append(record)
                bar.update(1)
    bar.close()

    for name in runs:
        runs[name].sort(key=lambda r: r["problem"])
    return build_report(args, runs)


def _checkpoint(args: BenchmarkArgs, name: str) -> str | None:
    path = args.checkpoints.get(name)
    return None if path is None else str(path)


def _check_env_and_samplers(task: str, env_id: str, env_kwargs: dict[str, Any],
                            samplers: list[tuple[str, str | None]]) -> None:
    """Build the env and every sampler once up front so bad input fails before the progress bar;
    one inference each warms up lazy imports (as the workers' initializer does)."""
    try:
        env = _cached_env(env_id, env_kwargs)
    except ImportError as exc:
        raise BenchmarkError(f"task {task!r} is not available: {exc}") from None
    except (ValueError, TypeError) as exc:
        raise BenchmarkError(f"cannot build {env_id} with {env_kwargs}: {exc}") from None
    obs, _ = env.reset(seed=0, options={"index": 0})
    for name, checkpoint in samplers:
        try:
            _cached_sampler(name, task, env.action_space.low, env.action_space.high, checkpoint).act(obs)
        except FileNotFoundError as exc:
            raise BenchmarkError(f"sampler {name!r}: missing checkpoint ({exc})") from None
        except (ValueError, OSError, RuntimeError, KeyError) as exc:
            raise BenchmarkError(f"sampler {name!r} cannot be loaded for task {task!r}: {exc}") from None


def write_outputs(args: BenchmarkArgs, report: dict[str, Any]) -> dict[str, Path]:
    """Write the requested --json / --plot / --render / --ompl-log outputs."""
    written: dict[str, Path] = {}
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
        written["json"] = args.json
    if args.plot is not None:
        plot_report(report, args.plot)
        written["plot"] = args.plot
    if args.render is not None:
        for i, path in enumerate(render_growth(args, args.render)):
            written[f"render{i}"] = path
    if args.ompl_log is not None:
        path = write_ompl_logs(args, report, args.ompl_log)
        if path is not None:
            written["ompl_log"] = path
    return written


def benchmark(args: BenchmarkArgs) -> dict[str, Any]:
    """Run, print the table, write outputs."""
    report = run_benchmark(args)
    print(format_table(report))
    for kind, path in write_outputs(args, report).items():
        print(f"wrote {path}", file=sys.stderr)
    return report


# ---------------------------------------------------------------------------- suites
@dataclass
class SuiteEntry:
    task: str
    samplers: list[str]
    problems: int
    max_nodes: int | None = None
    scene: str | None = None


#: OMPL rows added to a suite when OMPL is installed (control-based RRT / KPIECE1 for the pendulum).
SUITE_OMPL_PLANNERS: dict[str, tuple[str, ...]] = {"maze2d": ("rrt", "rrtconnect"), "arm": ("rrtconnect",),
                                                   "pendulum": ("rrt", "kpiece")}

#: ``--suite default``: what ``make benchmark`` runs, a few minutes on 2 cores.
SUITES: dict[str, list[SuiteEntry]] = {
    "default": [
        SuiteEntry("maze2d", ["uniform", "goal-bias"], problems=30),
        SuiteEntry("pendulum", ["uniform", "goal-bias"], problems=30),
        SuiteEntry("arm", ["uniform", "goal-bias"], problems=20, scene="test"),
    ],
    "smoke": [
        SuiteEntry("maze2d", ["uniform", "goal-bias"], problems=3, max_nodes=300),
    ],
}


def run_suite(name: str, out: Path, seed: int = 0, workers: int = 1, progress: bool = True,
              with_ompl: bool | None = None, render: bool = True) -> dict[str, dict[str, Any]]:
    """Run a named suite; writes ``{task}.json``, ``{task}.png``, ``{task}.txt`` and ``summary.md`` to ``out``."""
    if name not in SUITES:
        raise BenchmarkError(f"unknown suite {name!r}; known: {', '.join(sorted(SUITES))}")
    if with_ompl is None:
        with_ompl = ompl_available()
    out.mkdir(parents=True, exist_ok=True)
    reports: dict[str, dict[str, Any]] = {}
    tables: list[str] = []
    suite_start = time.perf_counter()
    for entry in SUITES[name]:
        samplers = list(entry.samplers)
        if with_ompl:
            samplers += [OMPL_PREFIX + p for p in SUITE_OMPL_PLANNERS.get(entry.task, ())]
        args = BenchmarkArgs(task=entry.task, samplers=samplers, problems=entry.problems, seed=seed,
                             max_nodes=entry.max_nodes, scene=entry.scene, workers=workers,
                             json=out / f"{entry.task}.json", plot=out / f"{entry.task}.png",
                             render=out / "renders" if render else None,
                             ompl_log=out / "ompl" if with_ompl else None,
                             progress=progress)
        task_start = time.perf_counter()
        report = benchmark(args)
        elapsed = time.perf_counter() - task_start
        table = format_table(report)
        (out / f"{entry.task}.txt").write_text(table + "\n")
        tables.append(f"{table}\n({elapsed:.0f} s)")
        reports[entry.task] = report
        print(f"({entry.task}: {elapsed:.0f} s)\n")
    total = time.perf_counter() - suite_start
    command = f"gnn-mp benchmark --suite {name} --out {out} --seed {seed} --workers {workers}"
    summary = [f"# Benchmark suite `{name}`", "", f"Command: `{command}`  ",
               f"Total wall time: {total:.0f} s", "", "```", "\n\n".join(tables), "```", ""]
    (out / "summary.md").write_text("\n".join(summary))
    print(f"suite {name!r}: {total:.0f} s; results in {out}/ (summary.md, <task>.json/.png/.txt)")
    return reports


def args_dict(args: BenchmarkArgs) -> dict[str, Any]:
    """The flags as a JSON-friendly dict (paths as strings)."""
    return {k: (str(v) if isinstance(v, os.PathLike) else v) for k, v in asdict(args).items()}
