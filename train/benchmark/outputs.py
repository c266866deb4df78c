"""One benchmark from flags to files: run, print the table, write the outputs the flags ask for."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from gnn_mp_envs.utils.io import atomic_write_text
from train.benchmark.args import BenchmarkArgs
from train.benchmark.ompl_rows import write_ompl_logs
from train.benchmark.plots import plot_report, plot_success_vs_time, render_growth
from train.benchmark.runs import BenchmarkIncomplete, run_benchmark
from train.benchmark.tables import families_of, format_family_table, format_table
from train.workers import WorkerPool


def write_outputs(args: BenchmarkArgs, report: dict[str, Any]) -> dict[str, Path]:
    """Write the requested --json / --plot / --success-plot / --render / --ompl-log outputs."""
    written: dict[str, Path] = {}
    if args.json is not None:
        write_json(args.json, report)
        written["json"] = args.json
    if args.plot is not None:
        plot_report(report, args.plot)
        written["plot"] = args.plot
    if args.success_plot is not None:
        plot_success_vs_time(report, args.success_plot)
        written["success_plot"] = args.success_plot
    if args.render is not None:
        for i, path in enumerate(render_growth(args, args.render)):
            written[f"render{i}"] = path
    if args.ompl_log is not None:
        path = write_ompl_logs(args, report, args.ompl_log)
        if path is not None:
            written["ompl_log"] = path
    return written


def write_json(path: Path, report: dict[str, Any]) -> Path:
    """The report as JSON, written atomically (an old file stays whole if the write fails)."""
    return atomic_write_text(path, json.dumps(report, indent=2, allow_nan=False) + "\n")


def benchmark(args: BenchmarkArgs, pool: WorkerPool | None = None) -> dict[str, Any]:
    """Run, print the table, write outputs. When the run stops early, the finished runs go to
    ``--json`` (marked ``"partial": true``) before the error is raised. ``pool``: worker processes
    shared with other calls (a suite's)."""
    try:
        report = run_benchmark(args, pool)
    except BenchmarkIncomplete as exc:
        if args.json is not None:
            if any(exc.report["runs"].values()):
                write_json(args.json, exc.report)
                print(f"wrote {args.json} (partial)", file=sys.stderr)
            else:     # nothing to keep: an older complete file stays as it was
                print(f"no run finished; {args.json} left as it was", file=sys.stderr)
        raise
    print(format_table(report))
    if len(families_of(report)) > 1:     # problems from several scene families: a line per family too
        print("\n" + format_family_table(report))
    for kind, path in write_outputs(args, report).items():
        print(f"wrote {path}", file=sys.stderr)
    return report
