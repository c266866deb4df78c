"""OMPL reference rows (through the isolated runner) and OMPL benchmark logs of every row."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

from tqdm import tqdm

from train.benchmark.args import (
    OMPL_INSTALL_HINT,
    OMPL_PREFIX,
    BenchmarkArgs,
    BenchmarkError,
    is_ompl,
    is_vamp,
    time_limit_s,
)


def _finite_or_none(x: Any) -> float | None:
    import math
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _ompl_record(planner_row: str, index: int, seed: int, result: dict[str, Any]) -> dict[str, Any]:
    """Map one result of the OMPL runner (see ``ompl_runner.solve_problem``) onto a benchmark record."""
    def as_int(x: Any) -> int | None:
        return None if x is None else int(x)

    success = bool(result.get("solved"))
    return {
        "sampler": planner_row, "problem": int(index), "seed": seed, "success": success,
        "nodes_expanded": as_int(result.get("nodes")),            # OMPL planner-data vertices
        "edges": as_int(result.get("edges_checked")),
        "collision_checks": as_int(result.get("collision_checks")),
        "iterations": as_int(result.get("iterations")),            # geometric planners: samples drawn
        "path_length": _finite_or_none(result.get("path_length")) if success else None,
        "path_valid": bool(result.get("path_valid")) if success else None,   # re-checked by the runner
        "path_valid_fine": (bool(result.get("path_valid_fine", result.get("path_valid")))   # finer (geometric)
                            if success else None),
        "wall_time_s": _finite_or_none(result.get("time")),       # OMPL's solve() time
        "family": result.get("family"),
        "ompl": {k: v for k, v in result.items() if isinstance(v, (int, float, str, bool))},
    }


def run_ompl_rows(args: BenchmarkArgs, planner_row: str, indices: list[int]) -> list[dict[str, Any]]:
    """Plan ``indices`` with an OMPL planner through the isolated runner (one subprocess per call)."""
    try:
        from gnn_mp_envs.baselines import ompl_runner
    except ImportError as exc:
        raise BenchmarkError(f"the OMPL runner is not available in this checkout ({exc})") from None
    planner = planner_row[len(OMPL_PREFIX):]
    task_kwargs = {k: v for k, v in (("scene", args.scene), ("checker", args.checker)) if v is not None} or None
    try:
        with tqdm(total=len(indices), desc=f"{args.task} {planner_row}", unit="run", disable=not args.progress,
                  file=sys.stderr) as bar:
            results = ompl_runner.run_ompl(args.task, indices, split=args.split, task_kwargs=task_kwargs,
                                           planner=planner, time_limit=time_limit_s(args), seed=args.seed,
                                           on_problem=lambda _: bar.update(1), modules=args.modules,
                                           keep_paths=args.save_paths)
    except ompl_runner.OMPLUnavailableError:
        raise BenchmarkError(OMPL_INSTALL_HINT) from None
    except subprocess.TimeoutExpired as exc:
        raise BenchmarkError(f"{planner_row} on {args.task}: the OMPL runner did not finish within "
                             f"{exc.timeout:.0f} s for {len(indices)} problems") from None
    except (ValueError, NotImplementedError, RuntimeError) as exc:
        raise BenchmarkError(f"{planner_row} on {args.task}: {exc}".replace("\n", " ")) from None
    # OMPL's RNG is seeded once per runner call (with --seed + 1), so the run's seed is --seed.
    records = [_ompl_record(planner_row, i, args.seed, r) for i, r in zip(indices, results)]
    if args.save_paths:     # OMPL's own path: its states; a control planner's controls and durations per edge
        for record, result in zip(records, results):
            solved = record["success"] and result.get("path") is not None
            record["path"] = result["path"] if solved else None
            record["path_controls"] = result.get("controls") if solved else None
            if solved and result.get("durations") is not None:
                record["path_durations"] = result["durations"]
    return records


def write_ompl_logs(args: BenchmarkArgs, report: dict[str, Any], directory: Path) -> Path | None:
    """All rows in OMPL's benchmark log format (for Planner Arena), via the runner's log writer."""
    try:
        from gnn_mp_envs.baselines.ompl_log import write_ompl_log
    except ImportError as exc:
        raise BenchmarkError(f"the OMPL log writer is not available in this checkout ({exc})") from None
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{args.task}.log"
    from gnn_mp_envs.registration import task_spec
    control = task_spec(args.task).ompl_control_setup is not None
    # the log's planner names: OMPL's control-based planners say so (ompl-rrt of maze2d is geometric RRT)
    log_name = {name: ("ompl-control-" + name[len(OMPL_PREFIX):] if control and is_ompl(name) else name)
                for name in args.samplers}
    results_by_planner = {log_name[name]: [_as_ompl_run(r, time_limit_s(args)) for r in report["runs"][name]]
                          for name in args.samplers}
    total_time = sum(r["time"] or 0.0 for runs in results_by_planner.values() for r in runs)
    settings = {log_name[name]: ({"time_limit": time_limit_s(args), "seed": args.seed + 1} if is_ompl(name)
                                 else {"vamp_defaults": 1, "halton_skip": args.seed} if is_vamp(name)
                                 else {"max_nodes": report["max_nodes"]})
                for name in args.samplers}
    # one word: OMPL's ompl_benchmark_statistics.py names the experiment by the line's last word
    experiment = ":".join(["gnn-mp", report["env_id"], *(f"{k}={v}" for k, v in
                                                          (("scene", args.scene), ("checker", report.get("checker")))
                                                          if v)])
    write_ompl_log(path, experiment, results_by_planner, time_limit=time_limit_s(args), seed=args.seed,
                   total_time=total_time, planner_settings=settings)
    return path


def _as_ompl_run(record: dict[str, Any], time_limit: float = float("inf")) -> dict[str, Any]:
    """A benchmark record in the OMPL runner's keys (which the log writer maps to OMPL property names).
    The log states a time limit per run: a run of ours that took longer counts as a timeout there."""
    run = dict(record.get("ompl", {}))   # OMPL rows: the runner's own fields (status, approximate, ...)
    for key in ("task", "split", "index", "planner", "family"):
        run.pop(key, None)
    late = record["wall_time_s"] is not None and record["wall_time_s"] > time_limit
    if late and record["success"]:
        run["status"] = "Timeout"
    run.update({
        "solved": record["success"] and not late, "time": record["wall_time_s"], "path_length": record["path_length"],
        "nodes": record["nodes_expanded"], "edges_checked": record["edges"],
        "collision_checks": record["collision_checks"], "problem": record["problem"],
    })
    if record.get("iterations") is not None:
        run["iterations"] = record["iterations"]
    return run
