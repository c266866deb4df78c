"""The sphere checker's time on the edges a planner checks: the edge checks of uniform BiRRT runs on a
split's problems, replayed in one compiled call per problem, so that settings that change the
checker's work but never its answers (such as the walks' ``REFINE``) are compared on the edges that
planning asks for rather than on random ones. Run from the repository root::

    python -m tools.bench_planning_checks --task ur5-mbm --split val --problems 40
    python -m tools.bench_planning_checks --task ur5-mbm --split val --problems 40 --refine 1.0

The problems are the benchmark's (``gnn-mp benchmark --split``, its default scene unless ``--scene``
names one). Each is planned once with the uniform sampler (seeded as the benchmark seeds it), the
samples it consumed are planned again by the Python planner, which records every steer and edge
check in order, and those calls are replayed through the compiled kernel with the checker's memory
of edge ends cleared first: the best of ``--repeat`` replays is the problem's time. ``--refine``
compiles the kernel with another ``REFINE`` into a numba cache folder of its own (the package's
cache is not touched). Prints edges, collision checks and milliseconds per problem and in all; the
replay's edges and checks must equal the planner's counters (else it stops with an error).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np


def _positive(text: str) -> float:
    value = float(text)
    if not (np.isfinite(value) and 0.0 < value <= 100.0):
        raise argparse.ArgumentTypeError(f"must be in (0, 100], got {text}")
    return value


def _record(problem, calls: list) -> None:
    """Make ``problem`` record its steer and edge-check calls and offer no compiled kernel (the Python
    planner, whose calls are the compiled loop's, in the same order)."""
    steer, motion = problem.steer, problem.check_motion

    def recorded_steer(a, b):
        calls.append((0, np.array(a, dtype=np.float64), np.array(b, dtype=np.float64)))
        return steer(a, b)

    def recorded_motion(a, b):
        calls.append((1, np.array(a, dtype=np.float64), np.array(b, dtype=np.float64)))
        return motion(a, b)

    problem.steer, problem.check_motion, problem.compiled_kernel = recorded_steer, recorded_motion, lambda: None


def _unrecord(problem) -> None:
    for name in ("steer", "check_motion", "compiled_kernel"):
        del problem.__dict__[name]


def main(argv: list[str] | None = None) -> int:
    from train.args import seed_int
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="ur5-mbm")
    ap.add_argument("--split", default="val", choices=("train", "val", "test"))
    ap.add_argument("--scene", default=None, help="scene family (default: the one the benchmark plans)")
    ap.add_argument("--problems", type=int, default=20)
    ap.add_argument("--seed", type=seed_int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="replays per problem (the best is kept)")
    ap.add_argument("--refine", type=_positive, default=None,
                    help="compile the kernel with this REFINE (its own numba cache folder)")
    ap.add_argument("--per-problem", action="store_true", help="print a line per problem")
    args = ap.parse_args(argv)
    for name, value, top in (("--problems", args.problems, 100_000), ("--repeat", args.repeat, 100)):
        if not 1 <= value <= top:
            ap.error(f"{name} must be in [1, {top}], got {value}")
    if args.refine is not None:        # before anything compiled is imported: a folder per setting
        os.environ["NUMBA_CACHE_DIR"] = os.path.join(tempfile.gettempdir(), f"gnn-mp-refine-{args.refine!r}")
        from gnn_mp_envs.robots.spheres import kernel
        kernel.REFINE = args.refine

    from gnn_mp_envs.registration import task_spec
    spec = task_spec(args.task)
    if "spheres" not in spec.checkers:
        from gnn_mp_envs.registration import TASK_SPECS
        ap.error(f"task {args.task!r} has no sphere checker (tasks with one: "
                 f"{', '.join(n for n, s in TASK_SPECS.items() if 'spheres' in s.checkers)})")
    from agents.samplers import load_sampler
    from gnn_mp_envs.core.planners import make_planner
    from gnn_mp_envs.evaluation import evaluation_env, problem_seed
    from gnn_mp_envs.utils.compiled import jit

    from gnn_mp_envs.core.problem import ZERO_LENGTH

    @jit
    def replay(steer, motion, kinds, starts, ends, step, context, x_new, distance):
        """The recorded calls in order: ``(edges, collision checks)`` as the planner counts them (a
        zero-length steer is refused unchecked and not counted)."""
        edges, checks = 0, 0
        for i in range(kinds.shape[0]):
            if kinds[i] == 0:
                r = steer(starts[i], ends[i], step, context, x_new, distance)
                if distance[0] < ZERO_LENGTH:
                    continue
            else:
                r = motion(starts[i], ends[i], context)
            edges += 1
            checks += abs(r)
        return edges, checks

    scene = args.scene if args.scene is not None else spec.benchmark_scene
    if scene is not None and scene not in spec.scenes:
        ap.error(f"--scene {scene!r}: {args.task} has " + (f"the scenes {', '.join(spec.scenes)}" if spec.scenes
                                                           else "no scenes"))
    env = evaluation_env(args.task, args.split, scene=scene, samples_per_step=64)
    sampler = load_sampler("uniform", args.task)
    available = env.task.num_problems(args.split)
    if available and args.problems > available:
        ap.error(f"--problems must be at most {available} (the {args.split} split of {args.task})")
    total_ms, total_edges, total_checks = 0.0, 0, 0
    for i in range(args.problems):
        obs, _ = env.reset(seed=problem_seed(args.seed, i), options={"index": i})
        sampler.reset(seed=problem_seed(args.seed, i))
        used, done, info = [], False, {}
        while not done:
            batch = sampler.act_batch(obs, 64)
            obs, _, terminated, truncated, info = env.step(batch)
            used.append(batch)
            done = terminated or truncated
        samples = np.concatenate(used)[: env.planner.iterations]
        problem, calls = env.problem, []
        _record(problem, calls)
        try:
            planner = make_planner(env.planner_name, problem, env.max_nodes)
            for sample in samples:
                planner.step(sample)
                if planner.solution is not None:
                    break
        finally:
            _unrecord(problem)
        kernel = problem.compiled_kernel()
        kinds = np.array([c[0] for c in calls], dtype=np.int64)
        starts = np.array([c[1] for c in calls]).reshape(len(calls), -1)
        ends = np.array([c[2] for c in calls]).reshape(len(calls), -1)
        x_new, distance = np.zeros(starts.shape[1]), np.zeros(1)
        best, edges, checks = np.inf, 0, 0
        for _ in range(args.repeat):
            problem.checker.kernel(problem.scene).forget_edge_ends()
            start = time.perf_counter()
            edges, checks = replay(kernel.steer, kernel.motion, kinds, starts, ends, problem.step_size,
                                   kernel.context, x_new, distance)
            best = min(best, time.perf_counter() - start)
        if (edges, checks) != (info["edges"], info["collision_checks"]):
            raise RuntimeError(f"problem {i}: the replay checked {edges} edges with {checks} collision checks, "
                               f"the planner {info['edges']} with {info['collision_checks']}")
        total_ms += 1e3 * best
        total_edges += int(edges)
        total_checks += int(checks)
        if args.per_problem:
            print(f"problem {i:4d}: {int(edges):7d} edges {int(checks):9d} checks {1e3 * best:9.2f} ms")
    env.close()
    refine = args.refine if args.refine is not None else "default"
    print(f"{args.task} ({args.split}, scene {scene}, {args.problems} problems, REFINE {refine}): {total_edges} edges, "
          f"{total_checks} collision checks, {total_ms:.1f} ms ({1e3 * total_ms / max(total_edges, 1):.2f} us "
          f"per edge)")
    return 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
