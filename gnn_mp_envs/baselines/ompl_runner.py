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

which writes its results to ``OUT``, flushes, and leaves with ``os._exit(0)``. Tasks registered
outside the package plan too: the runner imports ``--import MODULE`` first (the benchmark passes
its ``--import`` modules) and, if the task is still unknown, the module of the task's entry point
(``--task-module``, :func:`task_module`), so the task's ``register_task`` call runs in the
subprocess as well. What the runner returns is checked (:func:`checked_results`) before anyone
reads it.

Kinodynamic tasks use OMPL's control planners (``oc.RRT`` as ``"rrt"``, ``oc.KPIECE1`` as
``"kpiece"``) through :data:`SETUP_BUILDERS` (keyed by ``problem.geometric``) and a per-task
builder named by its task's ``TaskSpec.ompl_control_setup``, kept next to the task (the pendulum's:
:func:`gnn_mp_envs.tasks.pendulum.ompl_setup.pendulum_setup`) and imported only here, in the runner: the state
space, a propagator integrating the task's own dynamics, ``problem.check_state`` as the
validity checker (counted) and a goal satisfied exactly when ``problem.in_goal`` holds.
A planner that does not fit the problem (``rrtconnect`` on the pendulum, ``kpiece`` on a
geometric task) is refused with a ``ValueError`` before any planning starts. Details and
the settings that make edges comparable to ours: ``docs/ompl.md``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from gnn_mp_envs.core.problem import PATH_CHECK_REFINE, verdict

#: Planner name -> OMPL geometric planner class name.
GEOMETRIC_PLANNERS = {"rrtconnect": "RRTConnect", "rrt": "RRT"}
#: Planner name -> OMPL control (kinodynamic) planner class name.
CONTROL_PLANNERS = {"rrt": "RRT", "kpiece": "KPIECE1"}
#: Every planner name the runner accepts (which ones fit depends on ``problem.geometric``).
PLANNERS = sorted(set(GEOMETRIC_PLANNERS) | set(CONTROL_PLANNERS))
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
def task_module(task: str) -> str | None:
    """The module of ``task``'s entry point when it lies outside this package: importing it in the
    runner most likely registers the task there too (tried when ``--import`` did not)."""
    from gnn_mp_envs.registration import TASK_SPECS
    spec = TASK_SPECS.get(task)
    if spec is None:
        return None
    entry = spec.entry_point
    module = entry.split(":")[0] if isinstance(entry, str) else getattr(entry, "__module__", None)
    if not module or module == "__main__" or module.split(".")[0] == "gnn_mp_envs":
        return None
    return module


#: Result fields that must be numbers (or None) in what the runner returns.
RESULT_NUMBERS = ("nodes", "edges_checked", "collision_checks", "path_length", "time")


def checked_results(data: Any, count: int) -> list[dict[str, Any]]:
    """The runner's ``results``, if they are ``count`` dicts with a boolean ``solved`` and numbers
    (or None) in :data:`RESULT_NUMBERS`; else a one-line ``RuntimeError`` saying what came back
    (another runner, ``python=``, or a damaged file: never a traceback deep in the benchmark)."""
    results = data.get("results") if isinstance(data, dict) else None
    if not isinstance(results, list) or len(results) != count:
        got = (f"{len(results)} results" if isinstance(results, list) else
               f"'results' of type {type(results).__name__}" if isinstance(data, dict) else type(data).__name__)
        raise RuntimeError(f"the OMPL runner returned {got}, expected a list of {count} results")
    for i, r in enumerate(results):
        bad = (not isinstance(r, dict) or not isinstance(r.get("solved"), bool)
               or any(r.get(k) is not None and (isinstance(r[k], bool) or not isinstance(r[k], (int, float)))
                      for k in RESULT_NUMBERS))
        if bad:
            raise RuntimeError(f"the OMPL runner returned a malformed result {i} ({str(r)[:120]}): expected a dict "
                               f"with a boolean 'solved' and numbers in {', '.join(RESULT_NUMBERS)}")
    return results


