"""The benchmark's flags (one dataclass, the single source of the command line) and their checks."""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from gnn_mp_envs.evaluation import MAX_SEED
from gnn_mp_envs.registration import BUILTIN_TASKS
from gnn_mp_envs.robots.checkers import checker_name
from train.args import import_modules as import_plugins
from train.args import (UsageError, arg, check_output_path, check_ray_address, figure_path, name_list, non_negative_int,
                        positive_float, positive_int, seed_int, worker_count)

#: Prefix of OMPL planner rows; the rest of the name is the OMPL planner.
OMPL_PREFIX = "ompl-"
OMPL_INSTALL_HINT = ("OMPL is not installed; install the optional extra with `pip install 'gnn-mp-envs[ompl]'` "
                     "(in a checkout: `pip install -e '.[ompl]'`)")
#: Prefix of VAMP's rows (gnn_mp_envs/baselines/vamp_runner.py); the rest of the name is VAMP's planner.
VAMP_PREFIX = "vamp-"


class BenchmarkError(UsageError):
    """A user-facing error of the benchmark (bad flags, unknown names, missing files, a failing
    sampler): printed as one line."""


def checkpoint_pair(text: str) -> tuple[str, Path]:
    """``SAMPLER=PATH`` of ``--checkpoint``."""
    import argparse
    name, sep, path = text.partition("=")
    if not sep or not name.strip() or not path:
        raise argparse.ArgumentTypeError(f"expected SAMPLER=PATH, got {text!r}")
    return name.strip(), Path(path)


def setting_triple(text: str) -> tuple[str, str, Any]:
    """``SAMPLER.KEY=VALUE`` of ``--setting`` (VALUE read as JSON when it parses: 8, 0.5, true)."""
    import argparse
    import json as _json
    target, sep, raw = text.partition("=")
    name, dot, key = target.rpartition(".")
    if not sep or not dot or not name.strip() or not key.strip() or not raw:
        raise argparse.ArgumentTypeError(f"expected SAMPLER.KEY=VALUE, got {text!r}")
    try:
        value = _json.loads(raw)
    except ValueError:
        value = raw
    return name.strip(), key.strip(), value


#: Problems per benchmark row at most: a job list and its records stay in memory (about 1 kB a run).
MAX_PROBLEMS = 1_000_000


def time_limits_help() -> str:
    """Each built-in task's time budget (``TaskSpec.time_limit_s``), grouped: ``10 s for maze2d, ...``."""
    groups: dict[float, list[str]] = {}
    for spec in BUILTIN_TASKS:
        groups.setdefault(spec.time_limit_s, []).append(spec.name)
    return "; ".join(f"{limit:g} s for {', '.join(names)}" for limit, names in groups.items())


def builtin_tasks(where=lambda spec: True) -> str:
    """The built-in tasks (``gnn_mp_envs.registration.BUILTIN_TASKS``) ``where`` holds, for help texts."""
    return ", ".join(spec.name for spec in BUILTIN_TASKS if where(spec))


def ompl_rows_help() -> str:
    """The OMPL rows of each built-in task, grouped: ``ompl-rrtconnect / ompl-rrt for maze2d, arm, ...``."""
    groups: dict[tuple[str, ...], list[str]] = {}
    for spec in BUILTIN_TASKS:
        if spec.ompl_planners:
            groups.setdefault(spec.ompl_planners, []).append(spec.name)
    return "; ".join(" / ".join(OMPL_PREFIX + p for p in planners) + " for " + ", ".join(names)
                     for planners, names in groups.items())


