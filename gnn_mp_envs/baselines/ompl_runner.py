"""OMPL baselines (RRTConnect, RRT) on the project's problems, with the project's checkers.

The planner sees exactly the validity checks our planners see: ``problem.check_state`` is
the ``StateValidityChecker`` and a ``MotionValidator`` subclass calls
``problem.check_motion`` (the same interpolation at ``problem.resolution``, the same early
stop and the same counting), so ``collision_checks`` compares like with like. The state
space is a ``RealVectorStateSpace`` over ``problem.low/high`` (L2 distance, as our
geometric tasks), and the planner's range is ``problem.step_size``. The counts include
OMPL's own validity checks of the start and goal states (2 more than our BiRRT, which
roots its trees without checking), and times include the Python callbacks, as in our env.

Why a subprocess: the ``ompl==1.7.0`` wheel crashes at interpreter exit (2.0.1 exits
cleanly), and a crash must not take the caller down. :func:`run_ompl` therefore runs::

    python -m gnn_mp_envs.baselines.ompl_runner --task arm --split test --indices 0-9 \\
        --time-limit 10 --json OUT

which writes its results to ``OUT``, flushes, and leaves with ``os._exit(0)``.

Kinodynamic tasks (the pendulum) need OMPL's control planners; they get their own entry
in :data:`SETUP_BUILDERS` (keyed by ``problem.geometric``) when added. Until then they are
refused with a clear ``ValueError`` before any planning starts.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

#: Planner name -> OMPL geometric planner class name.
GEOMETRIC_PLANNERS = {"rrtconnect": "RRTConnect", "rrt": "RRT"}
INSTALL_HINT = ("OMPL's Python bindings are an optional extra: pip install 'gnn-mp-envs[ompl]' "
                "(i.e. pip install ompl==1.7.0) into the environment running gnn_mp_envs")
#: Exit code of the runner process when ``import ompl`` fails.
EXIT_NO_OMPL = 3


class OMPLUnavailableError(RuntimeError):
    """OMPL's Python bindings cannot be imported; the message says how to install them."""


def ompl_available() -> bool:
    """True when an ``ompl`` package is installed (checked without importing it, since
    importing 1.7.0 makes the interpreter crash at exit)."""
    return importlib.util.find_spec("ompl") is not None


def parse_indices(spec: str | int | list[int] | tuple[int, ...] | range) -> list[int]:
    """Problem indices from ``"0-9"``, ``"0,3,5-7"``, an int or a sequence."""
    if isinstance(spec, (int, np.integer)):
        return [int(spec)]
    if not isinstance(spec, str):
        return [int(i) for i in spec]
    out: list[int] = []
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part:
            a, b = part.split("-", 1)
            lo, hi = int(a), int(b)
            if hi < lo:
                raise ValueError(f"empty index range {part!r}")
            out.extend(range(lo, hi + 1))
        else:
            out.append(int(part))
    if not out or min(out) < 0:
        raise ValueError(f"indices must be non-negative integers, got {spec!r}")
    return out


