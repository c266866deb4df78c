"""Named suites: several tasks benchmarked in one go (``--suite default`` is ``make benchmark``).

``--suite ood`` plans, per task, the in-distribution test problems (as ``default``) and each of
the task's out-of-distribution scene families (``TaskSpec.ood_scenes``, 20 problems each) with
every learned sampler and the classical ones, and writes ``ood.md``: per kind, each sampler's
median headline figure (``TaskSpec.headline_metric``) as a ratio to uniform's, its success rate,
the geometric mean over the OOD kinds, and the gap between in-distribution and OOD.
``--suite ood-val`` does the same on the validation kinds (split ``val``): where decisions are taken.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gnn_mp_envs.utils.io import atomic_write_text
from train.args import arg
from train.benchmark.args import (
    OMPL_PREFIX,
    VAMP_PREFIX,
    BenchmarkArgs,
    BenchmarkError,
    ompl_available,
)
from train.benchmark.outputs import benchmark
from train.benchmark.plots import plot_success_vs_time
from train.benchmark.tables import format_family_table, format_field_table, format_table
from train.workers import WorkerPool


@dataclass
class SuiteOptions:
    """Flags of ``gnn-mp benchmark --suite NAME`` (the other benchmark flags give seed and workers)."""

    suite: str | None = arg(None, "run a named suite instead (default, smoke, ood, ood-val, mbm, mbm-vamp, mbm-vamp-balanced); writes "
                            "<task>[-<scene>].json/.png/.txt and summary.md (ood: ood.md) to --out")
    out: Path | None = arg(None, "output directory of --suite (default: results)")
    ompl: bool = arg(True, "--suite: skip OMPL rows even if installed")
    vamp: bool = arg(True, "--suite: skip VAMP's rows even if VAMP is built (docs/mbm.md)", flag="--no-vamp")
    render_images: bool = arg(True, "--suite: skip tree-growth images (else written to --render DIR, default "
                              "OUT/renders)", flag="--no-render")

    #: Where a suite writes when ``--out`` is not given.
    DEFAULT_OUT = Path("results")


@dataclass
class SuiteEntry:
    """One task of a suite: its samplers, problems and the OMPL rows added when OMPL is installed."""

    task: str
    samplers: list[str]
    problems: int
    max_nodes: int | None = None
    scene: str | None = None           # None: the task's benchmark scene (TaskSpec.benchmark_scene)
    ompl: tuple[str, ...] = ()
    #: VAMP's planners (rows ``vamp-<planner>``) added when VAMP is built (:func:`vamp_available`)
    vamp: tuple[str, ...] = ()
    split: str = "test"
    checker: str | None = None         # None: the task's default (TaskSpec.checkers[0], where it has several)
    balance: bool = False              # BiRRT's balanced trees (--balance)
    #: also report as the field does: <name>_field.txt (solved as every table counts it, median / p95 time,
    #: iterations, checks, initial path length; per scene) and <name>_success_vs_time.png
    field: bool = False

    @property
    def name(self) -> str:
        """File stem of the entry's outputs: the task, and the scene and checker when they are named."""
        return "-".join([self.task] + [v for v in (self.scene, self.checker) if v is not None])