@dataclass
class BenchmarkArgs:
    """Flags of one benchmark run (one task, several samplers)."""

    task: str = arg("maze2d", f"task family (built in: {builtin_tasks()}; --import adds others)")
    samplers: list[str] = arg(["uniform", "goal-bias"], "comma-separated sampler names (see `gnn-mp samplers`; OMPL "
                              f"rows: {ompl_rows_help()})", parse=name_list)
    problems: int = arg(20, "problems 0..N-1 of --split", parse=positive_int)
    split: str = arg("test", "problem split: test (held out, what results report) or val (for tuning)",
                     choices=("val", "test"))
    seed: int = arg(0, "root seed; problem i's sampler seed is derived from (seed, i)", parse=seed_int)
    max_nodes: int | None = arg(None, "tree node budget (default: the environment's)", parse=positive_int)
    scene: str | None = arg(None, f"scene family of a task with scenes ({builtin_tasks(lambda s: s.scenes)}; "
                            "default: the task's benchmark family, the held-out one where it has one)")
    checker: str | None = arg(None, f"collision checker of a task with several ({builtin_tasks(lambda s: s.checkers)}: "
                              "spheres or pybullet; default: the task's first); OMPL rows use the same")
    balance: bool = arg(False, "balance BiRRT's two trees as VAMP's RRT-Connect does (the next sample extends the "
                        "smaller tree while the other holds twice its nodes; tasks planned with BiRRT)")
    workers: int = arg(1, "worker processes over problems (with --ray: Ray actors); at most one per job",
                       parse=worker_count)
    ray: str | None = arg(None, "run the jobs as Ray actors: no ADDRESS starts a local Ray instance with "
                          "--workers CPUs; 'auto' or ray://HOST:10001 joins a running cluster (pip install "
                          "'gnn-mp-envs[ray]')", metavar="ADDRESS", const="local")
    json: Path | None = arg(None, "write the results as JSON (schema: docs/results.md)")
    plot: Path | None = arg(None, "write box plots (the suffix names the format: .png, .svg, .pdf)",
                            parse=figure_path)
    render: Path | None = arg(None, "write tree-growth images of problem 0 for each sampler", metavar="DIR")
    ompl_log: Path | None = arg(None, "write an OMPL benchmark log (Planner Arena) to DIR/<task>.log",
                                metavar="DIR")
    success_plot: Path | None = arg(None, "write the success-vs-time figure: the share of problems solved by each "
                                    "time budget, a curve per row (Planner Arena's progress view)", parse=figure_path,
                                    metavar="FILE")
    save_paths: bool = arg(False, "store each solved run's returned path in --json (its states, and the controls "
                           "of a kinodynamic task's edges)")
    recheck: bool = arg(True, "skip re-checking the returned paths (the longest phase with pybullet): success is "
                        "then the planner's word, unverified, and marked so in the table and --json")
    ompl_time_limit: float | None = arg(None, "seconds per problem: OMPL's solve limit (an OMPL row's success) and "
                                        "the axis of the success-vs-time figure (default: the task's: "
                                        f"{time_limits_help()})",
                                        parse=positive_float)
    checkpoints: dict[str, Path] = arg({}, "checkpoint of a learned sampler (repeatable): a .pt, or the SB3 .zip of a "
                                       "gnn-mp train rl run (read weights only, rebuilt from the run's config.json beside it); "
                                       "a SAMPLER that is no registered name is a row of its own, run by the sampler of "
                                       "the file's kind (--samplers uniform,rl-ppo,mine --checkpoint mine=PATH)",
                                       flag="--checkpoint", metavar="SAMPLER=PATH", parse=checkpoint_pair,
                                       append=True)
    settings: list[tuple] = arg([], "a sampler setting instead of the one stored with its weights, e.g. "
                                "gnn.proposals=1 or goal-bias.goal_bias=0.1 (repeatable)", flag="--setting",
                                metavar="SAMPLER.KEY=VALUE", parse=setting_triple, append=True)
    modules: list[str] = arg([], "import MODULE first: it registers samplers or tasks (repeatable)",
                             flag=("--import", "--sampler-module"), metavar="MODULE", append=True)
    progress: bool = arg(True, "hide the progress bar")

    def sampler_settings(self, name: str) -> tuple[tuple[str, Any], ...]:
        """The ``--setting`` values of sampler ``name``, sorted (hashable: part of a job)."""
        return tuple(sorted((key, value) for sampler, key, value in self.settings if sampler == name))

    def as_dict(self) -> dict[str, Any]:
        """The flags as a JSON-friendly dict (paths as strings)."""
        return {k: (str(v) if isinstance(v, os.PathLike) else v) for k, v in asdict(self).items()}


# ---------------------------------------------------------------------------- set-up
def task_spec_for(task: str):
    from gnn_mp_envs.registration import task_spec
    try:
        return task_spec(task)
    except ValueError as exc:
        raise BenchmarkError(str(exc)) from None


