"""Statistics of runs and the report document (the ``--json`` schema of docs/results.md)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from train.benchmark.args import BenchmarkArgs, task_spec_for, time_limit_s

#: The counters every run reports, in table order.
METRICS: tuple[str, ...] = ("nodes_expanded", "edges", "collision_checks", "iterations", "path_length",
                            "wall_time_s", "sampler_time_s", "planner_time_s")
#: Metrics summarised over successful runs only (:func:`solved`; a failed run has no path).
SUCCESS_ONLY_METRICS: frozenset[str] = frozenset({"path_length"})


def summarize(values: list[float | None]) -> dict[str, float | None]:
    """median, mean, q25, q75, p95 of the finite values; all None when there are none."""
    data = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)
    if data.size == 0:
        return {"median": None, "mean": None, "q25": None, "q75": None, "p95": None}
    q25, median, q75, p95 = np.percentile(data, [25, 50, 75, 95])
    return {"median": float(median), "mean": float(data.mean()), "q25": float(q25), "q75": float(q75),
            "p95": float(p95)}


def solved(record: dict[str, Any], max_nodes: int | None = None) -> bool:
    """The one meaning of success in every table of a report (the main table's success rate, the field
    table's and the per-scene table's "solved", ``tools/mbm_table``): the planner found a path (an OMPL
    row: within its solve time limit), within the node budget (an OMPL row's planner-data vertices
    too), and the path passed the independent re-check (``path_valid`` is not False). The wall time is
    no part of it: success stays a counter, deterministic for a seed whatever the machine's load (the
    success-vs-time figure shows the time budgets)."""
    if not record.get("success"):
        return False
    nodes = record.get("nodes_expanded")
    if max_nodes is not None and nodes is not None and nodes > max_nodes:
        return False
    return record.get("path_valid") is not False


def sampler_summary(records: list[dict[str, Any]], max_nodes: int | None = None) -> dict[str, Any]:
    """Success rate (:func:`solved`) and per-metric statistics of one sampler's runs."""
    wins = [solved(r, max_nodes) for r in records]
    summary: dict[str, Any] = {"success_rate": float(np.mean(wins)) if records else None}
    for metric in METRICS:
        runs = [r for r, won in zip(records, wins) if won] if metric in SUCCESS_ONLY_METRICS else records
        summary[metric] = summarize([r.get(metric) for r in runs])
    return summary


def build_report(args: BenchmarkArgs, runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """The ``--json`` document (schema in docs/results.md)."""
    spec = task_spec_for(args.task)
    max_nodes = args.max_nodes or spec.max_nodes
    return {
        "task": args.task,
        "problems": int(args.problems),
        "seed": int(args.seed),
        "results": {name: sampler_summary(runs[name], max_nodes) for name in args.samplers},
        "env_id": spec.env_id,
        "split": args.split,
        "max_nodes": int(max_nodes),
        "time_limit_s": time_limit_s(args),   # the time budget (OMPL rows: their solve limit)
        "scene": args.scene,
        "checker": args.checker,
        **({"balance": True} if getattr(args, "balance", False) else {}),   # --balance: BiRRT's balanced trees
        "samplers": list(args.samplers),
        "rechecked": bool(args.recheck),      # False: --no-recheck, success unverified
        "runs": {name: [{k: v for k, v in r.items() if k != "snapshots"} for r in runs[name]]
                 for name in args.samplers},
    }