def run_ompl(task: str, indices: Any, split: str = "test", task_kwargs: dict[str, Any] | None = None,
             planner: str = "rrtconnect", time_limit: float = 10.0, seed: int = 0,
             timeout: float | None = None, python: str | None = None,
             keep_paths: bool = False, on_problem: Callable[[int], None] | None = None,
             modules: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Solve ``make_task(task, **task_kwargs).problem(split, i)`` for each index with OMPL,
    in a subprocess; one result dict per problem (see :func:`solve_problem`). Solution
    paths (``path``; for control planners also ``controls`` and ``durations``) are kept
    only with ``keep_paths``. ``on_problem(index)`` is called as each problem finishes (a
    progress bar: the runner reports on its standard error). ``modules`` are imported by
    the runner first (they register the task; else the runner tries :func:`task_module`).

    Raises :class:`OMPLUnavailableError` when OMPL is not installed, ``ValueError`` for an
    unknown planner, a planner that does not fit the task (geometric vs. kinodynamic) or a
    task OMPL cannot plan yet, ``RuntimeError`` when the runner fails.
    """
    if planner not in PLANNERS:
        raise ValueError(f"unknown OMPL planner {planner!r}; known: {PLANNERS} (geometric tasks: "
                         f"{sorted(GEOMETRIC_PLANNERS)}, kinodynamic tasks: {sorted(CONTROL_PLANNERS)})")
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
        for module in modules:
            cmd += ["--import", module]
        for name, file in _module_files(modules):
            cmd += ["--import-file", f"{name}={file}"]
        if task_module(task) is not None:
            cmd += ["--task-module", task_module(task)]
        if keep_paths:
            cmd.append("--keep-paths")
        proc = _run_reporting(cmd, timeout, on_problem, env=_runner_environment())
        try:
            data = json.loads(out.read_text()) if out.exists() else None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise RuntimeError(f"the OMPL runner wrote unreadable JSON ({exc})") from None
        if proc.returncode == EXIT_NO_OMPL or (isinstance(data, dict) and data.get("error") == "ompl_unavailable"):
            stderr = proc.stderr.strip()[-500:]
            msg = data.get("message", stderr) if isinstance(data, dict) else stderr
            raise OMPLUnavailableError(f"cannot import ompl ({msg}). {INSTALL_HINT}")
        if isinstance(data, dict) and data.get("error") == "ValueError":
            raise ValueError(str(data.get("message")))
        if not isinstance(data, dict) or "results" not in data:
            detail = (data.get("message") if isinstance(data, dict) else None) or proc.stderr.strip()[-2000:]
            raise RuntimeError(f"OMPL runner failed (exit code {proc.returncode}): {detail}")
        return checked_results(data, len(idx))


#: The line prefix of the runner's per-problem report on its standard error.
PROGRESS_MARK = "ompl-runner: solved "


def _runner_environment() -> dict[str, str]:
    """The runner's environment: its import path is this process's. ``PYTHONSAFEPATH``: ``-m`` does not
    put the current directory first on it (a ``numpy.py`` or ``train.py`` there would be imported in
    place of the module of that name); ``PYTHONPATH``: the directories this process imports from that
    are not the interpreter's own (a test's root, the user's ``PYTHONPATH``). A module ``--import``
    loaded from the current directory is passed as its file (``--import-file``)."""
    own = tuple(p for p in {sys.prefix, sys.base_prefix, sys.exec_prefix} if p)
    extra = [p for p in sys.path if p and os.path.isabs(p) and not p.startswith(own)]
    return {**os.environ, "PYTHONSAFEPATH": "1", "PYTHONPATH": os.pathsep.join(dict.fromkeys(extra))}


def _module_files(modules: Sequence[str]) -> list[tuple[str, str]]:
    """``(name, file)`` of each of ``modules``' top-level modules this process loaded from a file: the
    runner loads one from that file when a plain import does not find it (``gnn-mp --import`` loads a
    module of the current directory by its file, without the directory on ``sys.path``)."""
    out = []
    for top in dict.fromkeys(m.split(".")[0] for m in modules):
        file = getattr(sys.modules.get(top), "__file__", None)
        if file:
            out.append((top, file))
    return out


def _load_files(entries: Sequence[str]) -> None:
    """The runner's ``--import-file NAME=FILE``: load the top-level module ``NAME`` from ``FILE`` (a
    package's ``__init__.py``: its submodules import through its ``__path__``) unless it is installed."""
    import importlib.util
    for entry in entries:
        name, _, file = entry.partition("=")
        if name in sys.modules or importlib.util.find_spec(name) is not None:
            continue
        path = Path(file)
        package = path.name == "__init__.py"
        spec = importlib.util.spec_from_file_location(
            name, path, submodule_search_locations=[str(path.parent)] if package else None)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[name]
            raise


def _run_reporting(cmd: list[str], timeout: float, on_problem: Callable[[int], None] | None,
                   env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)``, calling
    ``on_problem`` for each progress line the runner writes on its standard error."""
    import threading
    # its own process group, so that a timeout ends the runner's children too
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env=env)
    expired = threading.Event()

    def kill() -> None:
        expired.set()
        try:
            os.killpg(proc.pid, 9)
        except ProcessLookupError:
            pass
    timer = threading.Timer(timeout, kill)
    stdout: list[str] = []
    drain = threading.Thread(target=lambda: stdout.append(proc.stdout.read()), daemon=True)
    timer.start()
    drain.start()
    stderr = []
    try:
        for line in proc.stderr:
            if line.startswith(PROGRESS_MARK):
                if on_problem is not None:
                    on_problem(int(line[len(PROGRESS_MARK):]))
            else:
                stderr.append(line)
        proc.wait()
        drain.join()
    finally:
        timer.cancel()
        if proc.poll() is None:
            kill()
            expired.clear()
            proc.wait()
    if expired.is_set():
        raise subprocess.TimeoutExpired(cmd, timeout)
    return subprocess.CompletedProcess(cmd, proc.returncode, "".join(stdout), "".join(stderr))


# ---------------------------------------------------------------------- runner side
@dataclass
class OMPLSetup:
    """What a builder hands :func:`solve_problem`: the configured ``SimpleSetup`` and planner,
    how to read a solution path, and anything the callbacks need kept alive. A kinodynamic task's
    ``TaskSpec.ompl_control_setup`` (``function(problem, planner)``) returns one."""

    ss: Any
    planner: Any
    name: str                                   # e.g. "geometric_RRTConnect", "control_KPIECE1"
    path_result: Callable[[Any], dict[str, Any]]  # solution path -> path fields of the result
    counters: Callable[[], dict[str, int]]      # edges_checked (and more) since reset_counters
    reset_counters: Callable[[], None]          # called with problem.reset_counters() before solve
    keep: list = field(default_factory=list)


def _geometric_setup(problem: Any, planner: str) -> OMPLSetup:
    """SimpleSetup over a RealVectorStateSpace with the problem's checker and motion validator."""
    from ompl import base as ob
    from ompl import geometric as og

    if planner not in GEOMETRIC_PLANNERS:
        raise ValueError(f"OMPL planner {planner!r} is a control (kinodynamic) planner; the {problem.task!r} "
                         f"problem is geometric (geometric planners: {sorted(GEOMETRIC_PLANNERS)})")
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
    # Planner iterations, as our planners count them: RRTConnect and RRT draw one uniform sample per
    # iteration, so a sampler that counts its draws (and draws exactly what OMPL's own would) counts them.
    samples = {"n": 0}

    class CountingSampler(ob.RealVectorStateSampler):
        def sampleUniform(self, state: Any) -> None:
            samples["n"] += 1
            super().sampleUniform(state)

    allocator = ob.StateSamplerAllocator(lambda s: CountingSampler(s))
    space.setStateSamplerAllocator(allocator)
    start, goal = ob.State(space), ob.State(space)
    for i in range(d):
        start[i] = float(problem.start[i])
        goal[i] = float(problem.goal[i])
    ss.setStartAndGoalStates(start, goal, max(float(problem.goal_tolerance), 1e-9))
    plan = getattr(og, GEOMETRIC_PLANNERS[planner])(si)
    plan.setRange(float(problem.step_size))
    ss.setPlanner(plan)

    def path_result(path: Any) -> dict[str, Any]:
        states = np.array([as_array(path.getState(k)) for k in range(path.getStateCount())])
        return {"path_length": float(path.length()), "path": states.tolist(), "path_states": int(len(states)),
                "goal_reached": bool(problem.in_goal(states[-1])),
                "path_valid": verdict(problem.path_valid(states)),
                "path_valid_fine": verdict(problem.path_valid(states, refine=PATH_CHECK_REFINE))}

    return OMPLSetup(ss, plan, f"geometric_{GEOMETRIC_PLANNERS[planner]}", path_result,
                  lambda: {"edges_checked": int(problem.edges_checked), "iterations": samples["n"]},
                  lambda: samples.update(n=0),
                  # Keep the Python-side callbacks alive as long as the setup.
                  [checker, validator, as_array, space, start, goal, allocator, CountingSampler])


def _control_setup(problem: Any, planner: str) -> OMPLSetup:
    """The control-based setup its task's ``TaskSpec.ompl_control_setup`` names."""
    from gnn_mp_envs.registration import task_spec
    target = task_spec(problem.task).ompl_control_setup
    if target is None:
        raise ValueError(f"no control-based OMPL setup for the kinodynamic {problem.task!r} problem "
                         "(set TaskSpec.ompl_control_setup to 'module:function')")
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)(problem, planner)