# ---------------------------------------------------------------------- library side
def run_ompl(task: str, indices: Any, split: str = "test", task_kwargs: dict[str, Any] | None = None,
             planner: str = "rrtconnect", time_limit: float = 10.0, seed: int = 0,
             timeout: float | None = None, python: str | None = None) -> list[dict[str, Any]]:
    """Solve ``make_task(task, **task_kwargs).problem(split, i)`` for each index with OMPL,
    in a subprocess; one result dict per problem (see :func:`solve_problem`).

    Raises :class:`OMPLUnavailableError` when OMPL is not installed, ``ValueError`` for an
    unknown planner or a task OMPL cannot plan yet, ``RuntimeError`` when the runner fails.
    """
    if planner not in GEOMETRIC_PLANNERS:
        raise ValueError(f"unknown OMPL planner {planner!r}; known: {sorted(GEOMETRIC_PLANNERS)}")
    idx = parse_indices(indices)
    if python is None and not ompl_available():
        raise OMPLUnavailableError(f"cannot import ompl. {INSTALL_HINT}")
    if timeout is None:
        timeout = 120.0 + len(idx) * (float(time_limit) + 30.0)
    with tempfile.TemporaryDirectory(prefix="ompl_runner_") as tmp:
        out = Path(tmp) / "results.json"
        cmd = [python or sys.executable, "-m", "gnn_mp_envs.baselines.ompl_runner", "--task", task,
               "--split", split, "--indices", ",".join(map(str, idx)), "--time-limit", repr(float(time_limit)),
               "--planner", planner, "--seed", str(int(seed)), "--json", str(out)]
        if task_kwargs:
            cmd += ["--task-kwargs", json.dumps(task_kwargs)]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        data = json.loads(out.read_text()) if out.exists() else None
        if proc.returncode == EXIT_NO_OMPL or (data or {}).get("error") == "ompl_unavailable":
            msg = (data or {}).get("message", proc.stderr.strip()[-500:])
            raise OMPLUnavailableError(f"cannot import ompl ({msg}). {INSTALL_HINT}")
        if (data or {}).get("error") == "ValueError":
            raise ValueError(data["message"])
        if data is None or "results" not in data:
            detail = (data or {}).get("message") or proc.stderr.strip()[-2000:]
            raise RuntimeError(f"OMPL runner failed (exit code {proc.returncode}): {detail}")
        return data["results"]


