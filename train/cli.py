"""The ``gnn-mp`` command: one entry point, subcommands dispatch to modules.

    gnn-mp samplers                       # registered samplers with descriptions
    gnn-mp benchmark --task maze2d --samplers uniform,goal-bias --problems 20 --seed 0
    gnn-mp benchmark --suite default --out results/     # what `make benchmark` runs
    gnn-mp critical {train,evaluate,generate-data} [args]              (train.critical)
    gnn-mp train critical [args]          # = gnn-mp critical train [args]
    gnn-mp train sampler --task maze2d --model gnn       # learned tree sampler (train.tree)
    gnn-mp train rl --algo ppo --lib sb3 --task maze2d   # RL sampler          (train.rl)

Speed probes live outside the package: ``python -m tools.bench_env``, ``tools.bench_sampler``,
``tools.bench_arm``, ``tools.tune_proposals``.

Bad input exits with status 2 and one line on stderr (no traceback): every entry point's errors of
that kind are a :class:`train.args.UsageError`.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import Callable, Sequence

from agents.registry import LEARNED_MODULES, missing_extra_message
from train.args import OneLineParser, UsageError, add_dataclass_arguments, from_namespace

PROG = "gnn-mp"

#: Subcommands handled by another module's ``main(argv)``; imported only when used.
PASSTHROUGH: dict[str, tuple[str, str]] = {
    "critical": ("train.critical", "critical samples: train / evaluate / generate-data"),
}
#: ``gnn-mp train NAME ...`` -> (module, argv prefix).
TRAIN_TARGETS: dict[str, tuple[str, list[str]]] = {
    "critical": ("train.critical", ["train"]),
    "sampler": ("train.tree.cli", []),
    "rl": ("train.rl.cli", []),
}
TRAIN_HELP = {"critical": "critical-sample models on the fixed Halton graph (GNN, GAT, GNN-CVAE, CNN, CVAE)",
              "sampler": "learned tree samplers, the paper's Algorithm 1 (GNN, CVAE, GNN-CVAE)",
              "rl": "RL samplers: SB3 PPO/SAC, TorchRL PPO over the tree view (docs/rl.md)"}


class CLIError(UsageError):
    """A subcommand that cannot be loaded (not in this checkout, an extra not installed): one line, exit
    status 2."""


def exit_now(code: int) -> None:
    """Leave at once after Ctrl-C: outputs are already written (atomically), and tearing down
    torch and friends can take seconds on a busy machine. Worker processes still running
    (a TorchRL ParallelEnv's, an SB3 SubprocVecEnv's) are killed first: they ignore Ctrl-C
    (see ``train.rl.torchrl``), so nothing else would stop them; a Ray instance this process runs
    (``--ray``) is shut down (its agents would outlive the process)."""
    import gc
    import multiprocessing
    from multiprocessing import util
    for child in multiprocessing.active_children():
        child.kill()
    ray = sys.modules.get("ray")
    if ray is not None and getattr(ray, "is_initialized", lambda: False)():
        try:
            ray.shutdown()
        except Exception:       # already half torn down: leaving is what matters
            pass
    gc.collect()                # drop the killed pool's queues ...
    util._run_finalizers()      # ... and release their semaphores (else the resource tracker warns)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def fail(message: str, code: int = 2):
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return code


# ---------------------------------------------------------------------------- parsers
def terminate_as_interrupt() -> None:
    """SIGTERM (a scheduler's stop, ``kill``) ends a benchmark or a training run like Ctrl-C: the
    finished runs are written (``"partial": true``), the worker processes (a benchmark's, an SB3
    SubprocVecEnv's, a TorchRL ParallelEnv's) stopped, one line said, instead of dying without a word
    and leaving each worker to print the traceback of its broken pipe."""
    import signal

    def interrupt(signum, frame):
        raise KeyboardInterrupt
    try:
        signal.signal(signal.SIGTERM, interrupt)
    except ValueError:       # not the main thread (an embedding application): leave it
        pass


def package_version() -> str:
    """The installed ``gnn-mp-envs`` version (a checkout that is not installed: ``unknown``)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("gnn-mp-envs")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    from train.benchmark.args import BenchmarkArgs
    from train.benchmark.suites import SuiteOptions

    parser = OneLineParser(prog=PROG, description="Sampling-based motion planning environments and "
                           "sampler benchmarks (Khan et al. 2020, 'Graph Neural Networks for Motion Planning').")
    parser.add_argument("--version", action="version", version=f"{PROG} {package_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)

    sub.add_parser("samplers", help="list the registered samplers with descriptions")

    bench = sub.add_parser("benchmark", help="run samplers on the same held-out problems and compare",
                           description="Run every sampler on the same held-out (split='test') problems "
                           "and seeds; print success rate and median [q25, q75] of the planner's counters.")
    add_dataclass_arguments(bench, BenchmarkArgs)
    add_dataclass_arguments(bench, SuiteOptions)

    for name, (module, help_text) in PASSTHROUGH.items():
        sub.add_parser(name, help=f"{help_text} ({module}.main; arguments are passed through)", add_help=False)
    train = sub.add_parser("train", help="train a model: `gnn-mp train {sampler,rl,critical} ...`", add_help=False)
    train.add_argument("target", nargs="?", choices=sorted(TRAIN_TARGETS))
    return parser


# ---------------------------------------------------------------------------- commands
def cmd_samplers() -> int:
    from agents.registry import SAMPLERS, available_samplers, descriptions, missing_learned_modules
    from gnn_mp_envs.baselines.ompl_runner import ompl_available
    from gnn_mp_envs.registration import TASK_SPECS
    from train.benchmark.args import OMPL_PREFIX
    names = available_samplers()
    about = descriptions()
    missing = missing_learned_modules()
    width = max(len(n) for n in names + ["ompl-rrtconnect"])
    for name in names:
        note = " (needs the 'agents' extra)" if missing and SAMPLERS[name].learned else ""
        print(f"{name.ljust(width)}  {about.get(name, '')}{note}")
    planner_tasks: dict[str, list[str]] = {}
    for task, spec in TASK_SPECS.items():
        for planner in spec.ompl_planners:
            planner_tasks.setdefault(planner, []).append(task)
    status = "installed" if ompl_available() else "needs `pip install 'gnn-mp-envs[ompl]'`"
    for planner, tasks in planner_tasks.items():
        print(f"{(OMPL_PREFIX + planner).ljust(width)}  OMPL {planner} baseline for {', '.join(tasks)} "
              f"(isolated runner; {status})")
    return 0


#: One-task flags a suite would not use (it keeps --seed, --workers, --render and --import).
SUITE_IGNORED = ("task", "samplers", "problems", "split", "max_nodes", "scene", "checker", "ray", "json", "plot",
                 "ompl_log", "ompl_time_limit", "checkpoints", "settings", "success_plot", "save_paths", "recheck")


def cmd_benchmark(ns: argparse.Namespace) -> int:
    from train import benchmark as bm
    from train.benchmark.suites import SuiteOptions
    try:
        args = from_namespace(bm.BenchmarkArgs, ns)
    except ValueError as exc:        # e.g. --checkpoint repeated for one sampler
        raise UsageError(str(exc)) from None
    terminate_as_interrupt()
    suite = from_namespace(SuiteOptions, ns)
    if suite.suite is None and (suite.out is not None or not suite.ompl or not suite.vamp or not suite.render_images):
        # a one-task run writes only what --json / --plot / --render ask for: refuse rather than write nothing
        raise UsageError("--out, --no-ompl, --no-vamp and --no-render apply to --suite only; for one task give "
                         "--json FILE, --plot FILE or --render DIR (OMPL rows: --samplers ompl-rrt,...)")
    if suite.suite is not None:
        # a suite names its own tasks, samplers, problems and outputs: refuse one task's flags, not ignore them
        import dataclasses
        defaults = bm.BenchmarkArgs()
        ignored = [f"--{f.name.replace('_', '-')}".replace("--checkpoints", "--checkpoint").replace("--settings",
                                                                                                      "--setting")
                   .replace("--recheck", "--no-recheck")
                   for f in dataclasses.fields(bm.BenchmarkArgs)
                   if f.name in SUITE_IGNORED and getattr(args, f.name) != getattr(defaults, f.name)]
        if ignored:
            raise UsageError(f"--suite {suite.suite} plans its own tasks, samplers, problems and outputs; "
                             f"{', '.join(ignored)} apply to one task (drop --suite or those flags)")
    try:
        if suite.suite is not None:
            out = suite.out or SuiteOptions.DEFAULT_OUT
            renders = (args.render or out / "renders") if suite.render_images else None
            bm.run_suite(suite.suite, out, seed=args.seed, workers=args.workers, progress=args.progress,
                         with_ompl=None if suite.ompl else False, render=renders,
                         with_vamp=None if suite.vamp else False)
            return 0
        bm.benchmark(args)
    except bm.BenchmarkIncomplete as exc:      # not a usage error: exit 1 (130: interrupted)
        code = fail(f"benchmark: {exc}", 130 if exc.interrupted else 1)
        if exc.interrupted:
            exit_now(code)
        return code
    return 0


#: Top-level modules of the ``agents`` extra (torch and the libraries built on it).
EXTRA_MODULES = (*LEARNED_MODULES, "stable_baselines3", "torchrl", "tensorboard", "yaml")


def missing_extra(exc: ModuleNotFoundError, what: str) -> CLIError | None:
    """A one-line CLIError when ``exc`` is a module of the agents extra (an environments-only install)."""
    top = (exc.name or "").split(".")[0]
    if top not in EXTRA_MODULES:
        return None
    return CLIError(missing_extra_message(what, [top]))


def load_module_main(module: str) -> Callable[[list[str]], int | None]:
    """``module.main``, or a CLIError if the module is not part of this checkout."""
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
            raise CLIError(f"{module} is not available in this checkout") from None
        raise missing_extra(exc, module) or CLIError(f"{module} cannot be imported: {exc}") from None
    except ImportError as exc:
        raise CLIError(f"{module} cannot be imported: {exc}") from None
    main_fn = getattr(mod, "main", None)
    if main_fn is None:
        raise CLIError(f"{module} has no main(argv)")
    return main_fn


def run_passthrough(module: str, argv: list[str], prog: str) -> int:
    """Call ``module.main(argv)``; its argparse usage lines read ``prog`` (e.g. ``gnn-mp critical``)."""
    main_fn = load_module_main(module)
    saved_argv0, sys.argv[0] = sys.argv[0], prog
    try:
        code = main_fn(argv)
    except ModuleNotFoundError as exc:
        raise missing_extra(exc, prog) or exc from None
    finally:
        sys.argv[0] = saved_argv0
    return int(code or 0)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = ""        # a subcommand's one-line errors name it: "gnn-mp: error: benchmark: ..."
    try:
        if argv and argv[0] in PASSTHROUGH:
            return run_passthrough(PASSTHROUGH[argv[0]][0], argv[1:], f"{PROG} {argv[0]}")
        if argv and argv[0] == "train":
            if len(argv) < 2 or argv[1] in ("-h", "--help"):
                print(f"usage: {PROG} train {{{','.join(sorted(TRAIN_TARGETS))}}} [--help | ARGS]\n\n"
                      "Train a model; `gnn-mp train TARGET --help` lists its flags.\n")
                for name, (module, _) in sorted(TRAIN_TARGETS.items()):
                    print(f"  {name:<10} {TRAIN_HELP.get(name, module)}")
                return 0 if len(argv) > 1 else 2
            if argv[1] not in TRAIN_TARGETS:
                got = repr(argv[1]) if len(argv) > 1 else "nothing"
                return fail(f"train: expected one of {', '.join(sorted(TRAIN_TARGETS))}, got {got}")
            module, prefix = TRAIN_TARGETS[argv[1]]
            terminate_as_interrupt()     # a stopped training run: one line, its worker processes killed
            # `train critical` is `critical train`: name the command its usage lines show
            prog = f"{PROG} {argv[1]}" if prefix else f"{PROG} train {argv[1]}"
            return run_passthrough(module, prefix + argv[2:], prog)
        parser = build_parser()
        ns = parser.parse_args(argv)
        if ns.command is None:
            parser.print_help()
            return 2
        if ns.command == "samplers":
            return cmd_samplers()
        if ns.command == "benchmark":
            command = "benchmark: "
            return cmd_benchmark(ns)
        return fail(f"unknown command {ns.command!r}")
    except KeyboardInterrupt:
        exit_now(fail("interrupted", 130))
    except Exception as exc:
        if raised_by_an_interrupt(exc):   # library code that turned the KeyboardInterrupt into its own error
            exit_now(fail("interrupted", 130))
        if isinstance(exc, UsageError):   # every usage error (CLIError, BenchmarkError, a shared check's): exit 2
            return fail(f"{command}{exc}")
        if isinstance(exc, OSError):      # unreadable / unwritable files from any subcommand
            return fail(f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))
        if out_of_memory(exc):            # sizes the up-front checks let through, past what this process may use
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            return fail(f"{command}out of memory ({first[:200]}): lower the sizes or counts")
        raise


def out_of_memory(exc: BaseException) -> bool:
    """A failed allocation: numpy's or Python's ``MemoryError``, torch's allocator's ``RuntimeError``
    ("can't allocate memory"), or one raised while handling either."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, MemoryError) or (isinstance(exc, RuntimeError) and "can't allocate memory" in str(exc)):
            return True
        seen.add(id(exc))
        exc = exc.__context__
    return False


def raised_by_an_interrupt(exc: BaseException) -> bool:
    """Was ``exc`` raised while a KeyboardInterrupt (Ctrl-C, or SIGTERM: :func:`terminate_as_interrupt`)
    was being handled? A library's cleanup can answer the interrupt with an error of its own (TorchRL's
    PPO loss: "Converting a tensordict to boolean value is not permitted"): the run was stopped all the
    same, and says so in one line."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__context__
    return False


if __name__ == "__main__":
    sys.exit(main())
