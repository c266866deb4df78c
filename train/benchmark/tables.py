"""The fixed-width table the benchmark prints and writes to ``<task>.txt``."""

from __future__ import annotations

from typing import Any


def _fmt(x: float | None, digits: int) -> str:
    if x is None:
        return "-"
    return f"{x:.{digits}f}"


def ms_digits(median_ms: float | None) -> int:
    """Decimals of a time in ms: three significant figures from 1 ms up (1.28, 12.8, 128), none from
    100 ms, three decimals below 1 ms (VAMP's rows plan in tens of microseconds), so rows a few tenths
    apart read apart."""
    if median_ms is None or median_ms >= 100.0:
        return 0
    if median_ms >= 10.0:
        return 1
    return 2 if median_ms >= 1.0 else 3


def _cell(stats: dict[str, float | None], digits: int = 0, scale: float = 1.0) -> str:
    if stats["median"] is None:
        return "-"
    m, lo, hi = (stats[k] * scale for k in ("median", "q25", "q75"))
    return f"{_fmt(m, digits)} [{_fmt(lo, digits)}, {_fmt(hi, digits)}]"


def path_check_note(report: dict[str, Any]) -> str:
    """How many returned paths passed the re-check of every edge (``problem.path_valid``) at the
    planner's resolution and, independently, at ``PATH_CHECK_REFINE`` times finer; rows with
    failures are named."""
    from gnn_mp_envs.core.problem import PATH_CHECK_REFINE
    if report.get("rechecked") is False:
        return UNVERIFIED_NOTE
    runs = report["runs"]
    checked = [r for rows in runs.values() for r in rows if r.get("path_valid") is not None]
    fine = [r for rows in runs.values() for r in rows if r.get("path_valid_fine") is not None]
    notes = []
    for key, pool, what in (("path_valid", checked, "edge by edge"),
                            ("path_valid_fine", fine, f"at {PATH_CHECK_REFINE}x finer resolution")):
        if not pool and key == "path_valid_fine":
            continue
        bad = {name: sum(r.get(key) is False for r in rows) for name, rows in runs.items()}
        bad = {name: n for name, n in bad.items() if n}
        if not bad:
            notes.append(f"{len(pool)} of {len(pool)} valid {what}")
        else:
            notes.append(f"{sum(bad.values())} of {len(pool)} INVALID {what} ("
                         + ", ".join(f"{name}: {n}" for name, n in bad.items()) + ")")
    return "returned paths re-checked: " + "; ".join(notes)


#: The note of a report made with ``--no-recheck`` (in place of the re-check's counts).
UNVERIFIED_NOTE = ("returned paths NOT re-checked (--no-recheck): success is the planner's word, unverified "
                   "(OMPL rows: re-checked by their runner)")

#: What every table of a report counts as solved (:func:`train.benchmark.stats.solved`).
SOLVED_NOTE = "solved = a path found within {:,} nodes that passes the re-check"


def solved_note(report: dict[str, Any]) -> str:
    """:data:`SOLVED_NOTE` for ``report`` (a ``--no-recheck`` report's paths were not re-checked)."""
    note = SOLVED_NOTE.format(report["max_nodes"])
    return note.replace("that passes the re-check", "(not re-checked)") if report.get("rechecked") is False else note


def success_rate(report: dict[str, Any], name: str) -> float | None:
    """The share of ``name``'s runs :func:`~train.benchmark.stats.solved`, from the runs when the report
    carries them (a report written by an earlier version stored another meaning), else its stored rate."""
    from train.benchmark.stats import solved
    runs = report.get("runs", {}).get(name)
    if not runs:
        return report["results"][name].get("success_rate")
    return sum(solved(r, report.get("max_nodes")) for r in runs) / len(runs)


