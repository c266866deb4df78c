"""Choose a learned sampler's adaptive-mixture setting on validation problems: the in-distribution
split ``val`` and the task's held-out validation kinds (``TaskSpec.validation_scenes``), never the
OOD test suites.

    python -m tools.tune_adaptive --sampler gnn --task maze2d --problems 40 \\
        --candidates '[true, {"cells": 40}]' --write

Each candidate (a value of the ``adaptive`` setting: true = the defaults of
``agents.samplers.adaptive.DEFAULTS``, a dict = some of them overridden) and, as the reference
row, the fixed shares (``false``, never chosen: a shipped sampler keeps the adaptive guarantee)
plan problems ``0..N-1`` of every kind with the benchmark's seeding rule; per kind the median
headline figure (``TaskSpec.headline_metric``) is divided by uniform's. Chosen: among the
candidates whose worst ratio is at most ``--worst`` (all, when none is), the one with the
smallest geometric mean over the kinds. ``--write`` stores it in the shipped checkpoint
(``meta["sampler"]["adaptive"]``) and its sidecar, with the table and this command.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from train.args import OneLineParser, add_dataclass_arguments, arg, from_namespace, positive_float, positive_int
from tools.shipped_settings import store_tuned_setting, tool_command


@dataclass
class Args:
    sampler: str = arg("gnn", "learned sampler")
    task: str = arg("maze2d", "task")
    problems: int = arg(40, "problems per kind", parse=positive_int)
    candidates: str = arg('[true]', "JSON list of values of the adaptive setting (true or dicts of its settings)")
    worst: float = arg(1.1, "largest acceptable ratio to uniform on any kind", parse=positive_float)
    seed: int = arg(0, "root seed")
    workers: int = arg(2, "worker processes", parse=positive_int)
    write: bool = arg(False, "store the chosen value in the shipped checkpoint")


def measure(task: str, sampler: str, kinds: list[str | None], problems: int, seed: int, workers: int,
            candidates: list[Any]) -> dict:
    """``{kind: {"uniform": records, json(candidate): records}}`` (benchmark episodes, split ``val``)."""
    from train.benchmark.runs import WorkerPool
    jobs = []
    for kind in kinds:
        env_kwargs = {"split": "val", **({"scene": kind} if kind else {})}
        jobs += [(task, env_kwargs, "uniform", i, seed, None, ()) for i in range(problems)]
        for value in candidates:
            jobs += [(task, env_kwargs, sampler, i, seed, None, (("adaptive", value),)) for i in range(problems)]
    results: list = []
    with WorkerPool(workers) as pool:
        pool.run(jobs, results.append, _keyed_job)
    rows: dict = {}
    for (kind, key), record in results:
        rows.setdefault(kind, {}).setdefault(key, []).append(record)
    return rows


def _keyed_job(job: tuple):
    from train.benchmark.runs import run_episode
    task, env_kwargs, name, index, seed, checkpoint, settings = job
    record = run_episode(task, env_kwargs, name, index, seed, checkpoint, settings)
    return (env_kwargs.get("scene"), "uniform" if name == "uniform" else json.dumps(dict(settings)["adaptive"])), record


def table(rows: dict, candidates: list[Any], metric: str) -> dict:
    """Per candidate: per kind ``(ratio, success)`` and the geometric mean and worst ratio."""
    out = {}
    for value in candidates:
        key = json.dumps(value)
        kinds = {}
        for kind, runs in rows.items():
            u = float(np.median([r[metric] for r in runs["uniform"]]))
            m = float(np.median([r[metric] for r in runs[key]]))
            kinds[kind or "in-distribution"] = {"ratio": m / u, "success": float(np.mean([r["success"] for r in runs[key]])),
                                                "uniform_success": float(np.mean([r["success"] for r in runs["uniform"]]))}
        ratios = [k["ratio"] for k in kinds.values()]
        out[key] = {"kinds": kinds, "geometric_mean": math.exp(sum(map(math.log, ratios)) / len(ratios)),
                    "worst": max(ratios)}
    return out


def choose(summary: dict, worst: float) -> str:
    ok = [k for k, v in summary.items() if v["worst"] <= worst] or list(summary)
    return min(ok, key=lambda k: summary[k]["geometric_mean"])


def main(argv: list[str] | None = None) -> int:
    from gnn_mp_envs.registration import task_spec
    parser = OneLineParser(prog="python -m tools.tune_adaptive", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    try:
        candidates = json.loads(args.candidates)
        assert isinstance(candidates, list) and candidates
        assert all(c is True or isinstance(c, dict) for c in candidates)
    except (ValueError, AssertionError):
        parser.error(f"--candidates must be a JSON list of true or dicts, got {args.candidates!r}")
    spec = task_spec(args.task)
    kinds = [None, *spec.validation_scenes]
    rows = measure(args.task, args.sampler, kinds, args.problems, args.seed, args.workers, [False, *candidates])
    summary = table(rows, [False, *candidates], spec.headline_metric)
    print(f"{args.sampler} on {args.task}: median {spec.headline_metric} / uniform's, split val, "
          f"{args.problems} problems per kind (success)")
    for key, v in summary.items():
        cells = "  ".join(f"{k}: {x['ratio']:.2f} ({x['success']:.0%})" for k, x in v["kinds"].items())
        print(f"  {key:>32}: {cells}  | geo. mean {v['geometric_mean']:.2f}, worst {v['worst']:.2f}")
    chosen = choose({k: v for k, v in summary.items() if k != "false"}, args.worst)
    print(f"chosen: adaptive={chosen}")
    if args.write:
        store_tuned_setting(args.sampler, args.task, {"adaptive": json.loads(chosen)}, "adaptive_tuning",
                            {"command": tool_command("tools.tune_adaptive", argv),
                             "val_problems_per_kind": args.problems, "rows": summary})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
