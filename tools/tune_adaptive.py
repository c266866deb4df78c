"""Choose a learned sampler's mixture setting on validation problems: the in-distribution split
``val`` and the task's held-out validation kinds (``TaskSpec.validation_scenes``), never the OOD
test suites.

    python -m tools.tune_adaptive --sampler gnn --task maze2d --problems 40 \\
        --candidates '[true, {"cells": 40}]' --write
    python -m tools.tune_adaptive --sampler gnn-cvae --task pendulum --setting uniform_mix \\
        --candidates '[0.5, 0.6, 0.7, 0.8]' --write

``--setting adaptive`` (the default): each candidate is a value of the ``adaptive`` setting
(true = the defaults of ``agents.samplers.adaptive.DEFAULTS``, a dict = some of them
overridden), and the fixed shares (``false``) plan as a reference row, never chosen: a shipped
sampler keeps the adaptive guarantee. ``--setting uniform_mix`` or ``goal_bias``: each candidate
is that share, a number in [0, 1) (list the stored value too: it is not added for you). Every
candidate plans problems ``0..N-1`` of every kind with the benchmark's seeding rule; per kind the
median headline figure (``TaskSpec.headline_metric``; with ``--metric wall_time_s`` the wall time
per problem, inference included) is divided by uniform's. Chosen: among the
candidates whose worst ratio is at most ``--worst`` (all, when none is), the one with the
smallest geometric mean over the kinds. ``--write`` stores it in the shipped checkpoint
(``meta["sampler"][setting]``) and its sidecar (``<setting>_tuning``), with the table and this
command.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from train.args import (OneLineParser, add_dataclass_arguments, arg, from_namespace, positive_float, positive_int,
                        seed_int)
from tools.shipped_settings import store_tuned_setting, tool_command


@dataclass
class Args:
    sampler: str = arg("gnn", "learned sampler")
    task: str = arg("maze2d", "task")
    problems: int = arg(40, "problems per kind", parse=positive_int)
    setting: str = arg("adaptive", "the mixture setting to tune: adaptive, uniform_mix or goal_bias",
                       choices=("adaptive", "uniform_mix", "goal_bias"))
    candidates: str = arg('[true]', "JSON list of values of the setting (adaptive: true or dicts of its settings; "
                                     "a share: numbers in [0, 1))")
    metric: str = arg("headline", "the figure divided by uniform's: the task's headline metric, or wall_time_s "
                                  "(time to solution, inference included)", choices=("headline", "wall_time_s"))
    worst: float = arg(1.1, "largest acceptable ratio to uniform on any kind", parse=positive_float)
    seed: int = arg(0, "root seed", parse=seed_int)
    workers: int = arg(2, "worker processes", parse=positive_int)
    write: bool = arg(False, "store the chosen value in the shipped checkpoint")


def measure(task: str, sampler: str, kinds: list[str | None], problems: int, seed: int, workers: int,
            candidates: list[Any], setting: str = "adaptive") -> dict:
    """``{kind: {"uniform": records, json(candidate): records}}`` (benchmark episodes, split ``val``)."""
    from train.workers import WorkerPool
    jobs = []
    for kind in kinds:
        env_kwargs = {"split": "val", **({"scene": kind} if kind else {})}
        jobs += [(task, env_kwargs, "uniform", i, seed, None, ()) for i in range(problems)]
        for value in candidates:
            jobs += [(task, env_kwargs, sampler, i, seed, None, ((setting, value),)) for i in range(problems)]
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
    return (env_kwargs.get("scene"), "uniform" if name == "uniform" else json.dumps(settings[0][1])), record


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


def parse_candidates(setting: str, text: str) -> list[Any] | None:
    """The candidate values of ``--candidates`` for ``setting``, or None when they are not valid."""
    try:
        values = json.loads(text)
    except ValueError:
        return None
    if not isinstance(values, list) or not values:
        return None
    if setting == "adaptive":
        ok = all(v is True or isinstance(v, dict) for v in values)
    else:
        ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v < 1.0 for v in values)
    return values if ok else None


def main(argv: list[str] | None = None) -> int:
    from gnn_mp_envs.registration import task_spec
    parser = OneLineParser(prog="python -m tools.tune_adaptive", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    candidates = parse_candidates(args.setting, args.candidates)
    if candidates is None:
        expected = "true or dicts" if args.setting == "adaptive" else "numbers in [0, 1)"
        parser.error(f"--candidates must be a JSON list of {expected} for --setting {args.setting}, got {args.candidates!r}")
    reference = [False] if args.setting == "adaptive" else []
    spec = task_spec(args.task)
    kinds = [None, *spec.validation_scenes]
    rows = measure(args.task, args.sampler, kinds, args.problems, args.seed, args.workers, [*reference, *candidates],
                   args.setting)
    metric = spec.headline_metric if args.metric == "headline" else args.metric
    summary = table(rows, [*reference, *candidates], metric)
    print(f"{args.sampler} on {args.task}: median {metric} / uniform's, split val, "
          f"{args.problems} problems per kind (success)")
    for key, v in summary.items():
        cells = "  ".join(f"{k}: {x['ratio']:.2f} ({x['success']:.0%})" for k, x in v["kinds"].items())
        print(f"  {key:>32}: {cells}  | geo. mean {v['geometric_mean']:.2f}, worst {v['worst']:.2f}")
    chosen = choose({k: v for k, v in summary.items() if k not in map(json.dumps, reference)}, args.worst)
    print(f"chosen: {args.setting}={chosen}")
    if args.write:
        store_tuned_setting(args.sampler, args.task, {args.setting: json.loads(chosen)}, f"{args.setting}_tuning",
                            {"command": tool_command("tools.tune_adaptive", argv),
                             "metric": metric, "val_problems_per_kind": args.problems, "rows": summary})
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
