"""The fixed-width table the benchmark prints and writes to ``<task>.txt``."""

from __future__ import annotations

from typing import Any


def _fmt(x: float | None, digits: int) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}f}"


def _cell(stats: dict[str, float | None], digits: int = 0, scale: float = 1.0) -> str:
    if stats["median"] is None:
        return "-"
    m, lo, hi = (stats[k] * scale for k in ("median", "q25", "q75"))
    return f"{_fmt(m, digits)} [{_fmt(lo, digits)}, {_fmt(hi, digits)}]"


def path_check_note(report: dict[str, Any]) -> str:
    """How many returned paths passed the re-check of every edge (``problem.path_valid``); the
    rows with failures are named."""
    checked = [r for runs in report["runs"].values() for r in runs if r.get("path_valid") is not None]
    bad = {name: sum(r.get("path_valid") is False for r in runs) for name, runs in report["runs"].items()}
    bad = {name: n for name, n in bad.items() if n}
    if not bad:
        return f"returned paths re-checked edge by edge: {len(checked)} of {len(checked)} valid"
    return (f"returned paths re-checked edge by edge: {sum(bad.values())} of {len(checked)} INVALID ("
            + ", ".join(f"{name}: {n}" for name, n in bad.items()) + ")")


def format_table(report: dict[str, Any]) -> str:
    """A fixed-width table: success rate and median [q25, q75] per metric."""
    header = ["sampler", "success", "nodes expanded", "edges", "collision checks", "path length*",
              "wall time [ms]", "sampler / planner [ms]"]
    rows = [header]
    for name, s in report["results"].items():
        split = "-"
        if s.get("sampler_time_s", {}).get("median") is not None:
            split = f"{1e3 * s['sampler_time_s']['median']:.0f} / {1e3 * s['planner_time_s']['median']:.0f}"
        rows.append([name, f"{100 * s['success_rate']:.0f}%", _cell(s["nodes_expanded"]), _cell(s["edges"]),
                     _cell(s["collision_checks"]), _cell(s["path_length"], 2), _cell(s["wall_time_s"], 0, 1e3),
                     split])
    widths = [max(len(r[c]) for r in rows) for c in range(len(header))]
    lines = ["  ".join(cell.ljust(w) if c == 0 else cell.rjust(w) for c, (cell, w) in enumerate(zip(r, widths)))
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    title = (f"{report['task']} ({report['env_id']}, max_nodes={report['max_nodes']}"
             + (f", scene={report['scene']}" if report.get("scene") else "")
             + f"): {report['problems']} {'held-out' if report.get('split', 'test') == 'test' else report['split']} "
               f"problems, seed {report['seed']}")
    from gnn_mp_envs.registration import TASK_SPECS
    spec = TASK_SPECS.get(report["task"])
    unit = f" ({spec.path_unit})" if spec is not None else ""
    notes = [f"median [q25, q75] over the problems; *path length{unit} over successful runs only",
             "edges = extensions checked, blocked ones and goal connections included (so they can exceed nodes)",
             "wall time = planning loop incl. sampler inference (OMPL: solve time); it varies with machine load, "
             "the counters do not",
             "sampler / planner = medians of the time in the sampler (inference) and in env.step (the planner)",
             path_check_note(report)]
    return "\n".join([title, *lines, *notes])
