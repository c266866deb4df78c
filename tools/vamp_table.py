"""Ours against VAMP, per scene, from a benchmark JSON with VAMP's row (``vamp-rrtconnect``).

Run from the repository root on the ``--json`` of a MotionBenchMaker benchmark (``panda-mbm``,
``ur5-mbm``, ``fetch-mbm``) whose ``--samplers`` hold ``vamp-rrtconnect`` and rows of ours::

    gnn-mp benchmark --task panda-mbm --samplers uniform,vamp-rrtconnect --problems 70 --seed 0 \\
        --workers 1 --json results/panda-vamp.json
    python -m tools.vamp_table results/panda-vamp.json [more.json ...]

Prints, as Markdown, per scene and row of ours: problems solved by each (ours: the benchmark's
meaning, :func:`train.benchmark.stats.solved`; VAMP: its own word, a path returned), the median
planning time of each (ours: the planning loop's wall time; VAMP: its own planning time, measured
inside its C++ planner) and their ratio ours / VAMP, median iterations of each, and how many of
VAMP's returned paths fail the benchmark's re-check: at the planner's resolution with the report's
checker, and at 10x finer with pybullet (``path_valid``, ``path_valid_fine``); then the scenes the learned
rows never trained on together (``bookshelf_thin`` and ``cage``, where the report holds other scenes too), then
all scenes.
Medians over every run with a time (failed runs included, as the benchmark's tables count them).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from gnn_mp_envs.tasks.mbm import HELD_OUT_SCENES
from train.benchmark.stats import solved

VAMP_ROW = "vamp-rrtconnect"
TASKS = ("panda-mbm", "ur5-mbm", "fetch-mbm")
#: Rows of other planners that are no row of ours.
NOT_OURS = (VAMP_ROW, "ompl-rrtconnect", "ompl-rrt")


def _median(values: list[Any], scale: float = 1.0) -> float | None:
    data = [float(v) for v in values if v is not None]
    return None if not data else scale * float(np.median(data))


def _fmt(x: float | None, digits: int = 0) -> str:
    return "-" if x is None else f"{x:,.{digits}f}"


def vamp_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """VAMP's row: problems, solved (its word), median time (ms) and iterations, and its returned
    paths that fail the re-check (``coarse``: at the planner's resolution; ``fine``: 10x finer)."""
    returned = [r for r in runs if r.get("success")]
    return {"n": len(runs), "solved": len(returned),
            "time_ms": _median([r.get("wall_time_s") for r in runs], 1e3),
            "iterations": _median([r.get("iterations") for r in runs]),
            "coarse": sum(r.get("path_valid") is False for r in returned),
            "fine": sum(r.get("path_valid_fine") is False for r in returned),
            "unchecked": sum(r.get("path_valid_fine") is None for r in returned),
            "start_goal_invalid": sum((r.get("vamp") or {}).get("start_goal_valid") is False for r in runs)}


def our_figures(runs: list[dict[str, Any]], max_nodes: int | None) -> dict[str, Any]:
    return {"n": len(runs), "solved": sum(solved(r, max_nodes) for r in runs),
            "time_ms": _median([r.get("wall_time_s") for r in runs], 1e3),
            "iterations": _median([r.get("iterations") for r in runs])}


def ratio_table(report: dict[str, Any]) -> str:
    """The Markdown table of ``report`` (see the module docstring)."""
    runs, max_nodes = report["runs"], report.get("max_nodes")
    if VAMP_ROW not in runs:
        raise ValueError(f"the {report.get('task')} report has no {VAMP_ROW} row (rows: {', '.join(runs)})")
    ours = [name for name in runs if name not in NOT_OURS]
    if not ours:
        raise ValueError(f"the {report.get('task')} report has no row of ours beside {VAMP_ROW}")
    scenes = list(dict.fromkeys(r.get("family") for r in runs[VAMP_ROW]))
    groups: list[tuple[str, set | None]] = [(scene, {scene}) for scene in scenes]
    held_out = [s for s in scenes if s in HELD_OUT_SCENES]
    if held_out and len(held_out) < len(scenes):          # the learned rows' held-out scenes together
        groups.append((f"held-out ({', '.join(HELD_OUT_SCENES)})", set(HELD_OUT_SCENES)))
    groups.append(("all scenes", None))
    out = [f"{report['task']}: {report['problems']} {report.get('split', 'test')} problems, seed {report['seed']} "
           f"(times: medians in ms; ratio = ours / VAMP; VAMP's paths failing the re-check: at the planner's "
           f"resolution ({report.get('checker') or 'the task checker'}) / 10x finer (pybullet))", "",
           "| scene | row of ours | solved | time | VAMP: paths returned | VAMP: time | ours / VAMP | "
           "iterations (ours / VAMP) | VAMP's paths failing the re-check |",
           "|---|---|---|---|---|---|---|---|---|"]
    for label, members in groups:
        pick = (lambda rows: rows) if members is None else (lambda rows: [r for r in rows if r.get("family") in members])
        v = vamp_figures(pick(runs[VAMP_ROW]))
        for name in ours:
            o = our_figures(pick(runs[name]), max_nodes)
            ratio = None if not o["time_ms"] or not v["time_ms"] else o["time_ms"] / v["time_ms"]
            failing = f"{v['coarse']} / {v['fine']} of {v['solved']}"
            if v["unchecked"]:
                failing += f" ({v['unchecked']} not re-checked)"
            out.append(f"| {label} | {name} | {o['solved']}/{o['n']} | {_fmt(o['time_ms'], 2)} | "
                       f"{v['solved']}/{v['n']} | {_fmt(v['time_ms'], 3)} | "
                       f"{'-' if ratio is None else f'{ratio:,.0f}x'} | "
                       f"{_fmt(o['iterations'])} / {_fmt(v['iterations'])} | {failing} |")
    v = vamp_figures(runs[VAMP_ROW])
    if v["start_goal_invalid"]:
        out += ["", f"{v['start_goal_invalid']} problems not planned by VAMP: its spheres call the start or the goal "
                "invalid (VAMP's own evaluation skips them; counted as not solved here)"]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("reports", type=Path, nargs="+", help="benchmark JSONs with a vamp-rrtconnect row")
    args = ap.parse_args(argv)
    tables = []
    for path in args.reports:
        try:
            report = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            print(f"vamp_table: cannot read {path}: {exc}", file=sys.stderr)
            return 2
        if not isinstance(report, dict) or report.get("task") not in TASKS or not isinstance(report.get("runs"), dict):
            task = report.get("task") if isinstance(report, dict) else None
            print(f"vamp_table: {path} is no benchmark report of {', '.join(TASKS)} (task {task!r})", file=sys.stderr)
            return 2
        try:
            tables.append(ratio_table(report))
        except ValueError as exc:
            print(f"vamp_table: {path}: {exc}", file=sys.stderr)
            return 2
    print("\n\n".join(tables))
    return 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