#: problem.geometric -> setup builder.
SETUP_BUILDERS: dict[bool, Callable[[Any, str], OMPLSetup]] = {True: _geometric_setup, False: _control_setup}


def solve_problem(problem: Any, planner: str = "rrtconnect", time_limit: float = 10.0) -> dict[str, Any]:
    """Plan one problem with OMPL (importing it). The result holds: planner, status, solved
    (an exact solution whose final state satisfies ``problem.in_goal``; approximate
    solutions count as unsolved), approximate, collision_checks, edges_checked, time (s,
    wall, of ``solve``), plan_time, path_length (None when unsolved; for control planners
    the path's duration in seconds), path_states, nodes (planner graph vertices),
    goal_reached and path_valid (the returned path re-checked, uncounted; None when
    unsolved), for geometric planners iterations (uniform samples drawn: one per iteration) and path_valid_fine (the same at ``PATH_CHECK_REFINE`` times
    the resolution, by the uncounted ``is_state_valid``), and for control planners propagation_steps (integration steps of
    ``EDGE_DURATION / INTEGRATION_STEPS`` each)."""
    from ompl import base as ob

    setup = SETUP_BUILDERS[bool(problem.geometric)](problem, planner)
    ss, plan = setup.ss, setup.planner
    # the problem's checks once before the clock: a process's first check may build its checker or compile it
    # (numba, where its cache is stale: tens of seconds), which is not planning (uncounted: reset below)
    problem.is_state_valid(np.asarray(problem.start, dtype=np.float64)[None])
    if problem.geometric:
        problem.check_motion(problem.start, problem.goal)
    ss.setup()
    problem.reset_counters()
    setup.reset_counters()
    t0 = time.perf_counter()
    status = ss.solve(float(time_limit))
    elapsed = time.perf_counter() - t0
    checks, counts = problem.collision_checks, setup.counters()
    edges = counts.pop("edges_checked")
    exact = bool(ss.haveExactSolutionPath())
    data = ob.PlannerData(ss.getSpaceInformation())
    plan.getPlannerData(data)
    result: dict[str, Any] = {
        "planner": setup.name,
        "status": str(status.asString()) if hasattr(status, "asString") else str(status),
        "solved": False,
        "approximate": bool(ss.haveSolutionPath()) and not exact,
        "collision_checks": int(checks),
        "edges_checked": edges,
        "time": float(elapsed),
        "plan_time": float(ss.getLastPlanComputationTime()),
        "path_length": None,
        "path_states": 0,
        "nodes": int(data.numVertices()),
        "goal_reached": None,
        "path_valid": None,
    }
    result.update(counts)
    if exact:
        result.update(setup.path_result(ss.getSolutionPath()))
        result["solved"] = bool(result["goal_reached"])
        if not result["solved"]:   # OMPL called it exact, our goal test disagrees: report honestly
            result["path_length"] = None
        problem.collision_checks, problem.edges_checked = checks, edges
    del setup
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
    ap.add_argument("--planner", default="rrtconnect", choices=PLANNERS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--task-kwargs", default="{}", help="JSON dict of task constructor arguments")
    ap.add_argument("--import", dest="modules", action="append", default=[], metavar="MODULE",
                    help="import MODULE first (it registers the task; repeatable)")
    ap.add_argument("--import-file", dest="import_files", action="append", default=[], metavar="NAME=FILE",
                    help="load the top-level module NAME from FILE first, unless it is installed (what the caller "
                         "loaded from its current directory; repeatable)")
    ap.add_argument("--task-module", default=None, metavar="MODULE",
                    help="import MODULE if the task is still unknown (the module of its entry point)")
    ap.add_argument("--json", required=True, help="output file")
    ap.add_argument("--keep-paths", action="store_true",
                    help="keep solution paths (and controls, durations) in the output")
    args = ap.parse_args(argv)
    try:
        from ompl import util as ou
    except ImportError as e:
        _write_json(args.json, {"error": "ompl_unavailable", "message": str(e)})
        sys.stderr.flush()
        os._exit(EXIT_NO_OMPL)
    code = 0
    try:
        from gnn_mp_envs.registration import TASK_SPECS, make_task

        _load_files(args.import_files)
        for module in args.modules:
            importlib.import_module(module)
        if args.task not in TASK_SPECS and args.task_module:
            try:
                importlib.import_module(args.task_module)
            except ImportError as exc:
                raise ValueError(f"task {args.task!r} is not registered in the OMPL runner's process and its module "
                                 f"{args.task_module!r} cannot be imported there ({exc}); pass the module that "
                                 "registers it with --import") from None
        ou.setLogLevel(ou.LOG_WARN)
        ou.RNG.setSeed(int(args.seed) + 1)  # OMPL seeds must be positive
        task = make_task(args.task, **json.loads(args.task_kwargs))
        results = []
        try:
            for i in parse_indices(args.indices):
                problem = task.problem(args.split, i)
                r = solve_problem(problem, args.planner, args.time_limit)
                r.update(task=args.task, split=args.split, index=i, family=getattr(problem, "family", None))
                if not args.keep_paths:
                    for key in ("path", "controls", "durations"):
                        r.pop(key, None)
                results.append(r)
                print(f"{PROGRESS_MARK}{i}", file=sys.stderr, flush=True)
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