#: ``--suite default``: what ``make benchmark`` runs, a few minutes on 2 cores. The learned rows
#: (``gnn``, ``cvae``, ``gnn-cvae``: Algorithm 1; ``rl-ppo``: the RL policy; ``gnn-pick``: the
#: picker's candidates ranked by the supervised model alone, what RL adds over it) use the shipped weights;
#: problem counts follow what separates the samplers beyond noise (pendulum medians need about 60).
LEARNED = ["gnn", "cvae", "gnn-cvae"]
SUITES: dict[str, list[SuiteEntry]] = {
    "default": [
        SuiteEntry("maze2d", ["uniform", "goal-bias", *LEARNED, "gnn-pick", "rl-ppo"], problems=60,
                   ompl=("rrt", "rrtconnect")),
        SuiteEntry("pendulum", ["uniform", "goal-bias", *LEARNED, "gnn-pick", "rl-ppo"], problems=60,
                   ompl=("rrt", "kpiece")),
        SuiteEntry("arm", ["uniform", "goal-bias", *LEARNED, "gnn-pick", "rl-ppo"], problems=40, ompl=("rrtconnect",)),
    ],
    "smoke": [
        SuiteEntry("maze2d", ["uniform", "goal-bias"], problems=3, max_nodes=300),
    ],
    # MotionBenchMaker's problems (docs/mbm.md): the whole test split of each robot, 30 problems of
    # each of the seven scenes, reported as the field reports (Planner Arena log in OUT/ompl/), with
    # the sphere checker (the default) and, for the Panda, the same rows with pybullet's; VAMP's
    # RRTConnect beside them where VAMP is built (docs/mbm.md). The learned
    # rows trained on five scenes: bookshelf_thin and cage are their held-out scenes.
    "mbm": [
        SuiteEntry("panda-mbm", ["uniform", "goal-bias", "gnn", "cvae", "rl-ppo"], problems=210,
                   ompl=("rrtconnect",), vamp=("rrtconnect",), field=True),
        SuiteEntry("panda-mbm", ["uniform", "goal-bias", "gnn", "cvae"], problems=210, ompl=("rrtconnect",),
                   field=True, checker="pybullet"),
        # the UR5's and the Fetch's test splits without the problems their checkers call invalid (docs/mbm.md)
        SuiteEntry("ur5-mbm", ["uniform", "goal-bias", "gnn", "cvae"], problems=206, ompl=("rrtconnect",),
                   vamp=("rrtconnect",), field=True),
        SuiteEntry("fetch-mbm", ["uniform", "goal-bias", "gnn"], problems=197, ompl=("rrtconnect",),
                   vamp=("rrtconnect",), field=True),
    ],
    # Ours beside VAMP (docs/mbm.md, "VAMP's row"): the mbm suite's sphere-checker rows of the three robots
    # and VAMP's RRTConnect, without OMPL and pybullet's checker, so that it runs in minutes on one worker.
    "mbm-vamp": [
        SuiteEntry("panda-mbm", ["uniform", "goal-bias", "gnn"], problems=210, vamp=("rrtconnect",), field=True),
        SuiteEntry("ur5-mbm", ["uniform", "goal-bias", "gnn"], problems=206, vamp=("rrtconnect",), field=True),
        SuiteEntry("fetch-mbm", ["uniform", "goal-bias", "gnn"], problems=197, vamp=("rrtconnect",), field=True),
    ],
    # The same with BiRRT's trees balanced as VAMP's RRT-Connect balances its own (--balance): the planner
    # VAMP runs, with our checker. The learned rows aim a batch's samples at the trees alternating, which
    # balanced trees do not follow after the batch's first sample.
    "mbm-vamp-balanced": [
        SuiteEntry("panda-mbm", ["uniform", "goal-bias", "gnn"], problems=210, vamp=("rrtconnect",), field=True,
                   balance=True),
        SuiteEntry("ur5-mbm", ["uniform", "goal-bias", "gnn"], problems=206, vamp=("rrtconnect",), field=True,
                   balance=True),
        SuiteEntry("fetch-mbm", ["uniform", "goal-bias", "gnn"], problems=197, vamp=("rrtconnect",), field=True,
                   balance=True),
    ],
}
#: Problems per out-of-distribution (and validation) kind.
OOD_PROBLEMS = 20
#: Samplers of the OOD suites per task: the classical rows and every learned sampler the task ships.
OOD_SAMPLERS = {"maze2d": ["uniform", "goal-bias", *LEARNED, "rl-ppo"],
                "pendulum": ["uniform", "goal-bias", *LEARNED, "rl-ppo"],
                "arm": ["uniform", "goal-bias", *LEARNED, "rl-ppo"]}