def env_kwargs_for(args: BenchmarkArgs) -> dict[str, Any]:
    """Keyword arguments of :func:`gnn_mp_envs.evaluation.evaluation_env` for the benchmark env."""
    kwargs: dict[str, Any] = {"split": args.split}
    if args.max_nodes is not None:
        kwargs["max_nodes"] = int(args.max_nodes)
    if args.scene is not None:
        kwargs["scene"] = args.scene
    if args.checker is not None:
        kwargs["checker"] = args.checker
    if args.balance:
        kwargs["balance"] = True
    return kwargs


def is_ompl(name: str) -> bool:
    return name.startswith(OMPL_PREFIX)


def ompl_rows_for(task: str) -> list[str]:
    """The OMPL row names a task can run."""
    return [OMPL_PREFIX + p for p in task_spec_for(task).ompl_planners]


def is_vamp(name: str) -> bool:
    return name.startswith(VAMP_PREFIX)


def is_external(name: str) -> bool:
    """A row planned by another planner through an isolated runner (OMPL's, VAMP's): no sampler of ours."""
    return is_ompl(name) or is_vamp(name)


def vamp_rows_for(task: str) -> list[str]:
    """VAMP's row names for ``task``: its planners where VAMP has the task's robot (the MotionBenchMaker tasks)."""
    from gnn_mp_envs.baselines.vamp_runner import VAMP_PLANNERS, VAMP_ROBOTS
    return [VAMP_PREFIX + p for p in VAMP_PLANNERS] if task in VAMP_ROBOTS else []


def vamp_hint() -> str:
    """The one line that refuses a VAMP row where VAMP is not importable."""
    from gnn_mp_envs.baselines.vamp_runner import INSTALL_HINT
    return INSTALL_HINT


def known_sampler_names(task: str) -> list[str]:
    from agents.samplers import available_samplers
    return available_samplers() + ompl_rows_for(task) + vamp_rows_for(task)


def import_modules(modules: list[str]) -> None:
    """:func:`train.args.import_modules` (in the main process and in every worker), a
    :class:`BenchmarkError` when one cannot be imported."""
    try:
        import_plugins(modules)
    except ValueError as exc:
        raise BenchmarkError(str(exc)) from None


def time_limit_s(args: BenchmarkArgs) -> float:
    """The run's time budget: ``--ompl-time-limit``, else the task's (``TaskSpec.time_limit_s``; a
    validated ``args`` holds it)."""
    if args.ompl_time_limit is not None:
        return float(args.ompl_time_limit)
    return float(task_spec_for(args.task).time_limit_s)