# ---------------------------------------------------------------------- runner side
def _geometric_setup(ob: Any, og: Any, problem: Any, planner: str) -> tuple[Any, Any, list]:
    """SimpleSetup over a RealVectorStateSpace with the problem's checker and motion validator."""
    d = problem.state_dim
    space = ob.RealVectorStateSpace(d)
    bounds = ob.RealVectorBounds(d)
    for i in range(d):
        bounds.setLow(i, float(problem.low[i]))
        bounds.setHigh(i, float(problem.high[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    si = ss.getSpaceInformation()

    def as_array(s: Any) -> np.ndarray:
        return np.fromiter((s[i] for i in range(d)), dtype=np.float64, count=d)

    checker = ob.StateValidityCheckerFn(lambda s: problem.check_state(as_array(s)))
    ss.setStateValidityChecker(checker)

    class ProblemMotionValidator(ob.MotionValidator):
        """``problem.check_motion``: same interpolation, early stop and counting as our planners."""

        def checkMotion(self, s1: Any, s2: Any, *last_valid: Any) -> bool:
            return problem.check_motion(as_array(s1), as_array(s2))

    validator = ProblemMotionValidator(si)
    si.setMotionValidator(validator)
    # Only used by OMPL's default validator; kept consistent for anything that reads it.
    si.setStateValidityCheckingResolution(min(1.0, problem.resolution / space.getMaximumExtent()))
    start, goal = ob.State(space), ob.State(space)
    for i in range(d):
        start[i] = float(problem.start[i])
        goal[i] = float(problem.goal[i])
    ss.setStartAndGoalStates(start, goal, max(float(problem.goal_tolerance), 1e-9))
    plan = getattr(og, GEOMETRIC_PLANNERS[planner])(si)
    plan.setRange(float(problem.step_size))
    ss.setPlanner(plan)
    # Keep the Python-side callbacks alive as long as the setup.
    return ss, plan, [checker, validator, as_array, space, start, goal]


#: problem.geometric -> setup builder. Kinodynamic (control-based) setups plug in here.
SETUP_BUILDERS: dict[bool, Callable] = {True: _geometric_setup}


def solve_problem(problem: Any, planner: str = "rrtconnect", time_limit: float = 10.0) -> dict[str, Any]:
    """Plan one problem with OMPL (importing it): solved, collision_checks, edges_checked,
    time (s, wall, of ``solve``), path_length (None when unsolved), path_states, nodes
    (planner graph vertices), status, path_valid (the returned path re-checked, uncounted)."""
    from ompl import base as ob
    from ompl import geometric as og

    builder = SETUP_BUILDERS.get(bool(problem.geometric))
    if builder is None:
        raise ValueError(f"OMPL baselines cover geometric tasks only so far; the {problem.task!r} "
                         "problem is kinodynamic (add a control-based builder to SETUP_BUILDERS)")
    ss, plan, keep = builder(ob, og, problem, planner)
    ss.setup()
    problem.reset_counters()
    t0 = time.perf_counter()
    status = ss.solve(float(time_limit))
    elapsed = time.perf_counter() - t0
    checks, edges = problem.collision_checks, problem.edges_checked
    exact = bool(ss.haveExactSolutionPath())
    data = ob.PlannerData(ss.getSpaceInformation())
    plan.getPlannerData(data)
    result: dict[str, Any] = {
        "planner": f"geometric_{GEOMETRIC_PLANNERS[planner]}",
        "status": str(status.asString()) if hasattr(status, "asString") else str(status),
        "solved": exact,
        "approximate": bool(ss.haveSolutionPath()) and not exact,
        "collision_checks": int(checks),
        "edges_checked": int(edges),
        "time": float(elapsed),
        "plan_time": float(ss.getLastPlanComputationTime()),
        "path_length": None,
        "path_states": 0,
        "nodes": int(data.numVertices()),
        "path_valid": None,
    }
    if exact:
        path = ss.getSolutionPath()
        d = problem.state_dim
        states = np.array([[path.getState(k)[i] for i in range(d)] for k in range(path.getStateCount())])
        result["path_length"] = float(path.length())
        result["path_states"] = int(len(states))
        result["path"] = states.tolist()
        result["path_valid"] = bool(problem.path_valid(states))
        problem.collision_checks, problem.edges_checked = checks, edges
    del keep
    return result


def _write_json(path: str, payload: dict[str, Any]) -> None:
    with open(path, "w") as f:
        json.dump(payload, f)
        f.flush()
        os.fsync(f.fileno())


def main(argv: list[str] | None = None) -> None:
    """Runner process: plan the requested problems, write JSON, then ``os._exit``."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--indices", default="0-9")
    ap.add_argument("--time-limit", type=float, default=10.0)
    ap.add_argument("--planner", default="rrtconnect", choices=sorted(GEOMETRIC_PLANNERS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--task-kwargs", default="{}", help="JSON dict of task constructor arguments")
    ap.add_argument("--json", required=True, help="output file")
    ap.add_argument("--keep-paths", action="store_true", help="keep solution paths in the output")
    args = ap.parse_args(argv)
    try:
        from ompl import util as ou
    except ImportError as e:
        _write_json(args.json, {"error": "ompl_unavailable", "message": str(e)})
        sys.stderr.flush()
        os._exit(EXIT_NO_OMPL)
    code = 0
    try:
        from gnn_mp_envs.envs.tree_env import make_task

        ou.setLogLevel(ou.LOG_WARN)
        ou.RNG.setSeed(int(args.seed) + 1)  # OMPL seeds must be positive
        task = make_task(args.task, **json.loads(args.task_kwargs))
        results = []
        try:
            for i in parse_indices(args.indices):
                r = solve_problem(task.problem(args.split, i), args.planner, args.time_limit)
                r.update(task=args.task, split=args.split, index=i)
                if not args.keep_paths:
                    r.pop("path", None)
                results.append(r)
        finally:
            task.close()
        try:
            from importlib.metadata import version
            ompl_version = version("ompl")
        except Exception:  # pragma: no cover - metadata missing
            ompl_version = "unknown"
        _write_json(args.json, {"ompl_version": ompl_version, "task": args.task, "split": args.split,
                                "planner": args.planner, "time_limit": args.time_limit, "seed": args.seed,
                                "results": results})
    except Exception as e:  # report instead of crashing through OMPL's exit path
        _write_json(args.json, {"error": type(e).__name__, "message": f"{type(e).__name__}: {e}"})
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