def _ood_entries(role: str) -> list[SuiteEntry]:
    """Per task: the in-distribution problems (``role="ood"``: the default suite's test problems;
    ``"val"``: as many of split ``val``), then every scene of the role, OOD_PROBLEMS problems each."""
    from gnn_mp_envs.registration import task_spec
    split = "test" if role == "ood" else "val"
    entries = []
    for default in SUITES["default"]:
        spec = task_spec(default.task)
        samplers = OOD_SAMPLERS[default.task]
        entries.append(SuiteEntry(default.task, samplers, problems=default.problems, split=split))
        scenes = spec.ood_scenes if role == "ood" else spec.validation_scenes
        entries += [SuiteEntry(default.task, samplers, problems=OOD_PROBLEMS, scene=s, split=split) for s in scenes]
    return entries


SUITES["ood"] = _ood_entries("ood")
SUITES["ood-val"] = _ood_entries("val")


def run_suite(name: str, out: Path, seed: int = 0, workers: int = 1, progress: bool = True,
              with_ompl: bool | None = None, render: Path | None = None,
              with_vamp: bool | None = None) -> dict[str, dict[str, Any]]:
    """Run a named suite; writes ``{task}.json``, ``{task}.png``, ``{task}.txt`` and ``summary.md`` to
    ``out`` and tree-growth images to ``render`` (None: none). ``with_ompl`` / ``with_vamp``: add the
    entries' OMPL / VAMP rows (None: where installed / built)."""
    if name not in SUITES:
        raise BenchmarkError(f"unknown suite {name!r}; known: {', '.join(sorted(SUITES))}")
    if with_ompl is None:
        with_ompl = ompl_available()
    if with_vamp is None:
        from gnn_mp_envs.baselines.vamp_runner import vamp_available
        with_vamp = vamp_available()
    out.mkdir(parents=True, exist_ok=True)
    # one pool for every task of the suite (each worker pays its imports once), no larger than its largest task
    workers = min(workers, max(e.problems * len(e.samplers) for e in SUITES[name]))
    if workers > 1:
        with WorkerPool(workers) as pool:
            return _run_entries(name, out, seed, workers, progress, (with_ompl, with_vamp), render, pool)
    return _run_entries(name, out, seed, workers, progress, (with_ompl, with_vamp), render, None)


def _run_entries(name: str, out: Path, seed: int, workers: int, progress: bool, others: tuple[bool, bool],
                 render: Path | None, pool: WorkerPool | None) -> dict[str, dict[str, Any]]:
    with_ompl, with_vamp = others
    reports: dict[str, dict[str, Any]] = {}
    tables: list[str] = []
    suite_start = time.perf_counter()
    for entry in SUITES[name]:
        samplers = list(entry.samplers)
        if with_ompl:
            samplers += [OMPL_PREFIX + p for p in entry.ompl]
        if with_vamp:
            samplers += [VAMP_PREFIX + p for p in entry.vamp]
        args = BenchmarkArgs(task=entry.task, samplers=samplers, problems=entry.problems, seed=seed,
                             max_nodes=entry.max_nodes, scene=entry.scene, workers=workers, split=entry.split,
                             checker=entry.checker, balance=entry.balance,
                             json=out / f"{entry.name}.json", plot=out / f"{entry.name}.png",
                             render=render,
                             ompl_log=out / "ompl" if with_ompl else None,
                             progress=progress)
        task_start = time.perf_counter()
        report = benchmark(args, pool)
        elapsed = time.perf_counter() - task_start
        table = format_table(report)
        atomic_write_text(out / f"{entry.name}.txt", table + "\n")
        if entry.field:
            table = "\n\n".join([format_field_table(report), format_family_table(report)])
            print(table)
            atomic_write_text(out / f"{entry.name}_field.txt", table + "\n")
            plot_success_vs_time(report, out / f"{entry.name}_success_vs_time.png")
        tables.append(f"{table}\n({elapsed:.0f} s)")
        reports[entry.name] = report
        print(f"({entry.name}: {elapsed:.0f} s)\n")
    total = time.perf_counter() - suite_start
    command = f"gnn-mp benchmark --suite {name} --out {out} --seed {seed} --workers {workers}"
    summary = [f"# Benchmark suite `{name}`", "", f"Command: `{command}`  ",
               f"Machine: {machine_description()}  ", f"Date: {time.strftime('%Y-%m-%d')}  ",
               f"Total wall time: {total:.0f} s", "", "```", "\n\n".join(tables), "```", "", "## Figures", ""]
    for entry in SUITES[name]:           # the box plots (and success over time) beside the tables
        summary.append(f"![{entry.name}]({entry.name}.png)")
        if entry.field:
            summary.append(f"![{entry.name}: success over time]({entry.name}_success_vs_time.png)")
    summary.append("")
    if name in ("ood", "ood-val"):
        ratios = ood_markdown(reports, command)
        atomic_write_text(out / "ood.md", ratios)
        summary[7:7] = [ratios, ""]
        print(ratios)
    atomic_write_text(out / "summary.md", "\n".join(summary))
    print(f"suite {name!r}: {total:.0f} s; results in {out}/ (summary.md, <task>.json/.png/.txt)")
    return reports


