"""Environment throughput: env steps per second with the uniform sampler at given tree sizes.

Run: ``gnn-mp bench-env`` (or ``python -m train.bench_env``). For each task, a held-out
problem is planned with its goal test switched off so the tree can grow to each
measured size; then ``--window`` further ``env.step`` calls are timed (uniform actions
drawn beforehand, so only the environment is measured). The observation is updated
in place, so per-step cost should stay nearly flat as the tree grows; the nearest
neighbour query is the only part that scans the tree.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

import gnn_mp_envs  # noqa: F401  (registers the environments)
from gnn_mp_envs.registration import TASK_ENV_IDS
from train.args import OneLineParser


@dataclass
class Args:
    tasks: tuple[str, ...] = ("maze2d", "pendulum")
    """tasks to measure"""
    sizes: tuple[int, ...] = (100, 1000, 5000)
    """tree sizes at which steps/s is measured"""
    window: int = 1000
    """timed env steps per size"""
    seed: int = 0
    """seed of the uniform actions"""
    copy_observations: bool = True
    """measure with the default copied observations (False: live views)"""


def _goal_free(problem) -> None:
    """Switch off the goal test so the tree keeps growing (benchmark only)."""
    problem.in_goal = lambda x: False
    problem.goal_connection = lambda x: None


def measure(task: str, sizes: tuple[int, ...], window: int, seed: int,
            copy_observations: bool = True) -> dict[int, float]:
    """Steps per second of ``env.step`` at each tree size in ``sizes``."""
    registered = gym.spec(TASK_ENV_IDS[task]).kwargs["max_nodes"]
    max_nodes = max(registered, max(sizes) + window + 10)  # pad as users get it, or more if needed
    env = gym.make(TASK_ENV_IDS[task], max_nodes=max_nodes, max_steps=100 * max_nodes,
                   split="test", copy_observations=copy_observations).unwrapped
    problem = env.task.problem("test", 0)
    _goal_free(problem)
    env.reset(seed=seed, options={"problem": problem})
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    out: dict[int, float] = {}
    for size in sorted(sizes):
        while len(env.planner.tree) < size:
            env.step(rng.uniform(low, high).astype(np.float32))
        actions = rng.uniform(low, high, size=(window, len(low))).astype(np.float32)
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        out[size] = window / (time.perf_counter() - t0)
    env.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="gnn-mp bench-env", description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default=",".join(Args.tasks), help="comma-separated tasks")
    parser.add_argument("--sizes", default=",".join(map(str, Args.sizes)), help="comma-separated tree sizes")
    parser.add_argument("--window", type=int, default=Args.window, help=Args.__doc__ and "timed steps per size")
    parser.add_argument("--seed", type=int, default=Args.seed)
    parser.add_argument("--no-copy", action="store_true", help="return live observation views")
    ns = parser.parse_args(argv)
    tasks = tuple(t for t in ns.tasks.split(",") if t)
    unknown = [t for t in tasks if t not in TASK_ENV_IDS]
    if unknown:
        parser.error(f"unknown task(s) {unknown}; known: {sorted(TASK_ENV_IDS)}")
    try:
        sizes = tuple(int(s) for s in ns.sizes.split(","))
    except ValueError:
        parser.error(f"--sizes must be comma-separated integers, got {ns.sizes!r}")
    if min(sizes) < 1 or ns.window < 1:
        parser.error("--sizes and --window must be positive")
    print(f"{'task':<10} " + " ".join(f"{f'{s} nodes':>12}" for s in sizes) + "   (env steps/s, uniform actions)")
    for task in tasks:
        rates = measure(task, sizes, ns.window, ns.seed, not ns.no_copy)
        print(f"{task:<10} " + " ".join(f"{rates[s]:>12.0f}" for s in sizes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
