"""VAMP's rows (``vamp-rrtconnect``): VAMP's own planner and collision checker on the benchmark's
problems, through the isolated runner (:mod:`gnn_mp_envs.baselines.vamp_runner`); their paths are
re-checked by the benchmark like every row's."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
from tqdm import tqdm

from train.benchmark.args import VAMP_PREFIX, BenchmarkArgs, BenchmarkError, time_limit_s, vamp_hint


def vamp_record(row: str, index: int, seed: int, result: dict[str, Any], family: str | None,
                time_limit: float) -> dict[str, Any]:
    """One result of the VAMP runner as a benchmark record. Success: VAMP solved it within the time
    budget (VAMP has no time limit of its own; it stops at its iteration budget); the path's verdicts
    come from the benchmark's re-check (``path_valid``: our checker at the planner's resolution,
    ``path_valid_fine``: pybullet at 10x finer)."""
    wall = result.get("time")
    success = bool(result.get("solved")) and wall is not None and wall <= time_limit
    return {
        "sampler": row, "problem": int(index), "seed": int(seed), "success": success,
        "nodes_expanded": result.get("nodes"),     # both trees' sizes
        "edges": None, "collision_checks": None,   # VAMP counts neither
        "iterations": result.get("iterations"),
        "path_length": result.get("path_length") if success else None,
        "path_valid": None, "path_valid_fine": None,
        "wall_time_s": wall,                       # VAMP's own planning time (inside its C++ planner)
        "sampler_time_s": None, "planner_time_s": None,
        "family": family,
        "vamp": {k: v for k, v in result.items() if k != "path" and isinstance(v, (int, float, str, bool))},
    }


def run_vamp_rows(args: BenchmarkArgs, row: str, indices: list[int], env: Any, path_key: str) -> list[dict[str, Any]]:
    """Plan ``indices`` (the same split and problems as the other rows: ``env``'s, the benchmark env)
    with VAMP's planner of ``row``. A solved run's path, ``(states, None)``, waits in the record under
    ``path_key`` for the benchmark's re-check."""
    from gnn_mp_envs.baselines import vamp_runner

    problems = [env.task.problem(env.split, i) for i in indices]
    limit = time_limit_s(args)
    try:
        with tqdm(total=len(indices), desc=f"{args.task} {row}", unit="run", disable=not args.progress,
                  file=sys.stderr) as bar:
            results = vamp_runner.run_vamp(problems, vamp_runner.VAMP_ROBOTS[args.task], row[len(VAMP_PREFIX):],
                                           seed=args.seed, on_problem=lambda _: bar.update(1))
    except vamp_runner.VAMPUnavailableError as exc:
        raise BenchmarkError(f"{row}: {exc}" if vamp_runner.vamp_python() else vamp_hint()) from None
    except subprocess.TimeoutExpired as exc:
        raise BenchmarkError(f"{row} on {args.task}: the VAMP runner did not finish within {exc.timeout:.0f} s "
                             f"for {len(indices)} problems") from None
    except (ValueError, RuntimeError) as exc:
        raise BenchmarkError(f"{row} on {args.task}: {exc}".replace("\n", " ")) from None
    records = []
    for index, problem, result in zip(indices, problems, results):
        record = vamp_record(row, index, args.seed, result, getattr(problem, "family", None), limit)
        path = result["path"] if record["success"] else None
        if path is not None:
            record[path_key] = (np.asarray(path, dtype=np.float64), None)
        if args.save_paths:
            record["path"] = None if path is None else np.asarray(path, dtype=np.float64).tolist()
            record["path_controls"] = None
        records.append(record)
    return records
