"""Results in OMPL's benchmark log format, so ``ompl_benchmark_statistics.py`` and Planner
Arena can read our planners and OMPL's side by side.

The layout follows ``ompl::tools::Benchmark::saveResultsToStream`` (OMPL 1.5+) and the
grammar in OMPL's benchmark documentation: a preamble (version, experiment, host, date,
setup and CPU info blocks, seed, limits, run count, total time, the ``status`` enum), then
per planner its common properties, the sorted run property names with their types
(``REAL``, ``INTEGER``, ``BOOLEAN``), one ``"; "``-terminated line per run and a ``.``.

Pure Python, no OMPL needed.
"""

from __future__ import annotations

import datetime as _dt
import math
import platform
import socket
from pathlib import Path
from typing import Any

from gnn_mp_envs.utils.io import atomic_write_text

#: OMPL's ``PlannerStatus`` names in enum order (the ``status`` enum of the log).
STATUS_NAMES = ("Unknown status", "Invalid start", "Invalid goal", "Unrecognized goal type", "Timeout",
                "Approximate solution", "Exact solution", "Crash", "Abort", "Infeasible")
STATUS_EXACT = STATUS_NAMES.index("Exact solution")
STATUS_TIMEOUT = STATUS_NAMES.index("Timeout")

#: Our result keys -> OMPL property names (the names Planner Arena knows, where one exists).
PROPERTY_NAMES = {
    "time": "time",
    "solved": "solved",
    "approximate": "approximate solution",
    "path_length": "solution length",
    "path_states": "solution segments",
    "nodes": "graph states",
    "collision_checks": "collision checks",
    "edges_checked": "graph motions checked",
    "path_valid": "correct solution",
    "status": "status",
}


def _ptype(value: Any) -> str | None:
    if isinstance(value, bool):
        return "BOOLEAN"
    if isinstance(value, int):
        return "INTEGER"
    if isinstance(value, float):
        return "REAL"
    return None


