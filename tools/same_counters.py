"""Does a change keep every result? The benchmark's counters of the code at a git revision against those of a
source tree (by default this checkout's working tree), run by run. Run from the repository root::

    python -m tools.same_counters --base HEAD~1
    python -m tools.same_counters --base 65eb6b4 --tasks panda-mbm,ur5-mbm

A refactor changes no result: for the same seed, ``gnn-mp benchmark --seed 0 --workers 1 --no-recheck`` gives
the same success, nodes, edges, collision checks, iterations and path length on every problem before and
after. ``--base`` is checked out in a temporary git worktree; each side's benchmarks run in a process whose
working folder and ``PYTHONPATH`` are that side's tree (Python puts the working folder first on ``sys.path``,
so a ``PYTHONPATH`` alone would import the checkout the command runs in) and whose numba cache folder is its own
(compiled code and joint tables are not shared between the sides). The two sides run at once, one process each.
Prints ``N of M runs identical`` and each run that differs (task, sampler, problem, what changed); exits 1 when
one differs. Wall times are not compared: they are not results.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tools.fuzz_cli import ENTRY

#: What a run's record must keep: its counters and its answer (the report's per-run fields).
COUNTERS = ("success", "nodes_expanded", "edges", "collision_checks", "iterations", "path_length")
#: The default runs, ``(task, samplers, problems)``: every task's classical rows and its shipped learned ones
#: where their float math is CPU-independent enough to compare on one machine; 316 runs, minutes on 2 cores.
RUNS: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("maze2d", ("uniform", "goal-bias", "gnn", "rl-ppo"), 20),
    ("pendulum", ("uniform", "goal-bias", "rl-ppo"), 20),
    ("panda-mbm", ("uniform", "goal-bias", "gnn"), 20),
    ("ur5-mbm", ("uniform", "goal-bias"), 20),
    ("arm", ("uniform", "goal-bias", "gnn"), 20),
    ("fetch-mbm", ("uniform", "goal-bias"), 8),
)


def differences(task: str, before: dict[str, Any], after: dict[str, Any]) -> tuple[int, int, list[str]]:
    """``(runs compared, runs identical, what differs)`` between two ``--json`` reports of one task: per
    sampler of ``before``, run by run, each of :data:`COUNTERS` (a sampler or run missing from ``after``
    differs)."""
    compared, identical, found = 0, 0, []
    for sampler, runs in before["runs"].items():
        others = after["runs"].get(sampler)
        if others is None:
            found.append(f"{task} {sampler}: not in the second report")
            compared += len(runs)
            continue
        for i, run in enumerate(runs):
            compared += 1
            other = others[i] if i < len(others) else None
            if other is None:
                found.append(f"{task} {sampler} run {i}: not in the second report")
                continue
            changed = [f"{k} {run.get(k)!r} -> {other.get(k)!r}" for k in COUNTERS if run.get(k) != other.get(k)]
            if changed:
                found.append(f"{task} {sampler} problem {run.get('problem', i)}: {', '.join(changed)}")
            else:
                identical += 1
    return compared, identical, found


def run_benchmarks(source: Path, out: Path, runs: tuple, cache: Path) -> None:
    """The benchmarks of ``runs`` with the code of ``source`` (its working folder and import path), reports in
    ``out/<task>.json``; a failing benchmark stops with its last lines."""
    env = {**os.environ, "PYTHONPATH": str(source), "NUMBA_CACHE_DIR": str(cache)}
    for task, samplers, problems in runs:
        command = [sys.executable, "-c", ENTRY, "benchmark",
                   "--task", task, "--samplers", ",".join(samplers), "--problems", str(problems), "--seed", "0",
                   "--workers", "1", "--no-recheck", "--no-progress", "--json", str(out / f"{task}.json")]
        done = subprocess.run(command, check=False, cwd=source, env=env, capture_output=True, text=True)
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            raise RuntimeError(f"the benchmark of {task} with {source} failed: {' | '.join(tail)}")


def _revision(rev: str) -> str:
    """``rev``'s commit id (a one-line error when git does not know it)."""
    done = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"], check=False,
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise ValueError(f"--base {rev!r} is not a commit of this repository")
    return done.stdout.strip()


def _runs_of(tasks: str) -> tuple:
    """:data:`RUNS`, or those of the comma-separated ``tasks`` (a one-line error for one it has not)."""
    if not tasks:
        return RUNS
    names = [t.strip() for t in tasks.split(",") if t.strip()]
    known = [t for t, _, _ in RUNS]
    unknown = [t for t in names if t not in known]
    if unknown or not names:
        raise ValueError(f"--tasks takes some of {', '.join(known)}; got {tasks!r}")
    return tuple(r for r in RUNS if r[0] in names)


def main(argv: list[str] | None = None) -> int:
    from train.args import OneLineParser
    parser = OneLineParser(prog="python -m tools.same_counters", description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the git revision to compare with (e.g. HEAD~1)")
    parser.add_argument("--head", default=".", help="the source tree of the new code (default: this checkout)")
    parser.add_argument("--tasks", default="", help="comma-separated tasks of the default runs (default: all)")
    args = parser.parse_args(argv)
    try:
        runs = _runs_of(args.tasks)
        commit = _revision(args.base)
    except ValueError as exc:
        parser.error(str(exc))
    head = Path(args.head).resolve()
    if not (head / "gnn_mp_envs").is_dir():
        parser.error(f"--head {args.head!r} holds no gnn_mp_envs package")
    with tempfile.TemporaryDirectory(prefix="same-counters-") as tmp:
        root = Path(tmp)
        base = root / "base"
        subprocess.run(["git", "worktree", "add", "--detach", "--quiet", str(base), commit], check=True)
        try:
            sides = {"base": base, "head": head}
            for name in sides:
                (root / f"{name}-out").mkdir()
            with ThreadPoolExecutor(2) as pool:
                jobs = [pool.submit(run_benchmarks, src, root / f"{name}-out", runs, root / f"{name}-cache")
                        for name, src in sides.items()]
                for job in jobs:
                    job.result()
            compared, identical, found = 0, 0, []
            for task, _, _ in runs:
                before, after = (json.loads((root / f"{name}-out" / f"{task}.json").read_text()) for name in sides)
                n, same, diff = differences(task, before, after)
                compared, identical, found = compared + n, identical + same, found + diff
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], check=False)
    print(f"{identical} of {compared} runs identical ({commit[:10]} against {head})")
    for line in found:
        print(f"  {line}")
    return 1 if found else 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
