"""docs/mbm.md's tables from a panda-mbm benchmark JSON (e.g. the ``mbm`` suite's ``panda-mbm.json``).

Run from the repository root::

    python -m tools.mbm_table results/mbm/panda-mbm.json

Prints, as Markdown: per scene and sampler the problems solved (as the benchmark's own tables count
them, :func:`train.benchmark.stats.solved`), median iterations, collision checks and planning time;
the whole test split beside VAMP's and cuRobo's
published figures; and each learned row against uniform on the in-distribution scenes (the five
training scenes) and the held-out ones (``bookshelf_thin``, ``cage``). A report with VAMP's row
(``vamp-rrtconnect``) gets :mod:`tools.vamp_table`'s per-scene ratios ours / VAMP as well.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from gnn_mp_envs.tasks.mbm import HELD_OUT_SCENES, SCENES
from train.benchmark.stats import solved

#: Published figures (other machines, other collision models): VAMP's README (resources/README.md at
#: commit f6de6a7, RRTConnect on a Ryzen 9 7950X, spherised Panda) and cuRobo's paper.
VAMP = {"solved": "699/700", "iterations": "104 / 472 / 1,891", "time": "35 us median (343 us p95)"}
CUROBO = {"solved": "100% of MBM's 800 (with their collision model)"}
CLASSICAL = ("uniform", "goal-bias", "ompl-rrtconnect", "ompl-rrt", "vamp-rrtconnect")
#: Rows of planners not ours, as the tables label them (VAMP's own row, measured on this machine).
OTHERS = {"vamp-rrtconnect": "VAMP, measured here"}


def _median(values: list[float | None], scale: float = 1.0) -> float | None:
    data = [v for v in values if v is not None]
    return None if not data else scale * float(np.median(data))


def _fmt(x: float | None, digits: int = 0) -> str:
    return "-" if x is None else f"{x:,.{digits}f}"


def row_figures(runs: list[dict[str, Any]], max_nodes: int, limit: float | None = None) -> dict[str, Any]:
    """A row's figures; solved: :func:`train.benchmark.stats.solved`, as in the benchmark's own tables
    (``limit``, OMPL's solve time limit, is in the rows' success already)."""
    return {"solved": sum(solved(r, max_nodes) for r in runs), "n": len(runs),
            "iterations": _median([r.get("iterations") for r in runs]),
            "mean_iterations": float(np.mean([r["iterations"] for r in runs if r.get("iterations") is not None]))
            if any(r.get("iterations") is not None for r in runs) else None,
            "p95_iterations": float(np.percentile([r["iterations"] for r in runs if r.get("iterations") is not None], 95))
            if any(r.get("iterations") is not None for r in runs) else None,
            "checks": _median([r["collision_checks"] for r in runs]),
            "time_ms": _median([r["wall_time_s"] for r in runs], 1e3)}


def tables(report: dict[str, Any]) -> str:
    max_nodes, limit = report["max_nodes"], report.get("time_limit_s", 10.0)
    names = list(report["runs"])
    out = [f"Per scene ({report['problems']} test problems, seed {report['seed']}; solved: a path found within "
           f"{max_nodes:,} nodes that passes the re-check, OMPL's within its {limit:g} s; medians):", "",
           "| scene | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for scene in SCENES:
        cells = []
        for name in names:
            runs = [r for r in report["runs"][name] if r.get("family") == scene]
            if not runs:
                cells.append("-")
                continue
            f = row_figures(runs, max_nodes, limit)
            cells.append(f"{f['solved']}/{f['n']}, {_fmt(f['iterations'])} it, {_fmt(f['checks'])} checks, "
                         f"{_fmt(f['time_ms'], 3 if name in OTHERS else 1)} ms")
        out.append(f"| {scene} | " + " | ".join(cells) + " |")
    out += ["", "All scenes beside the published figures (iterations: median / mean / p95):", "",
            "| planner | solved | iterations | collision checks | time |", "|---|---|---|---|---|"]
    for name in names:
        f = row_figures(report["runs"][name], max_nodes, limit)
        its = "-" if f["iterations"] is None else \
            f"{_fmt(f['iterations'])} / {_fmt(f['mean_iterations'])} / {_fmt(f['p95_iterations'])}"
        out.append(f"| {name} ({OTHERS.get(name, 'ours')}) | {f['solved']}/{f['n']} | {its} | {_fmt(f['checks'])} | "
                   f"{_fmt(f['time_ms'], 3 if name in OTHERS else 1)} ms median |")
    out.append(f"| VAMP RRTConnect (published) | {VAMP['solved']} | {VAMP['iterations']} | - | {VAMP['time']} |")
    out.append(f"| cuRobo (published) | {CUROBO['solved']} | - | - | - |")
    learned = [n for n in names if n not in CLASSICAL and n != "uniform"]
    if "uniform" in names and learned:
        out += ["", "Learned rows against uniform (medians; ratio to uniform):", "",
                "| scenes | sampler | solved | collision checks | wall time [ms] |", "|---|---|---|---|---|"]
        for label, scenes in (("in-distribution (5 training scenes)", set(SCENES) - set(HELD_OUT_SCENES)),
                              ("held-out (bookshelf_thin, cage)", set(HELD_OUT_SCENES))):
            base = row_figures([r for r in report["runs"]["uniform"] if r.get("family") in scenes], max_nodes, limit)
            out.append(f"| {label} | uniform | {base['solved']}/{base['n']} | {_fmt(base['checks'])} | "
                       f"{_fmt(base['time_ms'], 1)} |")
            for name in learned:
                f = row_figures([r for r in report["runs"][name] if r.get("family") in scenes], max_nodes, limit)
                out.append(f"| {label} | {name} | {f['solved']}/{f['n']} | {_fmt(f['checks'])} "
                           f"({f['checks'] / base['checks']:.2f}x) | {_fmt(f['time_ms'], 1)} "
                           f"({f['time_ms'] / base['time_ms']:.2f}x) |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("report", type=Path, help="a panda-mbm benchmark JSON")
    args = ap.parse_args(argv)
    try:
        report = json.loads(args.report.read_text())
    except (OSError, ValueError) as exc:
        print(f"mbm_table: cannot read {args.report}: {exc}", file=sys.stderr)
        return 2
    if report.get("task") != "panda-mbm":
        print(f"mbm_table: {args.report} is a {report.get('task')!r} report, not panda-mbm", file=sys.stderr)
        return 2
    print(tables(report))
    if "vamp-rrtconnect" in report["runs"]:     # ours against VAMP per scene (tools/vamp_table.py)
        from tools.vamp_table import ratio_table
        print("\n" + ratio_table(report))
    return 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
