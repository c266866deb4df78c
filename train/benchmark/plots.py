"""Figures: box plots per sampler and tree-growth strips rendered from the environment."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gnn_mp_envs.utils.io import atomic_path
from train.benchmark.args import BenchmarkArgs, env_kwargs_for, is_external, task_spec_for
from train.benchmark.runs import checkpoint_of, run_episode


#: Box colours by the kind of sampler: classical, supervised (learned from planned trees), RL, OMPL.
KIND_COLOURS = {"classical": "#d9d9d9", "supervised": "#9ecae1", "rl": "#fdae6b", "ompl": "#a1d99b"}


def sampler_kind(name: str) -> str:
    """The kind of a benchmark row, for its colour: ``ompl-*``, ``rl-*``, the classical samplers, or
    a learned (supervised) one."""
    if name.startswith("ompl-"):
        return "ompl"
    if name.startswith("rl-"):
        return "rl"
    return "classical" if name in ("uniform", "goal-bias") else "supervised"


def _value(run: dict[str, Any], metric: str) -> float | None:
    """A run's figure for a panel (wall time in milliseconds)."""
    if metric == "wall_time_ms":
        return None if run.get("wall_time_s") is None else 1000.0 * run["wall_time_s"]
    return run[metric]


def plot_report(report: dict[str, Any], path: Path) -> None:
    """Box plots per sampler in the style of the paper: nodes expanded, collision checks, path length,
    and the wall time (inference included); boxes coloured by the kind of sampler, success rates in
    the title; the format follows the file's suffix (``.png``, ``.svg``, ``.pdf``).

    Counts that spread over more than a decade and a half get a log axis (a learned row's box
    would otherwise be squashed under uniform's long tail)."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from gnn_mp_envs.registration import TASK_SPECS
    spec = TASK_SPECS.get(report["task"])
    unit = spec.path_unit if spec is not None else "state-space length"
    panels = [("nodes_expanded", "nodes expanded", "nodes", False),
              ("collision_checks", "collision checks", "checks", False),
              ("path_length", "path length (solved runs)", unit, True),
              ("wall_time_ms", "wall time, inference included", "ms", False)]
    names = list(report["results"])
    width = max(3.4, 0.45 * len(names) + 1.2)
    fig, axes = plt.subplots(1, len(panels), figsize=(width * len(panels), 3.9), squeeze=False)
    for ax, (metric, title, ylabel, success_only) in zip(axes[0], panels):
        data = []
        for name in names:
            runs = report["runs"][name]
            values = [_value(r, metric) for r in runs if _value(r, metric) is not None and
                      (r["success"] or not success_only)]
            data.append(values if values else [np.nan])
        boxes = ax.boxplot(data, showfliers=True, patch_artist=True)
        for box, name in zip(boxes["boxes"], names):
            box.set_facecolor(KIND_COLOURS[sampler_kind(name)])
        ax.set_xticks(range(1, len(names) + 1), names, rotation=30, ha="right")
        finite = [v for d in data for v in d if np.isfinite(v) and v > 0]
        if not success_only and finite and max(finite) / min(finite) > 30:
            ax.set_yscale("log")
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.grid(axis="y", alpha=0.3)
    rates = ", ".join(f"{n}: {100 * report['results'][n]['success_rate']:.0f}%" for n in names)
    # Two lines: the success rates of four or more samplers overflow a one-line title.
    fig.suptitle(f"{report['task']}: {report['problems']} held-out problems\nsuccess {rates}", fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def plot_success_vs_time(report: dict[str, Any], path: Path) -> None:
    """Planner Arena's progress view: the fraction of problems solved (within the node budget) by
    each time budget, one curve per sampler, time on a log axis up to the report's time limit."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    grid, curves = success_curves(report)
    max_nodes = report["max_nodes"]
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for name, fractions in curves.items():
        ax.step(grid, fractions, where="post", label=name)
    ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("time budget [s] (planning loop incl. inference; OMPL: solve time)")
    ax.set_ylabel("fraction of problems solved")
    unverified = "; paths not re-checked (--no-recheck)" if report.get("rechecked") is False else ""
    ax.set_title(f"{report['task']}: {report['problems']} problems, node budget {max_nodes:,}{unverified}", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def success_curves(report: dict[str, Any], points: int = 200) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The success-vs-time figure's data: time budgets (log-spaced up to the report's time limit) and,
    per row, the share of its problems solved (:func:`~train.benchmark.stats.solved`) within each."""
    from train.benchmark.stats import solved as is_solved
    limit, max_nodes = report.get("time_limit_s", 10.0), report["max_nodes"]
    times = [r["wall_time_s"] for runs in report["runs"].values() for r in runs if r.get("wall_time_s")]
    grid = np.geomspace(max(min(min(times, default=1e-3) / 2, limit / 10), 1e-4), limit, points)
    curves = {}
    for name, runs in report["runs"].items():
        solved = np.sort([r["wall_time_s"] for r in runs
                          if is_solved(r, max_nodes) and r.get("wall_time_s") is not None])
        curves[name] = np.searchsorted(solved, grid, side="right") / max(len(runs), 1)
    return grid, curves


def snapshot_schedule(max_nodes: int) -> list[int]:
    """Iterations at which tree-growth snapshots are drawn (the final tree is always added)."""
    return [i for i in (25, 100, 400, 1600, 6400) if i < 4 * max_nodes]


def save_tree_growth(path: Path, title: str, snapshots: list[tuple[int, int, np.ndarray]]) -> None:
    """A strip of env.render() images: the tree at a few iterations and at the end."""
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(snapshots), figsize=(3.6 * len(snapshots), 3.6), squeeze=False)
    for ax, (iteration, nodes, image) in zip(axes[0], snapshots):
        ax.imshow(image)
        ax.set_title(f"iter {iteration}, {nodes} nodes", fontsize=8)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def render_growth(args: BenchmarkArgs, directory: Path, index: int = 0) -> list[Path]:
    """Tree-growth strips of problem ``index`` for every sampler of ours (not OMPL's or VAMP's rows); returns the
    files written."""
    spec = task_spec_for(args.task)
    env_kwargs = env_kwargs_for(args)
    max_nodes = args.max_nodes or spec.max_nodes
    written = []
    for name in args.samplers:
        if is_external(name):
            continue
        record = run_episode(args.task, env_kwargs, name, index, args.seed, checkpoint_of(args, name),
                             args.sampler_settings(name), snapshot_schedule(max_nodes))
        outcome = "solved" if record["success"] else "not solved"
        path = directory / f"{args.task}_{name}_problem{index}.png"
        save_tree_growth(path, f"{args.task}, {name}, test problem {index} ({outcome})", record["snapshots"])
        written.append(path)
    return written
