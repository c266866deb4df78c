"""Arm benchmark with pybullet's checker: checker speed, env overhead, and uniform BiRRT vs OMPL RRTConnect.

Run: ``.venv/bin/python -m tools.bench_arm`` from the repository root (``--help`` for options). It reports

1. raw collision checks per second of the checker alone (``RobotWorld.collides`` on
   uniformly drawn configurations in held-out scenes);
2. ``env.step`` calls per second of ``GNNMP/ArmBiRRT-v0`` driven by uniform samples, and
   the fraction of step time that is environment overhead, i.e. not spent inside the
   collision checks the step makes (measured by timing every ``collides`` call);
3. the uniform sampler's BiRRT on the first ``--problems`` held-out problems of the ``test``
   scene family (split ``test``) within ``--max-nodes`` nodes, planned by
   :func:`gnn_mp_envs.evaluation.plan_problem` (the benchmark's seeding rule): solve rate,
   median collision checks, median planning time (sum of step times), median nodes;
4. the same for OMPL's RRTConnect on the same problems with the same checker, via
   :func:`gnn_mp_envs.baselines.ompl_runner.run_ompl` (skipped when OMPL is missing).

``--json`` saves every number and per-problem record; ``--ompl-log`` writes both
planners' runs as an OMPL benchmark log for ``ompl_benchmark_statistics.py``/Planner Arena.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from agents.registry import load_sampler
from gnn_mp_envs.evaluation import evaluation_env, plan_problem
from gnn_mp_envs.registration import task_spec
from gnn_mp_envs.rollout import run_steps
from gnn_mp_envs.tasks.arm import ArmTask
from gnn_mp_envs.utils.io import atomic_write_text
from train.args import (OneLineParser, add_dataclass_arguments, arg, from_namespace, positive_float, positive_int,
                        seed_int)

ENV_ID = task_spec("arm").env_id
#: The checker measured: pybullet's (the arm's default is the sphere model; ``gnn-mp benchmark --task arm
#: --checker pybullet`` plans as this tool does).
CHECKER = "pybullet"


def raw_checks_per_second(scene: str, num_checks: int, num_scenes: int = 5, seed: int = 0) -> dict[str, float]:
    """Checks/s of ``RobotWorld.collides`` alone on uniform configurations in ``num_scenes`` scenes."""
    task = ArmTask(scene, checker=CHECKER)
    try:
        low, high = task.state_bounds()
        rng = np.random.default_rng(seed)
        total, elapsed, hits = 0, 0.0, 0
        per_scene = max(1, num_checks // num_scenes)
        for i in range(num_scenes):
            problem = task.problem("test", i)
            task.world.load(problem.scene)
            qs = rng.uniform(low, high, (per_scene, len(low)))
            collides = task.world.collides
            t0 = time.perf_counter()
            for q in qs:
                hits += collides(q)
            elapsed += time.perf_counter() - t0
            total += per_scene
        return {"checks_per_second": total / elapsed, "us_per_check": 1e6 * elapsed / total,
                "collision_fraction": hits / total, "checks": total}
    finally:
        task.close()


class _CheckTimer:
    """Wraps ``RobotWorld.collides`` to accumulate the time spent inside collision checks."""

    def __init__(self, world: Any) -> None:
        self.world = world
        self.inner = world.collides
        self.seconds = 0.0
        self.calls = 0
        world.collides = self

    def __call__(self, q: np.ndarray) -> bool:
        t0 = time.perf_counter()
        out = self.inner(q)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        return out

    def restore(self) -> None:
        self.world.collides = self.inner


def uniform_birrt(scene: str, split: str, problems: int, max_nodes: int, seed: int) -> dict[str, Any]:
    """The uniform sampler's BiRRT on problems ``0..problems-1`` of ``split`` (the benchmark's env and
    seeding rule), with the time inside the collision checks measured."""
    env = evaluation_env("arm", split, scene=scene, max_nodes=max_nodes, checker=CHECKER)
    base = env.unwrapped
    sampler = load_sampler("uniform", task="arm", seed=0)
    timer = _CheckTimer(base.task.world)
    records = []
    try:
        for i in tqdm(range(problems), desc=f"uniform BiRRT ({scene})", leave=False):
            check_s0, calls0 = timer.seconds, timer.calls
            run = plan_problem(env, sampler, i, seed)
            records.append({"index": i, "solved": run.success, "time": run.env_time_s, "steps": run.iterations,
                            "collision_checks": run.collision_checks, "nodes": run.nodes_expanded,
                            "path_length": run.path_length,
                            "check_time": timer.seconds - check_s0, "check_calls": timer.calls - calls0})
    finally:
        timer.restore()
        env.close()
    return _summary(records)


def _summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    solved = [r for r in records if r["solved"]]
    out: dict[str, Any] = {"problems": len(records), "solve_rate": len(solved) / max(1, len(records)),
                           "records": records}
    for key in ("collision_checks", "time", "nodes"):
        vals = [r[key] for r in records if r.get(key) is not None]
        out[f"median_{key}"] = float(np.median(vals)) if vals else float("nan")
        svals = [r[key] for r in solved if r.get(key) is not None]
        out[f"median_{key}_solved"] = float(np.median(svals)) if svals else float("nan")
    if records and "steps" in records[0]:
        steps = sum(r["steps"] for r in records)
        step_time = sum(r["time"] for r in records)
        check_time = sum(r["check_time"] for r in records)
        out["steps_per_second"] = steps / step_time
        out["checks_per_second_in_env"] = sum(r["check_calls"] for r in records) / max(check_time, 1e-12)
        out["overhead_fraction"] = 1.0 - check_time / step_time
    return out


def step_throughput(scene: str, window: int, seed: int, copy_observations: bool) -> dict[str, float]:
    """Steps/s and overhead over ``window`` uniform steps on held-out problems, the goal test
    kept on (episodes restart on the next problem when they end). The env keeps its registered
    ``max_nodes``: the padded observation it copies each step is part of its overhead."""
    env = gym.make(ENV_ID, split="test", task_kwargs={"scene": scene}, checker=CHECKER,
                   copy_observations=copy_observations, disable_env_checker=not copy_observations)
    base = env.unwrapped
    timer = _CheckTimer(base.task.world)
    try:
        rng = np.random.default_rng(seed)
        low, high = env.action_space.low, env.action_space.high
        actions = iter(rng.uniform(low, high, (window, len(low))).astype(np.float32))
        index, steps, step_time = 0, 0, 0.0
        obs, _ = env.reset(options={"index": index})
        while steps < window:
            run = run_steps(env, lambda _obs: next(actions), obs, max_steps=window - steps)
            steps += run.steps
            step_time += run.env_time_s
            obs = run.observation
            if run.terminated or run.truncated:
                index += 1
                obs, _ = env.reset(options={"index": index})
        return {"steps_per_second": window / step_time, "overhead_fraction": 1.0 - timer.seconds / step_time,
                "checks_per_step": timer.calls / window, "us_per_step": 1e6 * step_time / window}
    finally:
        timer.restore()
        env.close()


@dataclass
class Args:
    """Flags of ``python -m tools.bench_arm``."""

    scene: str = arg("test", "scene family (held out: test)", choices=("train-a", "train-b", "train", "test"))
    split: str = arg("test", "problem split", choices=("train", "val", "test"))
    problems: int = arg(50, "problems 0..N-1 planned by uniform BiRRT and OMPL", parse=positive_int)
    max_nodes: int = arg(20000, "node budget of the solve rows", parse=positive_int)
    raw_checks: int = arg(20000, "configurations for the raw checker rate", parse=positive_int)
    window: int = arg(3000, "env steps for the throughput measurement", parse=positive_int)
    time_limit: float = arg(10.0, "OMPL time limit per problem (s)", parse=positive_float)
    ompl: bool = arg(True, "skip OMPL RRTConnect")
    seed: int = arg(0, "seed of the uniform samples", parse=seed_int)
    json: str | None = arg(None, "write all figures and records here")
    ompl_log: str | None = arg(None, "write both planners' runs as an OMPL benchmark log")


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: prints the figures; exit status 0."""
    run(argv)
    return 0