def validate_args(args: BenchmarkArgs) -> None:
    """Reject bad flags before any planning starts (one-line messages); fills in the default scene."""
    import_modules(args.modules)
    spec = task_spec_for(args.task)
    if args.scene is not None and not spec.scenes:
        with_scenes = sorted(n for n, s in _specs().items() if s.scenes)
        raise BenchmarkError(f"--scene applies to {', '.join(with_scenes)} only, not {args.task!r}")
    if args.scene is not None and args.scene not in spec.scenes:
        raise BenchmarkError(f"unknown scene {args.scene!r} for {args.task}; known: {', '.join(spec.scenes)}")
    if args.scene is None:
        args.scene = spec.benchmark_scene   # the held-out family, for both splits
    if args.checker is not None and not spec.checkers:
        raise BenchmarkError(f"--checker {args.checker!r}: {args.task} has one checker only, named by no flag")
    if spec.checkers:
        try:
            args.checker = checker_name(args.checker or spec.checkers[0])
        except ValueError as exc:
            raise BenchmarkError(f"--checker: {exc}") from None
    if args.balance and spec.planner() != "birrt":
        raise BenchmarkError(f"--balance applies to BiRRT's two trees; {args.task} is planned with {spec.planner()}")
    if not 1 <= args.problems <= MAX_PROBLEMS:
        raise BenchmarkError(f"--problems must be in [1, {MAX_PROBLEMS:,}], got {args.problems}")
    if not 0 <= args.seed < MAX_SEED:
        raise BenchmarkError(f"--seed must be in [0, {MAX_SEED - 1}], got {args.seed}")
    if args.workers < 1:
        raise BenchmarkError(f"--workers must be >= 1, got {args.workers}")
    if args.max_nodes is not None and args.max_nodes < 2:
        raise BenchmarkError(f"--max-nodes must be >= 2, got {args.max_nodes}")
    args.ompl_time_limit = time_limit_s(args)
    if not args.ompl_time_limit > 0:
        raise BenchmarkError(f"--ompl-time-limit must be > 0, got {args.ompl_time_limit}")
    if not args.samplers:
        raise BenchmarkError("--samplers is empty")
    if len(set(args.samplers)) != len(args.samplers):
        raise BenchmarkError(f"--samplers lists a name twice: {','.join(args.samplers)}")
    known = known_sampler_names(args.task)
    for name in args.samplers:
        if is_ompl(name) and name not in known:
            supported = ", ".join(ompl_rows_for(args.task)) or "none"
            raise BenchmarkError(f"OMPL planner {name!r} is not available for task {args.task!r} "
                                 f"(supported: {supported})")
        if is_vamp(name) and name not in known:
            from gnn_mp_envs.baselines.vamp_runner import VAMP_PLANNERS, VAMP_ROBOTS
            raise BenchmarkError(f"VAMP row {name!r} is not available for task {args.task!r} (VAMP's rows: "
                                 f"{', '.join(VAMP_PREFIX + p for p in VAMP_PLANNERS)}, for "
                                 f"{', '.join(VAMP_ROBOTS)})")
        if name not in known and not (name in args.checkpoints and not is_external(name)):   # else a row of its own
            raise BenchmarkError(f"unknown sampler {name!r}; known: {', '.join(known)} (a row of your own: "
                                 f"--checkpoint {name}=PATH)")
    for name, _, _ in args.settings:
        if name not in args.samplers or is_external(name):
            raise BenchmarkError(f"--setting given for {name!r}, which is not one of the --samplers")
    from agents.registry import SAMPLERS
    for name, path in args.checkpoints.items():
        if name not in args.samplers:
            raise BenchmarkError(f"--checkpoint given for {name!r}, which is not in --samplers")
        if is_external(name):
            raise BenchmarkError(f"--checkpoint given for {name!r}, which has no weights (another planner's row)")
        if name in SAMPLERS and not SAMPLERS[name].learned:
            raise BenchmarkError(f"--checkpoint given for {name!r}, which has no weights (a classical sampler)")
        if not Path(path).is_file():
            raise BenchmarkError(f"missing checkpoint for sampler {name!r}: {path} is not a file")
        if not os.access(path, os.R_OK):
            raise BenchmarkError(f"checkpoint of sampler {name!r} is not readable: {path}")
        if name not in SAMPLERS:                # a labelled row: the sampler that runs the file's kind
            from agents.registry import sampler_for_checkpoint
            try:
                sampler_for_checkpoint(path)
            except ValueError as exc:
                raise BenchmarkError(f"--checkpoint {name}={path}: {str(exc).splitlines()[0]}") from None
    if args.save_paths and args.json is None:
        raise BenchmarkError("--save-paths stores the paths in the --json report: give --json FILE too")
    for flag, path, is_dir in (("--json", args.json, False), ("--plot", args.plot, False),
                               ("--success-plot", args.success_plot, False),
                               ("--render", args.render, True), ("--ompl-log", args.ompl_log, True)):
        if path is not None:
            check_output_path(flag, Path(path), is_dir)
    if any(is_ompl(n) for n in args.samplers):
        check_ompl()
    if any(is_vamp(n) for n in args.samplers):
        check_vamp()
    if args.ray not in (None, "local"):
        check_ray_address(args.ray)


def _specs():
    from gnn_mp_envs.registration import TASK_SPECS
    return TASK_SPECS


def check_ompl() -> None:
    """Fail early (before any planning) when OMPL rows cannot run."""
    try:
        from gnn_mp_envs.baselines import ompl_runner
    except ImportError as exc:
        raise BenchmarkError(f"the OMPL runner is not available in this checkout ({exc})") from None
    if not ompl_runner.ompl_available():
        raise BenchmarkError(OMPL_INSTALL_HINT)


def check_vamp() -> None:
    """Fail early (before any planning) when no interpreter can run VAMP's rows (one line: how to get one)."""
    from gnn_mp_envs.baselines.vamp_runner import vamp_available
    if not vamp_available():
        raise BenchmarkError(vamp_hint())


def ompl_available() -> bool:
    """Whether the OMPL runner exists and OMPL's Python bindings can be imported."""
    try:
        check_ompl()
    except BenchmarkError:
        return False
    return True