def _fmt(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return "inf" if math.isinf(value) else ("nan" if math.isnan(value) else repr(value))
    return str(value)


def _status(result: dict[str, Any]) -> int:
    s = result.get("status")
    if isinstance(s, str) and s in STATUS_NAMES:
        return STATUS_NAMES.index(s)
    if isinstance(s, int) and not isinstance(s, bool):
        return s
    return STATUS_EXACT if result.get("solved") else STATUS_TIMEOUT


def run_properties(result: dict[str, Any]) -> dict[str, tuple[str, str]]:
    """OMPL property name -> (type, formatted value) of one run's result dict.

    Known keys get OMPL's names (see :data:`PROPERTY_NAMES`); other scalar keys are kept
    with underscores turned into spaces; lists, dicts and strings are dropped.
    """
    out: dict[str, tuple[str, str]] = {}
    for key, value in result.items():
        if key == "status":
            out["status"] = ("ENUM", str(_status(result)))
            continue
        if value is None and key in PROPERTY_NAMES:
            kind = {"path_length": "REAL", "path_valid": "BOOLEAN"}.get(key)
            if kind:
                out[PROPERTY_NAMES[key]] = (kind, "")
            continue
        kind = _ptype(value)
        if kind is None:
            continue
        out[PROPERTY_NAMES.get(key, key.replace("_", " "))] = (kind, _fmt(value))
    if "status" not in out:
        out["status"] = ("ENUM", str(_status(result)))
    return out


def write_ompl_log(path: str | Path, experiment_name: str, results_by_planner: dict[str, list[dict[str, Any]]],
                   time_limit: float = 0.0, memory_limit: float = 0.0, seed: int = 0,
                   total_time: float | None = None, planner_settings: dict[str, dict[str, Any]] | None = None,
                   setup: str = "", library: str = "gnn-mp-envs", library_version: str | None = None,
                   host: str | None = None, start_time: _dt.datetime | None = None) -> Path:
    """Write ``results_by_planner`` (planner name -> one result dict per run, as returned by
    :func:`~gnn_mp_envs.baselines.ompl_runner.run_ompl` or the benchmark) as an OMPL
    benchmark log; returns the path.

    ``planner_settings`` gives each planner's common properties (e.g. ``{"range": 0.4}``).
    Missing values in a run are written empty (NULL in the database). Experiment and planner
    names must not contain newlines.
    """
    if not results_by_planner:
        raise ValueError("no planners to write")
    for name in [experiment_name, library, *results_by_planner]:
        if "\n" in name or not name.strip():
            raise ValueError(f"names must be non-empty single lines, got {name!r}")
    runs_per_planner = max(len(r) for r in results_by_planner.values())
    if total_time is None:
        total_time = float(sum(float(r.get("time") or 0.0) for runs in results_by_planner.values() for r in runs))
    start_time = start_time or _dt.datetime.now()
    lines = [
        f"{library} version {library_version or _library_version(library)}",
        f"Experiment {experiment_name}",
        f"Running on {host or socket.gethostname() or 'UNKNOWN'}",
        f"Starting at {start_time.isoformat(timespec='microseconds')}",
        "<<<|", *(setup.rstrip("\n").split("\n") if setup else []), "|>>>",
        "<<<|", f"{platform.processor() or platform.machine()} {platform.platform()}", "|>>>",
        f"{int(seed)} is the random seed",
        f"{float(time_limit)} seconds per run",
        f"{float(memory_limit)} MB per run",
        f"{runs_per_planner} runs per planner",
        f"{float(total_time)} seconds spent to collect the data",
        "1 enum type",
        "status|" + "|".join(STATUS_NAMES),
        f"{len(results_by_planner)} planners",
    ]
    for planner, runs in results_by_planner.items():
        lines.append(planner)
        common = (planner_settings or {}).get(planner, {})
        lines.append(f"{len(common)} common properties")
        lines += [f"{k} = {v}" for k, v in sorted(common.items())]
        per_run = [run_properties(r) for r in runs]
        types: dict[str, str] = {}
        for props in per_run:
            for name, (kind, _) in props.items():
                types.setdefault(name, kind)
        names = sorted(types)
        lines.append(f"{len(names)} properties for each run")
        lines += [f"{n} {types[n]}" for n in names]
        lines.append(f"{len(runs)} runs")
        for props in per_run:
            lines.append("".join(f"{props[n][1] if n in props else ''}; " for n in names))
        lines.append(".")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def _library_version(library: str) -> str:
    try:
        from importlib.metadata import version
        return version("ompl" if library.lower() == "ompl" else "gnn-mp-envs")
    except Exception:
        return "unknown"


def read_ompl_log(path: str | Path) -> dict[str, Any]:
    """Parse a log written by :func:`write_ompl_log` (or OMPL) back into
    ``{"experiment", "planners": {name: {"common", "properties", "runs"}}}``, mirroring
    ``readBenchmarkLog`` of ``ompl_benchmark_statistics.py``; values are floats or None."""
    lines = Path(path).read_text().split("\n")
    pos = 0

    def nxt() -> str:
        nonlocal pos
        pos += 1
        return lines[pos - 1]

    first = nxt()
    if " version " in first and not first.startswith("Experiment "):
        first = nxt()
    if not first.startswith("Experiment "):
        raise ValueError(f"not an OMPL benchmark log: expected 'Experiment', got {first!r}")
    out: dict[str, Any] = {"experiment": first[len("Experiment "):], "planners": {}}
    line = nxt()
    if line.endswith(" experiment properties"):
        for _ in range(int(line.split()[0])):
            nxt()
        line = nxt()
    out["host"] = line.split()[-1]
    out["date"] = " ".join(nxt().split()[2:])
    for _ in range(2):  # setup, then optional cpu info
        if lines[pos].startswith("<<<|"):
            while not nxt().startswith("|>>>"):
                pass
    out["seed"] = int(nxt().split()[0])
    out["time_limit"] = float(nxt().split()[0])
    out["memory_limit"] = float(nxt().split()[0])
    line = nxt()
    if line.endswith("runs per planner"):
        out["run_count"] = int(line.split()[0])
        line = nxt()
    out["total_time"] = float(line.split()[0])
    line = nxt()
    if "enum type" in line:
        out["enums"] = [nxt().split("|") for _ in range(int(line.split()[0]))]
        line = nxt()
    for _ in range(int(line.split()[0])):
        name = nxt()
        common = [nxt() for _ in range(int(nxt().split()[0]))]
        props = []
        for _ in range(int(nxt().split()[0])):
            field = nxt().split()
            props.append(("_".join(field[:-1]), field[-1]))
        runs = []
        for _ in range(int(nxt().split()[0])):
            values = nxt().split("; ")[:-1]
            if len(values) != len(props):
                raise ValueError(f"run of {name!r} has {len(values)} values for {len(props)} properties")
            runs.append({p: (None if v == "" else float(v)) for (p, _), v in zip(props, values)})
        end = nxt()
        if end != ".":
            raise ValueError(f"progress data is not supported by this reader (planner {name!r})")
        out["planners"][name] = {"common": common, "properties": props, "runs": runs}
    return out
