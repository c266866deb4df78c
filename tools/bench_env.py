"""Environment throughput: env steps per second with the uniform sampler at given tree sizes.

Run: ``.venv/bin/python -m tools.bench_env`` from the repository root. For each task, a held-out
problem is planned with its goal test switched off so the tree can grow to each
measured size; then ``--window`` further ``env.step`` calls are timed (uniform actions
drawn beforehand, so only the environment is measured). The observation is updated
in place, so per-step cost should stay nearly flat as the tree grows; the nearest
neighbour query is the only part that scans the tree. Only time inside ``env.step`` counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tools.probes import goal_free_env
from gnn_mp_envs.registration import task_spec
from gnn_mp_envs.rollout import run_steps
from train.args import OneLineParser, add_dataclass_arguments, arg, from_namespace, positive_int, seed_int


@dataclass
class Args:
    """Flags of ``python -m tools.bench_env``."""

    tasks: list[str] = arg(["maze2d", "pendulum"], "tasks to measure")
    sizes: list[int] = arg([100, 1000, 5000], "tree sizes at which steps/s is measured")
    window: int = arg(1000, "timed env steps per size", parse=positive_int)
    seed: int = arg(0, "seed of the uniform actions", parse=seed_int)
    copy_observations: bool = arg(True, "return live observation views instead of the default copies")


def measure(task: str, sizes: list[int], window: int, seed: int,
            copy_observations: bool = True) -> dict[int, float]:
    """Steps per second of ``env.step`` at each tree size in ``sizes``."""
    spec = task_spec(task)
    max_nodes = max(spec.max_nodes, max(sizes) + window + 10)  # pad as users get it, or more if needed
    env, obs = goal_free_env(task, "test", 0, max_nodes=max_nodes, copy_observations=copy_observations)
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    out: dict[int, float] = {}
    for size in sorted(sizes):
        grown = run_steps(env, lambda _obs: rng.uniform(low, high).astype(np.float32), obs,
                          on_step=lambda _o, info, _d: info["nodes_expanded"] >= size)
        actions = iter(rng.uniform(low, high, size=(window, len(low))).astype(np.float32))
        timed = run_steps(env, lambda _obs: next(actions), grown.observation, max_steps=window)
        obs = timed.observation
        out[size] = window / timed.env_time_s
    env.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m tools.bench_env", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    from gnn_mp_envs.registration import TASK_SPECS
    unknown = [t for t in args.tasks if t not in TASK_SPECS]
    if unknown:
        parser.error(f"unknown task(s) {unknown}; known: {sorted(TASK_SPECS)}")
    if min(args.sizes) < 1:
        parser.error("--sizes must be positive")
    sizes = args.sizes
    print(f"{'task':<10} " + " ".join(f"{f'{s} nodes':>12}" for s in sizes) + "   (env steps/s, uniform actions)")
    for task in args.tasks:
        rates = measure(task, sizes, args.window, args.seed, args.copy_observations)
        print(f"{task:<10} " + " ".join(f"{rates[s]:>12.0f}" for s in sizes))
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
