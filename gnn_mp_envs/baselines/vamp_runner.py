"""VAMP's RRTConnect on the MotionBenchMaker problems, with VAMP's own collision checker, in a process of its own.

VAMP (KavrakiLab/vamp, Thomason, Kingston and Kavraki, ICRA 2024; Apache-2.0) plans the Panda, the
UR5 and the Fetch with SIMD collision checks against its own sphere models of the robots. This
module plans our problems (``panda-mbm``, ``ur5-mbm``, ``fetch-mbm``: the same MotionBenchMaker
problems, in the same frames and joint orders as VAMP's copy they were converted from) with it:

* :func:`vamp_primitives` turns a problem's obstacles into VAMP's environment description, as VAMP's
  own MotionBenchMaker evaluation does (``vamp.problem_dict_to_vamp``): a box is a cuboid (half
  extents, Euler XYZ angles), a sphere a sphere, a cylinder a capsule of its radius and length,
  except in the ``box`` scene, where VAMP takes each cylinder as the cuboid of half extents
  (radius, radius, length / 2) around it (a top-down grasp of that cylinder, which the capsule's
  round caps would block). Pure Python: tested without VAMP.
* :func:`run_vamp` plans a list of problems in a subprocess, started with the interpreter
  :func:`vamp_python` names: ``$GNN_MP_VAMP_PYTHON`` when set (e.g. the virtual environment of
  ``build_vamp.sh``), else this interpreter when it imports ``vamp``. The subprocess runs this very
  file as a script (it imports only the standard library, numpy and ``vamp``, never this package),
  so VAMP needs no copy of gnn-mp-envs, and a crash of compiled code never takes the caller down.

The planner is ``vamp.<robot>.rrtc`` with the settings of ``vamp.configure_robot_and_planner_with_kwargs
(robot, "rrtc")`` (VAMP's defaults: range 1.0 rad for the Panda and the Fetch, 1.5 for the UR5;
dynamic domain on, radius 4, alpha 1e-4, min radius 1; balanced trees, tree ratio 1; at most
1,000,000 iterations and samples; the start tree first) and VAMP's default sampler, its Halton
sequence, reset before every problem and advanced by the run's seed (seed 0: VAMP's own evaluation,
``scripts/evaluate_mbm.py``). The path is RRTConnect's own, not simplified. One untimed warm-up
plan of the first problem precedes the timed ones (as the benchmark warms up every sampler).

What a result reports: ``solved``; ``iterations`` (VAMP's); ``time``, VAMP's own planning time
(``PlanningResult.nanoseconds``, measured inside its C++ planner: no Python conversion in it);
``call_time``, the Python call around it; ``nodes`` (both trees' sizes); ``path`` (float64, its
first and last state put back to the problem's exact start and goal, which VAMP holds in float32);
``path_length`` (joint-space L2 of that path); ``start_goal_valid`` (VAMP's own check of start and
goal; VAMP's evaluation plans no problem its spheres call invalid, and neither does this runner).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

#: Task -> VAMP's robot module (``vamp.panda``, ...): the tasks whose problems VAMP can plan.
VAMP_ROBOTS = {"panda-mbm": "panda", "ur5-mbm": "ur5", "fetch-mbm": "fetch"}
#: Planner name -> VAMP's planner function and its settings' name for
#: ``vamp.configure_robot_and_planner_with_kwargs``.
VAMP_PLANNERS = {"rrtconnect": "rrtc"}
#: Environment variable naming an interpreter that imports ``vamp`` (else this interpreter's).
PYTHON_ENV = "GNN_MP_VAMP_PYTHON"
INSTALL_HINT = ("VAMP is not importable: build it from source (docs/mbm.md, \"VAMP's row\") and pip install its wheel "
                f"into this environment (the optional extra 'vamp'), or set {PYTHON_ENV} to an interpreter that "
                "imports vamp")
#: Exit code of the runner process when ``import vamp`` fails.
EXIT_NO_VAMP = 3
#: The line prefix of the runner's per-problem report on its standard error.
PROGRESS_MARK = "vamp-runner: planned "
#: How far VAMP's float32 start and goal may lie from the problem's (per joint) and still be put back.
ENDPOINT_TOLERANCE = 1e-5
#: Result fields that must be numbers (or None) in what the runner returns.
RESULT_NUMBERS = ("iterations", "time", "call_time", "nodes", "path_length")


class VAMPUnavailableError(RuntimeError):
    """No interpreter that imports ``vamp``; the message says how to get one."""


def vamp_available() -> bool:
    """Whether :func:`vamp_python` names an interpreter (``$GNN_MP_VAMP_PYTHON``, or this one with
    ``vamp`` installed); the runner itself tells whether that interpreter really imports ``vamp``."""
    return vamp_python() is not None


def vamp_python() -> str | None:
    """The interpreter that runs VAMP: ``$GNN_MP_VAMP_PYTHON`` when set, else this interpreter when
    ``vamp`` is installed here (found without importing it), else None."""
    named = os.environ.get(PYTHON_ENV, "").strip()
    if named:
        return named
    import importlib.util
    return sys.executable if importlib.util.find_spec("vamp") is not None else None


# ---------------------------------------------------------------------- our problems -> VAMP's description
def quaternion_matrix(q: Sequence[float]) -> list[list[float]]:
    """The rotation matrix of the quaternion ``q`` = (x, y, z, w) (normalised first)."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        raise ValueError(f"a zero quaternion {list(q)}")
    x, y, z, w = x / n, y / n, z / n, w / n
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def euler_xyz(q: Sequence[float]) -> list[float]:
    """VAMP's "Euler XYZ" angles ``[rx, ry, rz]`` of the quaternion ``q`` = (x, y, z, w): the rotation is
    ``Rz(rz) @ Ry(ry) @ Rx(rx)`` (static axes x, then y, then z), as VAMP's factories build it from
    the angles and as its problem loader computes them (``euler_from_matrix``, axes ``sxyz``)."""
    m = quaternion_matrix(q)
    cy = math.hypot(m[0][0], m[1][0])
    if cy > 1e-12:
        return [math.atan2(m[2][1], m[2][2]), math.atan2(-m[2][0], cy), math.atan2(m[1][0], m[0][0])]
    return [math.atan2(-m[1][2], m[1][1]), math.atan2(-m[2][0], cy), 0.0]   # gimbal lock: rz = 0


