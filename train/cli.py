"""The ``gnn-mp`` command: one entry point, subcommands dispatch to modules.

    gnn-mp samplers                       # registered samplers with descriptions
    gnn-mp benchmark --task maze2d --samplers uniform,goal-bias --problems 20 --seed 0
    gnn-mp benchmark --suite default --out results/     # what `make benchmark` runs
    gnn-mp bench-env [args]               # env steps/s at tree sizes   (train.bench_env)
    gnn-mp bench-arm [args]               # arm planning benchmark      (train.bench_arm)
    gnn-mp critical {train,evaluate,generate-data} [args]              (train.critical)
    gnn-mp train critical [args]          # = gnn-mp critical train [args]

Bad input exits with status 2 and one line on stderr (no traceback).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import Callable, Sequence

from train.args import OneLineParser

PROG = "gnn-mp"

#: Subcommands handled by another module's ``main(argv)``; imported only when used.
PASSTHROUGH: dict[str, tuple[str, str]] = {
    "bench-env": ("train.bench_env", "environment steps/s at several tree sizes"),
    "bench-arm": ("train.bench_arm", "arm planning benchmark"),
    "bench-sampler": ("train.bench_sampler", "sampler speed: to_pyg conversions/s, act() us per call"),
    "critical": ("train.critical", "critical samples: train / evaluate / generate-data"),
}
#: ``gnn-mp train NAME ...`` -> (module, argv prefix).
TRAIN_TARGETS: dict[str, tuple[str, list[str]]] = {
    "critical": ("train.critical", ["train"]),
}


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def fail(message: str, code: int = 2):
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return code


# ---------------------------------------------------------------------------- argument types
def _bounded(cast: Callable[[str], float], minimum: float, strict: bool, noun: str) -> Callable[[str], float]:
    """An argparse type: ``cast(text)`` that must be ``> minimum`` (strict) or ``>= minimum``."""
    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if not (value > minimum if strict else value >= minimum):  # also rejects NaN
            raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {minimum}, got {value}")
        return value
    parse.__name__ = noun
    return parse


positive_int = _bounded(int, 1, False, "a positive integer")
non_negative_int = _bounded(int, 0, False, "a non-negative integer")
positive_float = _bounded(float, 0, True, "a positive number")


def checkpoint_pair(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        raise argparse.ArgumentTypeError(f"expected SAMPLER=PATH, got {text!r}")
    return name.strip(), Path(path)


def name_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of sampler names")
    return names


# ---------------------------------------------------------------------------- parsers
def build_parser() -> argparse.ArgumentParser:
    from gnn_mp_envs.registration import TASK_ENV_IDS

    parser = OneLineParser(prog=PROG, description="Sampling-based motion planning environments and "
                           "sampler benchmarks (Khan et al. 2020, 'Graph Neural Networks for Motion Planning').")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)

    sub.add_parser("samplers", help="list the registered samplers with descriptions")

    bench = sub.add_parser("benchmark", help="run samplers on the same held-out problems and compare",
                           description="Run every sampler on the same held-out (split='test') problems "
                           "and seeds; print success rate and median [q25, q75] of the planner's counters.")
    bench.add_argument("--task", choices=sorted(TASK_ENV_IDS), default="maze2d", help="task family")
    bench.add_argument("--samplers", type=name_list, default=["uniform", "goal-bias"],
                       help="comma-separated sampler names (see `gnn-mp samplers`; OMPL rows: "
                       "ompl-rrtconnect for maze2d/arm, ompl-rrt / ompl-kpiece for the pendulum)")
    bench.add_argument("--problems", type=positive_int, default=20, help="held-out problems 0..N-1")
    bench.add_argument("--seed", type=non_negative_int, default=0,
                       help="root seed; problem i's sampler seed is derived from (seed, i)")
    bench.add_argument("--max-nodes", type=positive_int, default=None,
                       help="tree node budget (default: the environment's)")
    bench.add_argument("--scene", default=None, help="arm scene (task_kwargs scene=...), e.g. test")
    bench.add_argument("--workers", type=positive_int, default=1, help="worker processes over problems")
    bench.add_argument("--json", type=Path, default=None, help="write the results as JSON (docs/results.md)")
    bench.add_argument("--plot", type=Path, default=None, help="write box plots (PNG)")
    bench.add_argument("--render", type=Path, default=None, metavar="DIR",
                       help="write tree-growth images of problem 0 for each sampler")
    bench.add_argument("--ompl-log", type=Path, default=None, metavar="DIR",
                       help="write an OMPL benchmark log (Planner Arena) to DIR/<task>.log")
    bench.add_argument("--ompl-time-limit", type=positive_float, default=10.0,
                       help="seconds per problem for OMPL rows")
    bench.add_argument("--checkpoint", action="append", type=checkpoint_pair, default=[],
                       metavar="SAMPLER=PATH", help="checkpoint of a learned sampler (repeatable)")
    bench.add_argument("--sampler-module", action="append", default=[], metavar="MODULE",
                       help="import MODULE first (it calls register_sampler); repeatable")
    bench.add_argument("--suite", default=None, help="run a named suite instead (e.g. default, smoke); "
                       "writes <task>.json/.png/.txt and summary.md to --out")
    bench.add_argument("--out", type=Path, default=Path("results"), help="output directory of --suite")
    bench.add_argument("--no-ompl", action="store_true", help="--suite: skip OMPL rows even if installed")
    bench.add_argument("--no-render", action="store_true", help="--suite: skip tree-growth images")
    bench.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    for name, (module, help_text) in PASSTHROUGH.items():
        sub.add_parser(name, help=f"{help_text} ({module}.main; arguments are passed through)", add_help=False)
    train = sub.add_parser("train", help="train a model: `gnn-mp train critical ...`", add_help=False)
    train.add_argument("target", nargs="?", choices=sorted(TRAIN_TARGETS))
    return parser


# ---------------------------------------------------------------------------- commands
def cmd_samplers() -> int:
    from agents.samplers import DESCRIPTIONS, available_samplers
    from train.benchmark import OMPL_PLANNERS, OMPL_PREFIX
    names = available_samplers()
    width = max(len(n) for n in names + ["ompl-rrtconnect"])
    for name in names:
        print(f"{name.ljust(width)}  {DESCRIPTIONS.get(name, '')}")
    planner_tasks: dict[str, list[str]] = {}
    for task, planners in OMPL_PLANNERS.items():
        for planner in planners:
            planner_tasks.setdefault(planner, []).append(task)
    for planner, tasks in planner_tasks.items():
        print(f"{(OMPL_PREFIX + planner).ljust(width)}  OMPL {planner} baseline for {', '.join(tasks)} "
              f"(isolated runner; needs `pip install -e .[ompl]`)")
    return 0


def cmd_benchmark(ns: argparse.Namespace) -> int:
    from train import benchmark as bm
    progress = not ns.no_progress
    try:
        if ns.suite is not None:
            bm.run_suite(ns.suite, ns.out, seed=ns.seed, workers=ns.workers, progress=progress,
                         with_ompl=False if ns.no_ompl else None, render=not ns.no_render)
            return 0
        args = bm.BenchmarkArgs(task=ns.task, samplers=ns.samplers, problems=ns.problems, seed=ns.seed,
                                max_nodes=ns.max_nodes, scene=ns.scene, workers=ns.workers, json=ns.json,
                                plot=ns.plot, render=ns.render, ompl_log=ns.ompl_log,
                                ompl_time_limit=ns.ompl_time_limit, checkpoints=dict(ns.checkpoint),
                                sampler_modules=ns.sampler_module,
                                progress=progress)
        bm.benchmark(args)
    except bm.BenchmarkError as exc:
        return fail(f"benchmark: {exc}")
    return 0


def load_module_main(module: str) -> Callable[[list[str]], int | None]:
    """``module.main``, or a CLIError if the module is not part of this checkout."""
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
            raise CLIError(f"{module} is not available in this checkout") from None
        raise CLIError(f"{module} cannot be imported: {exc}") from None
    except ImportError as exc:
        raise CLIError(f"{module} cannot be imported: {exc}") from None
    main_fn = getattr(mod, "main", None)
    if main_fn is None:
        raise CLIError(f"{module} has no main(argv)")
    return main_fn


def run_passthrough(module: str, argv: list[str], prog: str) -> int:
    """Call ``module.main(argv)``; its argparse usage lines read ``prog`` (e.g. ``gnn-mp bench-env``)."""
    main_fn = load_module_main(module)
    saved_argv0, sys.argv[0] = sys.argv[0], prog
    try:
        code = main_fn(argv)
    finally:
        sys.argv[0] = saved_argv0
    return int(code or 0)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in PASSTHROUGH:
            return run_passthrough(PASSTHROUGH[argv[0]][0], argv[1:], f"{PROG} {argv[0]}")
        if argv and argv[0] == "train":
            if len(argv) < 2 or argv[1] not in TRAIN_TARGETS:
                got = repr(argv[1]) if len(argv) > 1 else "nothing"
                return fail(f"train: expected one of {', '.join(sorted(TRAIN_TARGETS))}, got {got}")
            module, prefix = TRAIN_TARGETS[argv[1]]
            return run_passthrough(module, prefix + argv[2:], PROG)
        parser = build_parser()
        ns = parser.parse_args(argv)
        if ns.command is None:
            parser.print_help()
            return 2
        if ns.command == "samplers":
            return cmd_samplers()
        if ns.command == "benchmark":
            return cmd_benchmark(ns)
        return fail(f"unknown command {ns.command!r}")
    except CLIError as exc:
        return fail(str(exc))
    except KeyboardInterrupt:
        return fail("interrupted", 130)
    except OSError as exc:   # unreadable / unwritable files from any subcommand
        return fail(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))


if __name__ == "__main__":
    sys.exit(main())
