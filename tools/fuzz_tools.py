"""Feed bad values to every flag of every ``python -m tools.*`` script and count the tracebacks.

The scripts' flags are read from their ``--help``; each flag that takes a value gets, one at a time:
empty, negative, NaN, huge (10**30), text, a directory, a file that is not JSON; a positional argument
(a report file) also a missing file, a character device node of the attempt's own (never a device of
the machine: see ``tools.fuzz_cli``) and JSON of another kind; and each script gets an unknown flag. Every attempt runs in a subprocess of its own (its own session and
scratch directory as the current directory, the safety flags below, a timeout and a memory limit), and
counts as a traceback (``Traceback (most recent call last)`` in stderr: bad input must be one line),
an exit status, or "still running" at the timeout (a value the script accepted: not a finding).

Scripts that write into the package by default (the sphere models, the converted datasets, a
gallery) always get an ``--out`` in the scratch directory; no attempt passes ``--write``.

    python -m tools.fuzz_tools                        # every script, every flag (a few hundred attempts)
    python -m tools.fuzz_tools --tools bench_env,mbm_table --json out.json

Prints the counts, then one line per traceback; exits 1 when there is any.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from tools.fuzz_cli import HUGE, MEMORY_GIB, ROOT, _make_nodes, _names_a_device, run_limited

#: The scripts, and flags every attempt of theirs gets (``{scratch}``: its directory): outputs kept in it.
TOOLS: dict[str, tuple[str, ...]] = {
    "bench_arm": ("--json", "{scratch}/bench.json"),
    "bench_checker": (),
    "bench_planning_checks": (),
    "bench_env": (),
    "bench_sampler": (),
    "bench_vec": (),
    "compare_on_kinds": ("--json", "{scratch}/runs.json"),
    "fuzz_cli": ("--max-attempts", "1", "--timeout", "5"),
    "mbm_convert": ("--vamp", "{scratch}/no-vamp", "--out", "{scratch}/converted.json"),
    "mbm_table": (),
    "rl_tree_swap": (),
    "same_counters": (),
    "scene_gallery": ("--out", "{scratch}/gallery.png"),
    "spherize": ("--robot", "panda", "--out", "{scratch}/spheres.npz"),
    "tune_adaptive": (),
    "tune_batch": (),
    "tune_proposals": (),
    "vamp_table": (),
}
#: label -> value (``{dir}``, ``{missing}``, ``{chardev}``, ``{json}``, ``{text}``: made per attempt in its
#: scratch directory)
VALUES = [("empty", ""), ("negative", "-1"), ("nan", "nan"), ("huge", HUGE), ("text", "abc"),
          ("directory", "{dir}"), ("not json", "{text}")]
#: The scripts' positional arguments (report files) also get these.
POSITIONAL_VALUES = [("missing", "{missing}"), ("char device", "{chardev}"), ("json of another kind", "{json}")]
#: Flags never given: they store results into the package.
NEVER = {"--write", "--help"}


@dataclass(frozen=True)
class Attempt:
    tool: str
    option: str      # "" for the script's positional arguments
    label: str
    value: str


@dataclass
class Outcome:
    attempt: Attempt
    returncode: int | None
    seconds: float
    traceback: bool
    running: bool
    last_line: str = ""


def options_of(tool: str) -> tuple[list[str], bool]:
    """(the value-taking options of ``python -m tools.<tool>``, whether it takes positional arguments),
    from its ``--help``."""
    proc = subprocess.run([sys.executable, "-m", f"tools.{tool}", "--help"], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT)})
    options = []
    for match in re.finditer(r"^  (?:-\w, )?(--[\w-]+)(?:, --[\w-]+)*(?: ([A-Z][A-Z_=]*|\{[^}]*\}))?",
                             proc.stdout, re.M):
        flag, metavar = match.groups()
        if metavar and flag not in NEVER:
            options.append(flag)
    return options, "positional arguments:" in proc.stdout


def all_attempts(tools: list[str]) -> list[Attempt]:
    out = []
    for tool in tools:
        options, positional = options_of(tool)
        out.append(Attempt(tool, "--no-such-flag", "unknown flag", "1"))
        for option in options + ([""] if positional else []):
            out += [Attempt(tool, option, label, value) for label, value in VALUES + (
                POSITIONAL_VALUES if not option else [])]
    return out


def run_attempt(attempt: Attempt, workdir: Path, timeout: float, memory_gib: float = MEMORY_GIB) -> Outcome:
    scratch = Path(tempfile.mkdtemp(prefix="attempt-", dir=workdir))
    nodes, _ = _make_nodes(scratch)
    nodes["{json}"], nodes["{text}"] = str(scratch / "other.json"), str(scratch / "text.json")
    Path(nodes["{json}"]).write_text('{"runs": [1, 2], "results": null}\n')
    Path(nodes["{text}"]).write_text("not json\n")
    value = attempt.value
    for key, path in nodes.items():
        value = value.replace(key, path)
    safe = [a.replace("{scratch}", str(scratch)) for a in TOOLS[attempt.tool]]
    if attempt.option in safe:        # the fuzzed flag replaces the safety flag of the same name
        i = safe.index(attempt.option)
        del safe[i:i + 2]
    argv = [*safe, *([attempt.option] if attempt.option else []), value]
    named = [a for a in argv if _names_a_device(a, scratch)]
    if named:
        raise RuntimeError(f"the fuzzer never names a device of the machine: {named}")
    code = f"import runpy, sys; sys.argv[0] = 'tools.{attempt.tool}'; runpy.run_module('tools.{attempt.tool}', " \
           "run_name='__main__', alter_sys=True)"
    returncode, err, seconds, running = run_limited(code, argv, scratch, timeout, memory_gib)
    lines = [line for line in err.splitlines() if line.strip()]
    outcome = Outcome(attempt, None if running else returncode, round(seconds, 1),
                      "Traceback (most recent call last)" in err, running, lines[-1][:200] if lines else "")
    shutil.rmtree(scratch, ignore_errors=True)
    return outcome


def fuzz(attempts: list[Attempt], jobs: int = 2, timeout: float = 20.0, workdir: Path | None = None,
         progress: bool = True, memory_gib: float = MEMORY_GIB) -> list[Outcome]:
    own = workdir is None
    workdir = Path(tempfile.mkdtemp(prefix="gnn-mp-fuzz-tools-")) if own else Path(workdir)
    done = 0

    def one(attempt: Attempt) -> Outcome:
        nonlocal done
        outcome = run_attempt(attempt, workdir, timeout, memory_gib)
        done += 1
        if progress:
            mark = "TRACEBACK" if outcome.traceback else "running" if outcome.running else f"rc {outcome.returncode}"
            print(f"[{done}/{len(attempts)}] tools.{attempt.tool} {attempt.option or '(positional)'} {attempt.label}: "
                  f"{mark} ({outcome.seconds:.0f} s)", file=sys.stderr, flush=True)
        return outcome
    try:
        with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
            return list(pool.map(one, attempts))
    finally:
        if own:
            shutil.rmtree(workdir, ignore_errors=True)


def counts(outcomes: list[Outcome]) -> dict[str, int]:
    return {"attempts": len(outcomes), "tracebacks": sum(o.traceback for o in outcomes),
            "running_at_timeout": sum(o.running for o in outcomes),
            "exit_0": sum(o.returncode == 0 for o in outcomes), "exit_2": sum(o.returncode == 2 for o in outcomes),
            "other_exits": sum(o.returncode not in (0, 2, None) for o in outcomes)}


def main(argv: list[str] | None = None) -> int:
    from train.args import check_output_path, path_arg
    ap = argparse.ArgumentParser(prog="python -m tools.fuzz_tools", description=__doc__.splitlines()[0])
    ap.add_argument("--tools", default=",".join(TOOLS), help="comma-separated scripts (default: all)")
    ap.add_argument("--jobs", type=int, default=2, help="attempts running at a time")
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds per attempt (then: accepted, stopped)")
    ap.add_argument("--memory-gib", type=float, default=MEMORY_GIB,
                    help="heap and private memory per process of an attempt, GiB (0: none)")
    ap.add_argument("--json", type=path_arg, help="also write every outcome to this file")
    ap.add_argument("--quiet", action="store_true", help="no line per attempt on stderr")
    args = ap.parse_args(argv)
    if args.json is not None:          # refused now, not after the attempts
        check_output_path("--json", args.json, is_dir=False)
    names = [n.strip() for n in args.tools.split(",") if n.strip()]
    unknown = [n for n in names if n not in TOOLS]
    if unknown:
        ap.error(f"unknown script(s) {unknown}; known: {', '.join(TOOLS)}")
    if args.jobs < 1 or not args.timeout > 0 or not args.memory_gib >= 0:
        ap.error("--jobs must be >= 1, --timeout > 0, --memory-gib >= 0")
    outcomes = fuzz(all_attempts(names), jobs=args.jobs, timeout=args.timeout, progress=not args.quiet,
                    memory_gib=args.memory_gib)
    print(", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counts(outcomes).items()))
    for o in outcomes:
        if o.traceback:
            a = o.attempt
            print(f"traceback: python -m tools.{a.tool} {a.option} {a.value!r} ({a.label}) -> rc {o.returncode}: "
                  f"{o.last_line}")
    if args.json:
        args.json.write_text(json.dumps({"counts": counts(outcomes), "outcomes": [asdict(o) for o in outcomes]},
                                        indent=1))
    return 1 if any(o.traceback for o in outcomes) else 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