def euler_matrix(angles: Sequence[float]) -> list[list[float]]:
    """``Rz(rz) @ Ry(ry) @ Rx(rx)`` of ``angles`` = [rx, ry, rz] (the inverse of :func:`euler_xyz`)."""
    rx, ry, rz = (float(a) for a in angles)
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    return [[cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
            [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
            [-sy, cy * sx, cy * cx]]


def vamp_primitives(obstacles: Sequence[Any], scene: str | None = None) -> list[dict[str, Any]]:
    """VAMP's environment description of ``obstacles`` (:class:`gnn_mp_envs.robots.geometry.Obstacle`:
    ``kind``, ``size``, ``position``, ``quaternion()``), one dict per obstacle, in their order:

    * a box: ``{"shape": "cuboid", "center", "euler_xyz", "half_extents"}`` (our size is half extents);
    * a sphere: ``{"shape": "sphere", "center", "radius"}``;
    * a cylinder (our size: radius, height; its axis the local z): ``{"shape": "capsule", "center",
      "euler_xyz", "radius", "length"}``, but in the ``box`` scene (``scene == "box"``) the cuboid
      ``half_extents`` (radius, radius, height / 2) around it, as VAMP's loader takes it there.
    """
    out = []
    for ob in obstacles:
        center = [float(v) for v in ob.position]
        size = [float(v) for v in ob.size]
        if ob.kind == "sphere":
            out.append({"shape": "sphere", "center": center, "radius": size[0]})
            continue
        angles = euler_xyz(ob.quaternion())
        if ob.kind == "box":
            out.append({"shape": "cuboid", "center": center, "euler_xyz": angles, "half_extents": size})
        elif ob.kind == "cylinder":
            radius, height = size
            if scene == "box":
                out.append({"shape": "cuboid", "center": center, "euler_xyz": angles,
                            "half_extents": [radius, radius, height / 2]})
            else:
                out.append({"shape": "capsule", "center": center, "euler_xyz": angles, "radius": radius,
                            "length": height})
        else:
            raise ValueError(f"VAMP has no primitive for an obstacle of kind {ob.kind!r}")
    return out


def vamp_job(problem: Any, robot: str) -> dict[str, Any]:
    """What the runner plans for ``problem`` (a MotionBenchMaker problem: ``start``, ``goal``,
    ``obstacles``, ``family``, the scene) with VAMP's ``robot``: JSON-ready."""
    return {"robot": robot, "start": [float(v) for v in problem.start], "goal": [float(v) for v in problem.goal],
            "primitives": vamp_primitives(problem.obstacles, getattr(problem, "family", None))}


# ---------------------------------------------------------------------- library side
def checked_results(data: Any, count: int) -> list[dict[str, Any]]:
    """The runner's ``results`` if they are ``count`` dicts with a boolean ``solved`` and numbers (or
    None) in :data:`RESULT_NUMBERS`; else a one-line ``RuntimeError`` saying what came back."""
    results = data.get("results") if isinstance(data, dict) else None
    if not isinstance(results, list) or len(results) != count:
        got = (f"{len(results)} results" if isinstance(results, list) else
               f"'results' of type {type(results).__name__}" if isinstance(data, dict) else type(data).__name__)
        raise RuntimeError(f"the VAMP runner returned {got}, expected a list of {count} results")
    for i, r in enumerate(results):
        bad = (not isinstance(r, dict) or not isinstance(r.get("solved"), bool)
               or any(r.get(k) is not None and (isinstance(r[k], bool) or not isinstance(r[k], (int, float)))
                      for k in RESULT_NUMBERS)
               or (r.get("solved") and not isinstance(r.get("path"), list)))
        if bad:
            raise RuntimeError(f"the VAMP runner returned a malformed result {i} ({str(r)[:120]}): expected a dict "
                               f"with a boolean 'solved', numbers in {', '.join(RESULT_NUMBERS)} and a solved "
                               "run's 'path'")
    return results


def exact_endpoints(path: np.ndarray, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """``path`` (float64) with its first and last state replaced by ``start`` and ``goal`` where they
    are those states in VAMP's float32 (within :data:`ENDPOINT_TOLERANCE` per joint); a path that
    starts or ends elsewhere is returned as it is (and fails the re-check)."""
    path = np.array(path, dtype=np.float64)
    for row, exact in ((0, start), (-1, goal)):
        exact = np.asarray(exact, dtype=np.float64)
        if len(path) and path[row].shape == exact.shape and np.all(np.abs(path[row] - exact) <= ENDPOINT_TOLERANCE):
            path[row] = exact
    return path


def run_vamp(problems: Sequence[Any], robot: str, planner: str = "rrtconnect", seed: int = 0,
             python: str | None = None, timeout: float | None = None,
             on_problem: Callable[[int], None] | None = None) -> list[dict[str, Any]]:
    """Plan each of ``problems`` (see :func:`vamp_job`) with VAMP's ``planner`` for its ``robot`` in a
    subprocess (interpreter: ``python``, else :func:`vamp_python`); one result per problem (module
    docstring), ``path`` as a float64 array (None when not solved). ``on_problem(k)`` is called as the
    ``k``-th problem finishes. Raises :class:`VAMPUnavailableError` when no interpreter imports
    ``vamp``, ``ValueError`` for an unknown robot or planner, ``RuntimeError`` when the runner fails,
    ``subprocess.TimeoutExpired`` past ``timeout`` (default: 120 s plus 60 s a problem)."""
    if planner not in VAMP_PLANNERS:
        raise ValueError(f"unknown VAMP planner {planner!r}; known: {', '.join(VAMP_PLANNERS)}")
    if robot not in VAMP_ROBOTS.values():
        raise ValueError(f"VAMP has no robot {robot!r} here; known: {', '.join(VAMP_ROBOTS.values())}")
    python = python or vamp_python()
    if python is None:
        raise VAMPUnavailableError(INSTALL_HINT)
    jobs = [vamp_job(p, robot) for p in problems]
    if not jobs:
        return []
    if timeout is None:
        timeout = 120.0 + 60.0 * len(jobs)
    with tempfile.TemporaryDirectory(prefix="vamp_runner_") as tmp:
        src, out = Path(tmp) / "jobs.json", Path(tmp) / "results.json"
        src.write_text(json.dumps({"planner": planner, "seed": int(seed), "jobs": jobs}))
        cmd = [python, str(Path(__file__).resolve()), "--jobs", str(src), "--json", str(out)]
        try:
            proc = _run_reporting(cmd, timeout, on_problem, cwd=tmp)
        except OSError as exc:          # a GNN_MP_VAMP_PYTHON that is no program
            raise VAMPUnavailableError(f"cannot start {python!r} ({exc.strerror or exc}). {INSTALL_HINT}") from None
        try:
            data = json.loads(out.read_text()) if out.exists() else None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise RuntimeError(f"the VAMP runner wrote unreadable JSON ({exc})") from None
        if proc.returncode == EXIT_NO_VAMP or (isinstance(data, dict) and data.get("error") == "vamp_unavailable"):
            msg = data.get("message") if isinstance(data, dict) else proc.stderr.strip()[-300:]
            raise VAMPUnavailableError(f"{python} cannot import vamp ({msg}). {INSTALL_HINT}")
        if not isinstance(data, dict) or "results" not in data:
            detail = (data.get("message") if isinstance(data, dict) else None) or proc.stderr.strip()[-2000:]
            raise RuntimeError(f"VAMP runner failed (exit code {proc.returncode}): {detail}")
        results = checked_results(data, len(jobs))
    for problem, r in zip(problems, results):
        r["vamp_version"] = data.get("vamp_version")
        r["path"] = exact_endpoints(r["path"], problem.start, problem.goal) if r["solved"] else None
        if r["path"] is not None:
            r["path_length"] = float(np.linalg.norm(np.diff(r["path"], axis=0), axis=1).sum())
    return results


def _run_reporting(cmd: list[str], timeout: float, on_problem: Callable[[int], None] | None,
                   cwd: str | None = None) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)`` in its own process
    group, calling ``on_problem`` for each progress line the runner writes on its standard error."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd,
                            start_new_session=True)
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
            proc.wait()
    if expired.is_set():
        raise subprocess.TimeoutExpired(cmd, timeout)
    return subprocess.CompletedProcess(cmd, proc.returncode, "".join(stdout), "".join(stderr))


# ---------------------------------------------------------------------- runner side (VAMP's interpreter)
def build_environment(vamp: Any, primitives: list[dict[str, Any]]) -> Any:
    """A ``vamp.Environment`` of :func:`vamp_primitives`' description (``add_cuboid``, ``add_capsule``,
    ``add_sphere``, as VAMP's loader does)."""
    env = vamp.Environment()
    for p in primitives:
        if p["shape"] == "cuboid":
            env.add_cuboid(vamp.Cuboid(p["center"], p["euler_xyz"], p["half_extents"]))
        elif p["shape"] == "capsule":
            env.add_capsule(vamp.Cylinder(p["center"], p["euler_xyz"], p["radius"], p["length"]))
        elif p["shape"] == "sphere":
            env.add_sphere(vamp.Sphere(p["center"], p["radius"]))
        else:
            raise ValueError(f"unknown primitive {p['shape']!r}")
    return env


def plan_jobs(vamp: Any, planner: str, seed: int, jobs: list[dict[str, Any]],
              on_done: Callable[[int], None] = lambda k: None) -> list[dict[str, Any]]:
    """Plan every job with VAMP (module docstring); one warm-up plan of the first job first."""
    results, configured, warm = [], {}, False
    for k, job in enumerate(jobs):
        robot = job["robot"]
        if robot not in configured:
            module, plan, settings, _ = vamp.configure_robot_and_planner_with_kwargs(robot, VAMP_PLANNERS[planner])
            configured[robot] = (module, plan, settings, module.halton())
        module, plan, settings, sampler = configured[robot]
        if len(job["start"]) != module.dimension():
            raise ValueError(f"a {robot} problem of {len(job['start'])} joints; VAMP's {robot} has "
                             f"{module.dimension()}")
        env = build_environment(vamp, job["primitives"])
        start, goal = np.asarray(job["start"], dtype=np.float32), np.asarray(job["goal"], dtype=np.float32)
        valid = bool(module.validate(start, env)) and bool(module.validate(goal, env))
        result: dict[str, Any] = {"solved": False, "start_goal_valid": valid, "iterations": None, "time": None,
                                  "call_time": None, "nodes": None, "path_length": None, "path": None}
        if valid:
            if not warm:      # warm-up, untimed: first-call costs stay out of the timed runs
                plan(start, goal, env, settings, sampler)
                warm = True
            sampler.reset()
            sampler.skip(int(seed))
            t0 = time.perf_counter()
            planned = plan(start, goal, env, settings, sampler)
            call = time.perf_counter() - t0
            solved = bool(planned.solved)
            result.update(solved=solved, iterations=int(planned.iterations), time=planned.nanoseconds * 1e-9,
                          call_time=call, nodes=int(sum(planned.size)))
            if solved:
                path = np.asarray(planned.path.numpy(), dtype=np.float64)
                result["path"] = path.tolist()
                result["path_length"] = float(planned.path.cost())
        results.append(result)
        on_done(k)
    return results


def _write_json(path: str, payload: dict[str, Any]) -> None:
    with open(path, "w") as f:
        json.dump(payload, f)
        f.flush()
        os.fsync(f.fileno())


def main(argv: list[str] | None = None) -> int:
    """Runner process: read the jobs, plan them with VAMP, write the results as JSON."""
    ap = argparse.ArgumentParser(description="Plan MotionBenchMaker problems with VAMP (gnn-mp-envs' VAMP runner).")
    ap.add_argument("--jobs", required=True, help="input JSON: {planner, seed, jobs: [{robot, start, goal, primitives}]}")
    ap.add_argument("--json", required=True, help="output file")
    args = ap.parse_args(argv)
    try:
        import vamp
    except ImportError as exc:
        _write_json(args.json, {"error": "vamp_unavailable", "message": str(exc)})
        return EXIT_NO_VAMP
    try:
        spec = json.loads(Path(args.jobs).read_text())
        if spec["planner"] not in VAMP_PLANNERS:
            raise ValueError(f"unknown VAMP planner {spec['planner']!r}")
        results = plan_jobs(vamp, spec["planner"], int(spec["seed"]), spec["jobs"],
                            lambda k: print(f"{PROGRESS_MARK}{k}", file=sys.stderr, flush=True))
        try:
            from importlib.metadata import version
            vamp_version = version("vamp-planner")
        except Exception:  # pragma: no cover - metadata missing
            vamp_version = "unknown"
        _write_json(args.json, {"vamp_version": vamp_version, "planner": spec["planner"], "seed": spec["seed"],
                                "results": results})
    except Exception as exc:   # reported, not a traceback in the caller
        _write_json(args.json, {"error": type(exc).__name__, "message": f"{type(exc).__name__}: {exc}"})
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