def run(argv: list[str] | None = None) -> dict[str, Any]:
    """Measure and print everything; returns the report (also written with ``--json``)."""
    ap = OneLineParser(prog="python -m tools.bench_arm", description=__doc__.split("\n\n")[0])
    add_dataclass_arguments(ap, Args)
    args = from_namespace(Args, ap.parse_args(argv))

    report: dict[str, Any] = {"scene": args.scene, "split": args.split, "max_nodes": args.max_nodes}
    raw = raw_checks_per_second(args.scene, args.raw_checks, seed=args.seed)
    report["raw_checker"] = raw
    print(f"checker alone: {raw['checks_per_second']:,.0f} checks/s ({raw['us_per_check']:.1f} us/check, "
          f"{100 * raw['collision_fraction']:.0f}% of uniform configurations in collision)")
    for copy in (True, False):
        thr = step_throughput(args.scene, args.window, args.seed, copy)
        report[f"throughput_copy_{copy}"] = thr
        print(f"env steps (copy_observations={copy}): {thr['steps_per_second']:,.0f} steps/s, "
              f"{thr['checks_per_step']:.1f} checks/step, overhead {100 * thr['overhead_fraction']:.1f}% of step time")

    uni = uniform_birrt(args.scene, args.split, args.problems, args.max_nodes, args.seed)
    report["uniform_birrt"] = uni
    print(f"uniform BiRRT, {args.problems} held-out '{args.scene}' problems, <= {args.max_nodes} nodes: "
          f"solved {100 * uni['solve_rate']:.0f}%, median checks {uni['median_collision_checks']:,.0f}, "
          f"median time {uni['median_time']:.3f} s, median nodes {uni['median_nodes']:.0f}; "
          f"{uni['steps_per_second']:,.0f} steps/s, overhead {100 * uni['overhead_fraction']:.1f}%")

    ompl_results = None
    if args.ompl:
        from gnn_mp_envs.baselines.ompl_runner import OMPLUnavailableError, run_ompl
        try:
            ompl_results = run_ompl("arm", list(range(args.problems)), split=args.split,
                                    task_kwargs={"scene": args.scene, "checker": CHECKER}, planner="rrtconnect",
                                    time_limit=args.time_limit, seed=args.seed)
        except OMPLUnavailableError as e:
            print(f"OMPL RRTConnect skipped: {e}")
    if ompl_results is not None:
        om = _summary(ompl_results)
        report["ompl_rrtconnect"] = om
        print(f"OMPL RRTConnect, same problems, {args.time_limit:g} s limit: solved {100 * om['solve_rate']:.0f}%, "
              f"median checks {om['median_collision_checks']:,.0f}, median time {om['median_time']:.3f} s, "
              f"median nodes {om['median_nodes']:.0f}")
    if args.json:
        atomic_write_text(Path(args.json), json.dumps(report, indent=1, default=float) + "\n")
    if args.ompl_log:
        from gnn_mp_envs.baselines.ompl_log import write_ompl_log
        runs = {"birrt_uniform": [dict(r, status="Exact solution" if r["solved"] else "Timeout")
                                  for r in uni["records"]]}
        if ompl_results is not None:
            runs["geometric_RRTConnect"] = ompl_results
        write_ompl_log(args.ompl_log, f"arm {args.scene} {args.split}", runs, time_limit=args.time_limit,
                       seed=args.seed, setup=f"task=arm scene={args.scene} split={args.split} "
                       f"problems=0..{args.problems - 1} max_nodes={args.max_nodes}")
    return report


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
