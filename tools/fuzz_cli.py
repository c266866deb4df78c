"""Feed bad values to every flag of every ``gnn-mp`` subcommand and count what goes wrong.

Each subcommand's flags are read from its own argparse parser (``gnn-mp benchmark``, ``train
sampler``, ``train rl``, ``critical generate-data|train|evaluate``); each flag gets values of the
kind it takes, turned bad: numbers negative, zero, huge (10**30), NaN, inf, empty, text, and the
largest value the flag accepts (its parser's bound: 10**9 for a count, 4,096 for a width, 256
workers, the last seed; where a bound that is not one shows); paths empty, a directory, a FIFO, a
character device node, a symlink, a missing directory; names empty, unknown, NaN, huge. Every
attempt is the subcommand with small budget flags (one problem, a few training steps) and the one
bad value, run in a subprocess of its own (its own session and scratch directory, a timeout, a
memory limit: ``--memory-gib`` of heap and private memory, ``RLIMIT_DATA``; at most ``--jobs`` at a
time), and counted:

- attempts;
- tracebacks: ``Traceback (most recent call last)`` in stderr (a bad value must be one line);
- hangs: attempts still running at the timeout (killed with their process group);
- non-regular files replaced: a FIFO, character device node or symlink given as a path that is not
  one any more afterwards (looked at with ``lstat`` only: this script never opens a FIFO).

The device node is the attempt's own, made in its scratch directory with ``mknod`` (the numbers of
``/dev/null``); where ``mknod`` is not permitted (not root) a Unix socket stands in. No attempt names
a path under ``/dev`` or any device of the machine (:func:`argv_of` refuses one): a regression of the
commands' refusal of device nodes replaces the attempt's node, never the machine's.

    python -m tools.fuzz_cli                                   # the full run: a few hundred attempts
    python -m tools.fuzz_cli --commands benchmark --max-attempts 20 --json fuzz.json

Prints the counts, then one line per finding (subcommand, flag, value, the last line of stderr);
exits 1 when there is any.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
HUGE = "1" + "0" * 30
#: The subprocess: the CLI's own entry point.
ENTRY = "import sys; from train.cli import main; sys.exit(main())"
#: The heap and private memory of each of an attempt's processes (``--memory-gib``, ``RLIMIT_DATA``:
#: what numpy and torch allocate; not the address space, which thread stacks and libraries reserve far
#: beyond what they use): a count that allocates beyond it is a MemoryError (a finding when it is a
#: traceback), not a machine out of memory.
MEMORY_GIB = 6.0
#: Destinations that name files or directories even where the parser takes a plain string.
PATH_DESTS = {"out", "json", "plot", "render", "ompl_log", "data", "data_dir", "checkpoints", "hyperparams",
              "prior", "init_from"}


@dataclass(frozen=True)
class Command:
    """A subcommand: its argv prefix, its parser and the budget flags that keep one attempt short
    (``{scratch}`` is the attempt's own directory, ``{data}`` the shared small critical dataset)."""

    name: str
    prefix: tuple[str, ...]
    parser: Callable[[], argparse.ArgumentParser]
    budget: tuple[str, ...]
    #: extra flags when fuzzing a SAMPLER=PATH flag: a sampler that takes the path
    pair_extra: tuple[str, ...] = ()


def _benchmark_parser() -> argparse.ArgumentParser:
    from train.cli import build_parser
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["benchmark"]


def _critical_parser(name: str) -> Callable[[], argparse.ArgumentParser]:
    def build() -> argparse.ArgumentParser:
        from train.critical.cli import build_parser
        sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
        return sub.choices[name]
    return build


def _train_sampler_parser() -> argparse.ArgumentParser:
    from train.tree.cli import build_parser
    return build_parser()


def _train_rl_parser() -> argparse.ArgumentParser:
    from train.rl.cli import build_parser
    return build_parser()


_CRITICAL_DATA = ("--data", "{data}", "--num-maps", "9", "--pairs-per-map", "1", "--eval-problems", "1")
COMMANDS: dict[str, Command] = {c.name: c for c in (
    Command("benchmark", ("benchmark",), _benchmark_parser,
            ("--task", "maze2d", "--samplers", "uniform", "--problems", "1", "--workers", "1", "--no-progress",
             "--json", "{scratch}/report.json"), pair_extra=("--samplers", "gnn")),
    Command("train sampler", ("train", "sampler"), _train_sampler_parser,
            ("--task", "maze2d", "--model", "gnn", "--problems", "4", "--minutes", "0.02", "--dagger-rounds", "0",
             "--eval-problems", "1", "--data-dir", "{scratch}/data", "--out", "{scratch}/run", "--no-progress")),
    Command("train rl", ("train", "rl"), _train_rl_parser,
            ("--task", "maze2d", "--hyperparams", "none", "--total-steps", "64", "--n-envs", "1", "--n-steps", "32",
             "--batch-size", "32", "--eval-problems", "1", "--eval-max-steps", "100", "--no-progress",
             "--out", "{scratch}/run")),
    Command("critical generate-data", ("critical", "generate-data"), _critical_parser("generate-data"),
            _CRITICAL_DATA),
    Command("critical train", ("critical", "train"), _critical_parser("train"),
            ("--model", "gnn", *_CRITICAL_DATA, "--epochs", "1", "--max-train-problems", "2",
             "--out", "{scratch}/run/critical_gnn.pt")),
    Command("critical evaluate", ("critical", "evaluate"), _critical_parser("evaluate"),
            ("--models", "gnn", "--checkpoints", str(ROOT / "agents" / "checkpoints"), *_CRITICAL_DATA,
             "--problems", "1", "--samples", "1", "--ks", "1", "--no-progress")),
)}


# ----------------------------------------------------------------------------- flags and values
@dataclass(frozen=True)
class Flag:
    command: str
    option: str
    dest: str
    kind: str          # number, path, pair, choice, text
    #: The largest value the flag's parser accepts (``train.args.bounded``'s ``maximum``), if it has one.
    maximum: str | None = None


def maximum_of(action: argparse.Action) -> str | None:
    """The largest value ``action`` accepts, as its parser states it (``parse.maximum``), as text."""
    bound = getattr(action.type, "maximum", None)
    if bound is None:
        return None
    return str(int(bound)) if float(bound).is_integer() else repr(float(bound))


def kind_of(action: argparse.Action) -> str | None:
    """What an option takes, from its parser: None for switches (no value to make bad)."""
    from train.args import figure_path, path_arg
    if action.nargs == 0:
        return None
    if action.choices:
        return "choice"
    parse = action.type
    if parse in (path_arg, figure_path) or parse is Path:
        return "path"
    try:
        sample = parse("1") if callable(parse) else "1"
    except (argparse.ArgumentTypeError, ValueError, TypeError):
        sample = None
    if action.dest == "checkpoints" and action.option_strings == ["--checkpoint"]:
        return "pair"
    if isinstance(sample, (int, float)) and not isinstance(sample, bool):
        return "number"
    if isinstance(sample, Path) or action.dest in PATH_DESTS:
        return "path"
    return "text"


def flags_of(command: Command) -> list[Flag]:
    out = []
    for action in command.parser()._actions:
        options = [o for o in action.option_strings if o.startswith("--")]
        if not options or options[0] in ("--help", "--version"):
            continue
        kind = kind_of(action)
        if kind is not None:
            out.append(Flag(command.name, max(options, key=len), action.dest, kind,
                            maximum_of(action) if kind == "number" else None))
    return out


#: label -> value (``{fifo}``, ``{chardev}``, ``{symlink}``, ``{dir}``, ``{missing}``: made per attempt, in its
#: scratch directory; never a device of the machine)
VALUES: dict[str, list[tuple[str, str]]] = {
    "number": [("negative", "-1"), ("zero", "0"), ("huge", HUGE), ("nan", "nan"), ("inf", "inf"), ("empty", ""),
               ("text", "abc")],
    "path": [("empty", ""), ("directory", "{dir}"), ("fifo", "{fifo}"), ("char device", "{chardev}"),
             ("symlink", "{symlink}"), ("missing", "{missing}")],
    "pair": [("empty", ""), ("no =", "abc"), ("directory", "gnn={dir}"), ("fifo", "gnn={fifo}"),
             ("char device", "gnn={chardev}"), ("missing", "gnn={missing}")],
    "choice": [("empty", ""), ("unknown", "no-such-value"), ("nan", "nan"), ("huge", HUGE)],
    "text": [("empty", ""), ("unknown", "no-such-value"), ("nan", "nan"), ("huge", HUGE), ("negative", "-1")],
}
#: Values that leave a node behind whose type is checked afterwards (a socket stands in for the device
#: node where ``mknod`` is not permitted).
SPECIAL = {"{fifo}": stat.S_ISFIFO, "{chardev}": stat.S_ISCHR, "{symlink}": stat.S_ISLNK}
#: The value of a number flag at its bound (label "at bound"): the flag's own maximum.
AT_BOUND = "at bound"
#: Flags that set how long a run is (a time budget, a step or epoch count): at their bound the attempt
#: runs until the timeout, as asked; that is counted apart ("budget runs"), not as a hang.
RUN_LENGTH = {("train sampler", "--minutes"), ("train sampler", "--dagger-minutes"), ("train rl", "--minutes"),
              ("train rl", "--total-steps"), ("critical train", "--epochs"), ("critical train", "--time-budget"),
              ("critical train", "--max-steps")}


@dataclass(frozen=True)
class Attempt:
    command: str
    option: str
    label: str
    value: str


def values_of(flag: Flag) -> list[tuple[str, str]]:
    """The bad values of ``flag``'s kind, and for a bounded number its bound."""
    return VALUES[flag.kind] + ([(AT_BOUND, flag.maximum)] if flag.maximum is not None else [])


def all_attempts(commands: list[str]) -> list[Attempt]:
    return [Attempt(flag.command, flag.option, label, value)
            for name in commands for flag in flags_of(COMMANDS[name]) for label, value in values_of(flag)]


def at_bound_attempts(commands: list[str]) -> list[Attempt]:
    """Every bounded number flag at its bound (``--at-bound``)."""
    return [a for a in all_attempts(commands) if a.label == AT_BOUND]


def choose(attempts: list[Attempt], limit: int | None, seed: int) -> list[Attempt]:
    """Every flag once (a random value of its kind), every FIFO and device node given to a path, then
    random others, up to ``limit`` (None: all)."""
    if limit is None or limit >= len(attempts):
        return list(attempts)
    rng = random.Random(seed)
    by_flag: dict[tuple[str, str], list[Attempt]] = {}
    for a in attempts:
        by_flag.setdefault((a.command, a.option), []).append(a)
    first = [rng.choice(group) for group in by_flag.values()]
    special = [a for a in attempts if a.label in ("fifo", "char device", "symlink") and a not in first]
    rest = [a for a in attempts if a not in first and a not in special]
    rng.shuffle(first)
    rng.shuffle(special)
    rng.shuffle(rest)
    return (first + special + rest)[:limit]


# ----------------------------------------------------------------------------- running
@dataclass
class Outcome:
    attempt: Attempt
    returncode: int | None
    seconds: float
    traceback: bool
    hang: bool
    replaced: list[str] = field(default_factory=list)
    last_line: str = ""
    #: still running at the timeout, as a run-length flag at its bound asks (:data:`RUN_LENGTH`): not a hang
    budget_run: bool = False


def _make_nodes(scratch: Path) -> tuple[dict[str, str], dict[str, Callable[[int], bool]]]:
    """The attempt's special paths (a fresh FIFO, device node, symlink to a regular file, a directory),
    all inside ``scratch``, and the file type each node must still have afterwards."""
    nodes = {"{dir}": str(scratch / "a-directory"), "{missing}": str(scratch / "missing" / "out.png"),
             "{fifo}": str(scratch / "fifo.png"), "{chardev}": str(scratch / "chardev.png"),
             "{symlink}": str(scratch / "symlink.png")}
    checks = dict(SPECIAL)
    Path(nodes["{dir}"]).mkdir()
    os.mkfifo(nodes["{fifo}"])
    try:
        os.mknod(nodes["{chardev}"], 0o666 | stat.S_IFCHR, os.makedev(1, 3))     # /dev/null's numbers, our node
    except OSError:           # mknod not permitted (not root, a restricted container): a socket, never /dev/*
        import socket
        with socket.socket(socket.AF_UNIX) as sock:
            sock.bind(nodes["{chardev}"])
        checks["{chardev}"] = stat.S_ISSOCK
    (scratch / "target.txt").write_text("a regular file\n")
    os.symlink(scratch / "target.txt", nodes["{symlink}"])
    return nodes, checks


def _names_a_device(arg: str, scratch: Path) -> bool:
    """Does the argument (or the value after a ``KEY=``) name a path under ``/dev`` or a device node
    outside the attempt's scratch directory?"""
    for text in {arg, arg.split("=", 1)[-1]}:
        if not text:
            continue
        path = Path(text)
        if str(path).startswith("/dev") or str(os.path.realpath(path)).startswith("/dev"):
            return True
        try:
            mode = os.stat(path).st_mode
        except (OSError, ValueError):
            continue
        if (stat.S_ISCHR(mode) or stat.S_ISBLK(mode)) and not os.path.realpath(path).startswith(
                os.path.realpath(scratch) + os.sep):
            return True
    return False


def argv_of(attempt: Attempt, scratch: Path, data: Path, nodes: dict[str, str]) -> list[str]:
    """The attempt's command line (after the entry point): the budget flags, then the bad value. A
    ``RuntimeError`` if any argument would name a device of the machine."""
    value = attempt.value
    for key, path in nodes.items():
        value = value.replace(key, path)
    command = COMMANDS[attempt.command]
    budget = [b.replace("{scratch}", str(scratch)).replace("{data}", str(data)) for b in command.budget]
    extra = list(command.pair_extra) if attempt.value.startswith("gnn=") else []
    argv = [*command.prefix, *budget, *extra, attempt.option, value]
    named = [a for a in argv if _names_a_device(a, scratch)]
    if named:
        raise RuntimeError(f"the fuzzer never names a device of the machine: {named}")
    return argv


def limited(code: str, gib: float) -> str:
    """``code`` run under a limit of ``gib`` GiB of heap and private memory per process (``RLIMIT_DATA``,
    set in the child, inherited by its own processes)."""
    if not gib:
        return code
    limit = int(gib * 2 ** 30)
    return f"import resource; resource.setrlimit(resource.RLIMIT_DATA, ({limit}, {limit}))\n{code}"


def run_limited(code: str, argv: list[str], scratch: Path, timeout: float,
                memory_gib: float) -> tuple[int, str, float, bool]:
    """Run ``python -c code *argv`` in ``scratch`` under the memory limit, in a session of its own (killed
    with its children past ``timeout``): its exit status, standard error, seconds, and whether it ran
    past the timeout."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "PYTHONWARNINGS": "ignore"}
    started = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", limited(code, memory_gib), *argv], cwd=scratch,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=env, start_new_session=True)
    timed_out = False
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        timed_out = True
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        _, err = proc.communicate()
    return proc.returncode, err or "", time.perf_counter() - started, timed_out


def run_attempt(attempt: Attempt, workdir: Path, data: Path, timeout: float,
                memory_gib: float = MEMORY_GIB) -> Outcome:
    scratch = Path(tempfile.mkdtemp(prefix="attempt-", dir=workdir))
    nodes, checks = _make_nodes(scratch)
    argv = argv_of(attempt, scratch, data, nodes)
    returncode, err, seconds, hang = run_limited(ENTRY, argv, scratch, timeout, memory_gib)
    replaced = []
    for key, check in checks.items():
        path = nodes[key]
        if key in attempt.value:
            try:
                if not check(os.lstat(path).st_mode):
                    replaced.append(key.strip("{}"))
            except FileNotFoundError:
                replaced.append(key.strip("{}") + " (removed)")
    lines = [line for line in err.splitlines() if line.strip()]
    budget_run = hang and attempt.label == AT_BOUND and (attempt.command, attempt.option) in RUN_LENGTH
    outcome = Outcome(attempt, returncode, round(seconds, 1), "Traceback (most recent call last)" in err,
                      hang and not budget_run, replaced, lines[-1][:200] if lines else "", budget_run)
    shutil.rmtree(scratch, ignore_errors=True)
    return outcome


def small_critical_data(workdir: Path) -> Path:
    """The small labelled and evaluation sets the critical commands read (made once per run)."""
    data = workdir / "critical-data"
    subprocess.run([sys.executable, "-c", ENTRY, "critical", "generate-data", "--data", str(data), "--num-maps", "9",
                    "--pairs-per-map", "1", "--eval-problems", "1"], cwd=workdir, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)
    return data


def fuzz(attempts: list[Attempt], jobs: int = 2, timeout: float = 120.0, workdir: Path | None = None,
         progress: bool = True, memory_gib: float = MEMORY_GIB) -> list[Outcome]:
    """Run ``attempts``, ``jobs`` at a time; the outcomes in the attempts' order."""
    own = workdir is None
    workdir = Path(tempfile.mkdtemp(prefix="gnn-mp-fuzz-")) if own else Path(workdir)
    try:
        data = small_critical_data(workdir) if any(a.command.startswith("critical") for a in attempts) else workdir
        done = 0

        def one(attempt: Attempt) -> Outcome:
            nonlocal done
            outcome = run_attempt(attempt, workdir, data, timeout, memory_gib)
            done += 1
            if progress:
                mark = "HANG" if outcome.hang else "TRACEBACK" if outcome.traceback else \
                    "REPLACED" if outcome.replaced else "budget run" if outcome.budget_run else f"rc {outcome.returncode}"
                print(f"[{done}/{len(attempts)}] {attempt.command} {attempt.option} {attempt.label}: {mark} "
                      f"({outcome.seconds:.0f} s)", file=sys.stderr, flush=True)
            return outcome
        with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
            return list(pool.map(one, attempts))
    finally:
        if own:
            shutil.rmtree(workdir, ignore_errors=True)


def counts(outcomes: list[Outcome]) -> dict[str, int]:
    return {"attempts": len(outcomes), "tracebacks": sum(o.traceback for o in outcomes),
            "hangs": sum(o.hang for o in outcomes), "budget_runs": sum(o.budget_run for o in outcomes),
            "non_regular_files_replaced": sum(bool(o.replaced) for o in outcomes),
            "exit_0": sum(o.returncode == 0 for o in outcomes), "exit_2": sum(o.returncode == 2 for o in outcomes),
            "other_exits": sum(o.returncode not in (0, 2) and not (o.hang or o.budget_run) for o in outcomes)}


def findings(outcomes: list[Outcome]) -> list[Outcome]:
    return [o for o in outcomes if o.traceback or o.hang or o.replaced]


def main(argv: list[str] | None = None) -> int:
    from train.args import check_output_path, path_arg, seed_int
    ap = argparse.ArgumentParser(prog="python -m tools.fuzz_cli", description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default=",".join(COMMANDS),
                    help=f"comma-separated subcommands (default: all: {', '.join(COMMANDS)})")
    ap.add_argument("--max-attempts", type=int, default=400, help="attempts at most (every flag once first); 0: all")
    ap.add_argument("--jobs", type=int, default=2, help="attempts running at a time")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds per attempt before it counts as a hang")
    ap.add_argument("--seed", type=seed_int, default=0, help="seed of the choice of attempts")
    ap.add_argument("--memory-gib", type=float, default=MEMORY_GIB,
                    help="heap and private memory of each of an attempt's processes, GiB (0: no limit)")
    ap.add_argument("--at-bound", action="store_true",
                    help="only every bounded number flag at its bound (the largest value it accepts)")
    ap.add_argument("--json", type=path_arg, help="also write every outcome to this file")
    ap.add_argument("--quiet", action="store_true", help="no line per attempt on stderr")
    args = ap.parse_args(argv)
    if args.json is not None:          # refused now, not after the attempts
        check_output_path("--json", args.json, is_dir=False)
    names = [n.strip() for n in args.commands.split(",") if n.strip()]
    unknown = [n for n in names if n not in COMMANDS]
    if unknown:
        ap.error(f"unknown subcommand(s) {unknown}; known: {', '.join(COMMANDS)}")
    if args.jobs < 1 or not args.timeout > 0 or args.max_attempts < 0 or not args.memory_gib >= 0:
        ap.error("--jobs must be >= 1, --timeout > 0, --max-attempts >= 0, --memory-gib >= 0")
    pool = at_bound_attempts(names) if args.at_bound else all_attempts(names)
    attempts = choose(pool, args.max_attempts or None, args.seed)
    outcomes = fuzz(attempts, jobs=args.jobs, timeout=args.timeout, progress=not args.quiet,
                    memory_gib=args.memory_gib)
    summary = counts(outcomes)
    print(", ".join(f"{k.replace('_', ' ')} {v}" for k, v in summary.items()))
    for o in findings(outcomes):
        what = "hang" if o.hang else "traceback" if o.traceback else f"replaced {', '.join(o.replaced)}"
        print(f"{what}: gnn-mp {o.attempt.command} {o.attempt.option} {o.attempt.value!r} ({o.attempt.label}) -> "
              f"rc {o.returncode}: {o.last_line}")
    if args.json:
        args.json.write_text(json.dumps({"counts": summary, "outcomes": [asdict(o) for o in outcomes]}, indent=1))
    return 1 if findings(outcomes) else 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