def format_table(report: dict[str, Any]) -> str:
    """A fixed-width table: success rate and median [q25, q75] per metric."""
    unverified = report.get("rechecked") is False
    header = ["sampler", "success (unverified)" if unverified else "success", "nodes expanded", "edges",
              "collision checks", "path length*", "wall time [ms]", "sampler / planner [ms]"]
    rows = [header]
    for name, s in report["results"].items():
        rate = success_rate(report, name)
        split = "-"
        if s.get("sampler_time_s", {}).get("median") is not None:
            sampler_ms, planner_ms = (1e3 * s[k]["median"] for k in ("sampler_time_s", "planner_time_s"))
            split = f"{sampler_ms:.{ms_digits(sampler_ms)}f} / {planner_ms:.{ms_digits(planner_ms)}f}"
        rows.append([name, "-" if rate is None else f"{100 * rate:.0f}%", _cell(s["nodes_expanded"]), _cell(s["edges"]),
                     _cell(s["collision_checks"]), _cell(s["path_length"], 2),
                     _cell(s["wall_time_s"], ms_digits(None if s["wall_time_s"]["median"] is None
                                                       else 1e3 * s["wall_time_s"]["median"]), 1e3),
                     split])
    widths = [max(len(r[c]) for r in rows) for c in range(len(header))]
    lines = ["  ".join(cell.ljust(w) if c == 0 else cell.rjust(w) for c, (cell, w) in enumerate(zip(r, widths)))
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    title = (f"{report['task']} ({report['env_id']}, max_nodes={report['max_nodes']}"
             + (f", scene={report['scene']}" if report.get("scene") else "")
             + (f", checker={report['checker']}" if report.get("checker") else "")
             + (", balanced trees" if report.get("balance") else "")
             + f"): {report['problems']} {'held-out' if report.get('split', 'test') == 'test' else report['split']} "
               f"problems, seed {report['seed']}")
    from gnn_mp_envs.registration import TASK_SPECS
    spec = TASK_SPECS.get(report["task"])
    unit = f" ({spec.path_unit})" if spec is not None else ""
    notes = [f"{solved_note(report).replace('solved', 'success', 1)}; median [q25, q75] over "
             f"the problems; *path length{unit} over successful runs only",
             "edges = extensions checked, blocked ones and goal connections included (so they can exceed nodes)",
             "wall time = planning loop incl. sampler inference (OMPL: solve time"
             + ("; VAMP: its own planning time" if any(n.startswith("vamp-") for n in report["results"]) else "")
             + "); it varies with machine load, the counters do not",
             "sampler / planner = medians of the time in the sampler (inference) and in env.step (the planner)",
             path_check_note(report)]
    return "\n".join([title, *lines, *notes])


def _grid(rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) if c == 0 else cell.rjust(w) for c, (cell, w) in enumerate(zip(r, widths)))
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return lines


def _median(values: list[float | None], scale: float = 1.0, digits: int | None = 0) -> str:
    """The median of the values given, as text (``digits`` None: :func:`ms_digits` of it)."""
    import numpy as np
    data = [v for v in values if v is not None]
    if not data:
        return "-"
    median = scale * float(np.median(data))
    return f"{median:.{ms_digits(median) if digits is None else digits}f}"


def format_field_table(report: dict[str, Any]) -> str:
    """The figures motion-planning papers report (Planner Arena, MotionBenchMaker, VAMP): success
    within the node and the time budget, median and 95th-percentile planning time, planner
    iterations, collision checks and the length of the first path found."""
    from train.benchmark.stats import solved as is_solved
    max_nodes, limit = report["max_nodes"], report.get("time_limit_s", 10.0)
    header = ["sampler", "solved", "time median / p95 [ms]", "iterations median / mean / p95",
              "collision checks", "initial path length"]
    rows = [header]
    for name, s in report["results"].items():
        runs = report["runs"][name]
        solved = sum(is_solved(r, max_nodes) for r in runs)
        t, it = s["wall_time_s"], s.get("iterations", {})
        d = ms_digits(None if t["median"] is None else 1e3 * t["median"])
        times = "-" if t["median"] is None else f"{1e3 * t['median']:.{d}f} / {1e3 * t['p95']:.{d}f}"
        iters = "-" if not it or it.get("median") is None else f"{it['median']:.0f} / {it['mean']:.0f} / {it['p95']:.0f}"
        rows.append([name, f"{solved}/{len(runs)}", times, iters, _cell(s["collision_checks"]),
                     _cell(s["path_length"], 2)])
    title = (f"{report['task']}: {report['problems']} problems, seed {report['seed']}; {solved_note(report)} "
             f"(OMPL rows: within their {limit:g} s solve limit)")
    notes = ["time: planning loop incl. sampler inference (OMPL: solve time), all runs; iterations: samples drawn "
             "(OMPL: uniform samples its planner drew); checks and initial path length: median [q25, q75]"]
    return "\n".join([title, *_grid(rows), *notes])


def families_of(report: dict[str, Any]) -> list[str]:
    """The problem families (scenes) the runs came from, in first-seen order (empty: none named)."""
    seen: dict[str, None] = {}
    for runs in report["runs"].values():
        for r in sorted(runs, key=lambda r: r["problem"]):
            if r.get("family") is not None:
                seen.setdefault(r["family"], None)
    return list(seen)


def format_family_table(report: dict[str, Any]) -> str:
    """Per scene family and sampler: solved (:func:`~train.benchmark.stats.solved`), median iterations,
    collision checks and planning time (ms)."""
    from train.benchmark.stats import solved
    max_nodes = report["max_nodes"]
    rows = [["scene", "sampler", "solved", "iterations", "checks", "time [ms]"]]
    for family in families_of(report):
        for name in report["results"]:
            runs = [r for r in report["runs"][name] if r.get("family") == family]
            if not runs:
                continue
            rows.append([family, name, f"{sum(solved(r, max_nodes) for r in runs)}/{len(runs)}",
                         _median([r.get("iterations") for r in runs]), _median([r["collision_checks"] for r in runs]),
                         _median([r["wall_time_s"] for r in runs], 1e3, digits=None)])
    return "\n".join([f"per scene (medians over the scene's problems; {solved_note(report)}):",
                      *_grid(rows)])
