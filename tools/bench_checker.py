"""Cost of the collision checkers, side by side: per configuration and per edge, and where the
sphere checker's time goes (forward kinematics, obstacle tests, self-collision). Run from the
repository root::

    python -m tools.bench_checker --task panda-mbm --problems 10

On each of the first ``--problems`` test problems it draws ``--states`` uniform configurations
and ``--edges`` random edges of one extension (``step_size``) from valid configurations, checks
them with both checkers (every state of an edge, in the planner's order, up to the first invalid
one) and prints microseconds per configuration and per edge. The breakdown times the sphere
checker three ways on the same states: with no obstacles and no self pairs (forward kinematics
and the call), with obstacles only, and whole; the differences are the obstacle tests and the
self-collision tests. Counters (states checked, valid fractions) are printed too: both checkers see
the same states.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np


def _time(fn, repeat: int = 3) -> float:
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main(argv: list[str] | None = None) -> int:
    from train.args import seed_int
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="panda-mbm")
    ap.add_argument("--problems", type=int, default=10)
    ap.add_argument("--states", type=int, default=2000, help="uniform configurations per problem")
    ap.add_argument("--edges", type=int, default=200, help="edges per problem")
    ap.add_argument("--seed", type=seed_int, default=0)
    args = ap.parse_args(argv)
    for name, value in (("--problems", args.problems), ("--states", args.states), ("--edges", args.edges)):
        if not 1 <= value <= 1_000_000:
            ap.error(f"{name} must be in [1, 1000000], got {value}")

    from gnn_mp_envs.registration import make_task, task_spec
    spec = task_spec(args.task)
    if "spheres" not in spec.checkers:
        from gnn_mp_envs.registration import TASK_SPECS
        ap.error(f"task {args.task!r} has no sphere checker (tasks with one: "
                 f"{', '.join(n for n, s in TASK_SPECS.items() if 'spheres' in s.checkers)})")
    scene = {"scene": spec.default_scene("test")} if spec.scenes else {}
    tasks = {c: make_task(args.task, checker=c, **scene) for c in ("spheres", "pybullet")}
    rng = np.random.default_rng(args.seed)
    per_state = {c: 0.0 for c in tasks}
    per_edge = {c: 0.0 for c in tasks}
    checks = {c: 0 for c in tasks}
    valid = {c: 0 for c in tasks}
    parts = {"fk": 0.0, "obstacles": 0.0, "whole": 0.0}
    n_states = n_edges = 0
    for i in range(args.problems):
        problems = {c: t.problem("test", i) for c, t in tasks.items()}
        p = problems["spheres"]
        states = rng.uniform(p.low, p.high, (args.states, p.state_dim))
        # edges from valid configurations (valid for both checkers), one step long
        starts = states[problems["pybullet"].is_state_valid(states) & p.is_state_valid(states)][: args.edges]
        d = rng.normal(size=starts.shape)
        ends = np.clip(starts + p.step_size * d / np.linalg.norm(d, axis=1, keepdims=True), p.low, p.high)
        for c, prob in problems.items():
            prob.is_state_valid(states[:1])                          # load the scene (and compile) first
            per_state[c] += _time(lambda: prob.is_state_valid(states), repeat=1 if c == "pybullet" else 3)
            valid[c] += int(prob.is_state_valid(states).sum())
            if len(starts):                                          # the edge check compiled before its timing
                prob.check_motion(starts[0], ends[0])
            prob.reset_counters()

            def edges(prob=prob):
                for a, b in zip(starts, ends):
                    prob.check_motion(a, b)
            per_edge[c] += _time(edges, repeat=1)
            checks[c] += prob.collision_checks
        checker = p.checker.kernel(p.scene)
        spheres = checker.spheres
        try:
            parts["whole"] += _time(lambda: checker.valid(states))
            checker.spheres = spheres._replace(pairs=spheres.pairs[:0], pair_root=spheres.pair_root[:0],
                                               pair_moving=spheres.pair_moving[:0],
                                               pair_reach=spheres.pair_reach[:0])
            checker._pack()
            parts["obstacles"] += _time(lambda: checker.valid(states))
            checker.set_obstacles(())
            parts["fk"] += _time(lambda: checker.valid(states))
        finally:
            checker.spheres = spheres
            p.checker.prepare(())             # the checker reloads the problem's scene at its next use
            checker._pack()
        n_states += len(states)
        n_edges += len(starts)
    for t in tasks.values():
        t.close()
    print(f"{args.task}: {args.problems} test problems, {n_states} uniform configurations, {n_edges} edges of "
          f"{p.step_size} rad checked every {p.resolution} rad in the planner's order")
    print(f"{'checker':<10} {'us / configuration':>19} {'us / edge':>10} {'states per edge':>16} {'valid':>7}")
    for c in tasks:
        print(f"{c:<10} {1e6 * per_state[c] / n_states:>19.2f} {1e6 * per_edge[c] / n_edges:>10.1f} "
              f"{checks[c] / n_edges:>16.1f} {valid[c] / n_states:>7.1%}")
    ratio = (per_state["pybullet"] / n_states) / (per_state["spheres"] / n_states)
    print(f"pybullet / spheres per configuration: {ratio:.0f}x")
    whole = parts["whole"]
    fk, obst = parts["fk"], parts["obstacles"] - parts["fk"]
    selfc = whole - parts["obstacles"]
    print(f"sphere checker, uniform configurations: {1e6 * whole / n_states:.2f} us each: forward kinematics and "
          f"call {fk / whole:.0%}, obstacle tests {obst / whole:.0%}, self-collision {selfc / whole:.0%}")
    return 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
