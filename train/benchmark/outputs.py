"""One benchmark from flags to files: run, print the table, write --json/--plot/--render/--ompl-log."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from train.benchmark.args import BenchmarkArgs
from train.benchmark.ompl_rows import write_ompl_logs
from train.benchmark.plots import plot_report, render_growth
from train.benchmark.runs import run_benchmark
from train.benchmark.tables import format_table


def write_outputs(args: BenchmarkArgs, report: dict[str, Any]) -> dict[str, Path]:
    """Write the requested --json / --plot / --render / --ompl-log outputs."""
    written: dict[str, Path] = {}
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
        written["json"] = args.json
    if args.plot is not None:
        plot_report(report, args.plot)
        written["plot"] = args.plot
    if args.render is not None:
        for i, path in enumerate(render_growth(args, args.render)):
            written[f"render{i}"] = path
    if args.ompl_log is not None:
        path = write_ompl_logs(args, report, args.ompl_log)
        if path is not None:
            written["ompl_log"] = path
    return written


def benchmark(args: BenchmarkArgs) -> dict[str, Any]:
    """Run, print the table, write outputs."""
    report = run_benchmark(args)
    print(format_table(report))
    for kind, path in write_outputs(args, report).items():
        print(f"wrote {path}", file=sys.stderr)
    return report