def machine_description() -> str:
    """The CPU model and core count of this machine, for the header of a results page."""
    import os
    model = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), model)
    except OSError:
        import platform
        model = platform.processor() or model
    return f"{model}, {os.cpu_count()} cores"


# ---------------------------------------------------------------------------- the OOD summary
def ratio_rows(reports: dict[str, dict[str, Any]], task: str) -> dict[str, Any]:
    """One task's kinds of a suite run: ``{"metric", "kinds": [(kind, report)], "in": report}``
    (the in-distribution entry is the one without a scene)."""
    from gnn_mp_envs.registration import task_spec
    kinds = [(r["scene"] or "in-distribution", r) for r in reports.values() if r["task"] == task]
    default = next((r for k, r in kinds if r.get("scene") in (None, task_spec(task).benchmark_scene)), None)
    return {"metric": task_spec(task).headline_metric, "in": default,
            "kinds": [(k, r) for k, r in kinds if r is not default]}


def ratio(report: dict[str, Any], sampler: str, metric: str) -> float | None:
    """``sampler``'s median ``metric`` over uniform's in one report (None without both)."""
    res = report["results"]
    if sampler not in res or "uniform" not in res:
        return None
    a, b = res[sampler][metric]["median"], res["uniform"][metric]["median"]
    return None if a is None or not b else a / b


def geometric_mean(values: list[float | None]) -> float | None:
    vals = [v for v in values if v is not None and v > 0]
    return math.exp(sum(math.log(v) for v in vals) / len(vals)) if vals and len(vals) == len(values) else None


def ood_markdown(reports: dict[str, dict[str, Any]], command: str) -> str:
    """Per task: sampler rows, a column per kind with ``ratio (success)`` to uniform, the geometric
    mean over the kinds and its gap to the in-distribution ratio."""
    out = [f"Command: `{command}`", ""]
    for task in dict.fromkeys(r["task"] for r in reports.values()):
        rows = ratio_rows(reports, task)
        metric, kinds, default = rows["metric"], rows["kinds"], rows["in"]
        what = metric.replace("_", " ")
        samplers = list(next(iter(kinds))[1]["results"]) if kinds else []
        head = ["sampler", "in-distribution"] + [k for k, _ in kinds] + ["geo. mean", "gap"]
        out += [f"**{task}**: median {what} / uniform's median (success rate); in-distribution: "
                f"{default['problems'] if default else 0} {default['split'] if default else ''} problems, "
                f"each kind {kinds[0][1]['problems'] if kinds else 0}; gap = geo. mean / in-distribution", "",
                "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for s in samplers:
            cells = [s]
            r_in = ratio(default, s, metric) if default else None
            cells.append("-" if r_in is None else f"{r_in:.2f} ({100 * default['results'][s]['success_rate']:.0f}%)")
            vals = []
            for _, rep in kinds:
                r = ratio(rep, s, metric)
                vals.append(r)
                succ = rep["results"].get(s, {}).get("success_rate")
                cells.append("-" if r is None else f"{r:.2f} ({100 * succ:.0f}%)")
            g = geometric_mean(vals)
            cells.append("-" if g is None else f"{g:.2f}")
            cells.append("-" if g is None or not r_in else f"{g / r_in:.2f}x")
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)
