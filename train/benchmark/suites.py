"""Named suites: several tasks benchmarked in one go (``--suite default`` is ``make benchmark``)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gnn_mp_envs.utils.io import atomic_write_text
from train.args import arg
from train.benchmark.args import (
    OMPL_PREFIX,
    BenchmarkArgs,
    BenchmarkError,
    ompl_available,
)
from train.benchmark.outputs import benchmark
from train.benchmark.runs import WorkerPool
from train.benchmark.plots import plot_success_vs_time
from train.benchmark.tables import format_family_table, format_field_table, format_table


@dataclass
class SuiteOptions:
    """Flags of ``gnn-mp benchmark --suite NAME`` (the other benchmark flags give seed and workers)."""

    suite: str | None = arg(None, "run a named suite instead (default, smoke, mbm); writes "
                            "<task>.json/.png/.txt and summary.md to --out")
    out: Path = arg(Path("results"), "output directory of --suite")
    ompl: bool = arg(True, "--suite: skip OMPL rows even if installed")
    render_images: bool = arg(True, "--suite: skip tree-growth images (else written to --render DIR, default "
                              "OUT/renders)", flag="--no-render")


@dataclass
class SuiteEntry:
    """One task of a suite: its samplers, problems and the OMPL rows added when OMPL is installed."""

    task: str
    samplers: list[str]
    problems: int
    max_nodes: int | None = None
    scene: str | None = None           # None: the task's benchmark scene (TaskSpec.benchmark_scene)
    ompl: tuple[str, ...] = ()
    #: also report as the field does: <task>_field.txt (success within the budgets, median / p95 time,
    #: iterations, checks, initial path length; per scene) and <task>_success_vs_time.png
    field: bool = False

#: ``--suite default``: what ``make benchmark`` runs, a few minutes on 2 cores. The learned rows
#: (``gnn``, ``cvae``, ``gnn-cvae``: Algorithm 1; ``rl-ppo``: the RL policy) use the shipped weights;
#: problem counts follow what separates the samplers beyond noise (pendulum medians need about 60).
LEARNED = ["gnn", "cvae", "gnn-cvae"]
SUITES: dict[str, list[SuiteEntry]] = {
    "default": [
        SuiteEntry("maze2d", ["uniform", "goal-bias", *LEARNED, "rl-ppo"], problems=60,
                   ompl=("rrt", "rrtconnect")),
        SuiteEntry("pendulum", ["uniform", "goal-bias", *LEARNED, "rl-ppo"], problems=60,
                   ompl=("rrt", "kpiece")),
        SuiteEntry("arm", ["uniform", "goal-bias", *LEARNED], problems=40, ompl=("rrtconnect",)),
    ],
    "smoke": [
        SuiteEntry("maze2d", ["uniform", "goal-bias"], problems=3, max_nodes=300),
    ],
    # MotionBenchMaker's Panda problems (docs/mbm.md): the whole test split, 30 problems of each of
    # the seven scenes, reported as the field reports (Planner Arena log in OUT/ompl/). The learned
    # rows trained on five scenes: bookshelf_thin and cage are their held-out scenes.
    "mbm": [
        SuiteEntry("panda-mbm", ["uniform", "goal-bias", "gnn", "cvae"], problems=210, ompl=("rrtconnect",),
                   field=True),
    ],
}


def run_suite(name: str, out: Path, seed: int = 0, workers: int = 1, progress: bool = True,
              with_ompl: bool | None = None, render: Path | None = None) -> dict[str, dict[str, Any]]:
    """Run a named suite; writes ``{task}.json``, ``{task}.png``, ``{task}.txt`` and ``summary.md`` to
    ``out`` and tree-growth images to ``render`` (None: none)."""
    if name not in SUITES:
        raise BenchmarkError(f"unknown suite {name!r}; known: {', '.join(sorted(SUITES))}")
    if with_ompl is None:
        with_ompl = ompl_available()
    out.mkdir(parents=True, exist_ok=True)
    if workers > 1:   # one pool for every task of the suite: each worker pays its imports once
        with WorkerPool(workers) as pool:
            return _run_entries(name, out, seed, workers, progress, with_ompl, render, pool)
    return _run_entries(name, out, seed, workers, progress, with_ompl, render, None)


def _run_entries(name: str, out: Path, seed: int, workers: int, progress: bool, with_ompl: bool,
                 render: Path | None, pool: WorkerPool | None) -> dict[str, dict[str, Any]]:
    reports: dict[str, dict[str, Any]] = {}
    tables: list[str] = []
    suite_start = time.perf_counter()
    for entry in SUITES[name]:
        samplers = list(entry.samplers)
        if with_ompl:
            samplers += [OMPL_PREFIX + p for p in entry.ompl]
        args = BenchmarkArgs(task=entry.task, samplers=samplers, problems=entry.problems, seed=seed,
                             max_nodes=entry.max_nodes, scene=entry.scene, workers=workers,
                             json=out / f"{entry.task}.json", plot=out / f"{entry.task}.png",
                             render=render,
                             ompl_log=out / "ompl" if with_ompl else None,
                             progress=progress)
        task_start = time.perf_counter()
        report = benchmark(args, pool)
        elapsed = time.perf_counter() - task_start
        table = format_table(report)
        atomic_write_text(out / f"{entry.task}.txt", table + "\n")
        if entry.field:
            table = "\n\n".join([format_field_table(report), format_family_table(report)])
            print(table)
            atomic_write_text(out / f"{entry.task}_field.txt", table + "\n")
            plot_success_vs_time(report, out / f"{entry.task}_success_vs_time.png")
        tables.append(f"{table}\n({elapsed:.0f} s)")
        reports[entry.task] = report
        print(f"({entry.task}: {elapsed:.0f} s)\n")
    total = time.perf_counter() - suite_start
    command = f"gnn-mp benchmark --suite {name} --out {out} --seed {seed} --workers {workers}"
    summary = [f"# Benchmark suite `{name}`", "", f"Command: `{command}`  ",
               f"Total wall time: {total:.0f} s", "", "```", "\n\n".join(tables), "```", ""]
    atomic_write_text(out / "summary.md", "\n".join(summary))
    print(f"suite {name!r}: {total:.0f} s; results in {out}/ (summary.md, <task>.json/.png/.txt)")
    return reports
