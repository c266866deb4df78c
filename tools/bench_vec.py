"""Vectorised environments: env steps per second of one env, Gymnasium's ``make_vec`` (sync and async,
through ``gnn_mp_envs.envs.vector.make_vec``) and TorchRL's ``ParallelEnv``, with uniform random actions.

Run: ``.venv/bin/python -m tools.bench_vec`` from the repository root. Each mode plans held-out
problems of ``--env-id`` with uniform actions (drawn beforehand; ``parallelenv``: from its action
spec, each step) for ``--steps`` environment steps in all (``--n-envs`` copies step together in the
vectorised modes; an ended episode resets, as in training); steps/s counts every copy's steps. The
start-up (building the copies and the first reset) is timed apart: the workers of ``async`` fork,
those of ``parallelenv`` start as ``--mp-start-method`` says (TorchRL's default: spawned, importing
torch and the package anew). ``--no-copy`` makes the envs with ``copy_observations=False``: a vector
env copies each observation into its batch anyway.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from train.args import OneLineParser, add_dataclass_arguments, arg, from_namespace, name_list, positive_int, seed_int

MODES = ("single", "sync", "async", "parallelenv")


@dataclass
class Args:
    """Flags of ``python -m tools.bench_vec``."""

    env_id: str = arg("GNNMP/Maze2DRRT-v0", "environment id")
    modes: list[str] = arg(list(MODES), f"modes to measure ({', '.join(MODES)})", parse=name_list)
    n_envs: int = arg(2, "copies of the env in the vectorised modes", parse=positive_int)
    steps: int = arg(20000, "env steps per mode, all copies together", parse=positive_int)
    seed: int = arg(0, "seed of the problems and of the actions", parse=seed_int)
    copy: bool = arg(True, "make the envs with copy_observations=False", flag="--no-copy")
    mp_start_method: str = arg("spawn", "ParallelEnv's start method (TorchRL's default: spawn, unless the program "
                               "set one; fork starts faster on Linux)", choices=("spawn", "fork", "forkserver"))


def _actions(space, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(space.low, space.high, size=(count, *space.shape)).astype(space.dtype)


def single(args: Args) -> tuple[float, float]:
    import gymnasium as gym
    start = time.perf_counter()
    env = gym.make(args.env_id, split="test", copy_observations=args.copy)
    env.reset(seed=args.seed)
    startup = time.perf_counter() - start
    actions = _actions(env.action_space, args.steps, args.seed)
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return startup, args.steps / elapsed


def vector(args: Args, mode: str) -> tuple[float, float]:
    from gnn_mp_envs.envs.vector import make_vec
    start = time.perf_counter()
    envs = make_vec(args.env_id, num_envs=args.n_envs, vectorization_mode=mode, split="test",
                    copy_observations=args.copy)
    envs.reset(seed=args.seed)
    startup = time.perf_counter() - start
    calls = max(args.steps // args.n_envs, 1)
    actions = _actions(envs.single_action_space, calls * args.n_envs, args.seed).reshape(
        calls, args.n_envs, *envs.single_action_space.shape)
    start = time.perf_counter()
    for a in actions:
        envs.step(a)                   # an ended copy resets on its next step (Gymnasium's autoreset)
    elapsed = time.perf_counter() - start
    envs.close()
    return startup, calls * args.n_envs / elapsed


def parallel_env(args: Args) -> tuple[float, float]:
    from functools import partial

    from torchrl.envs import ParallelEnv
    start = time.perf_counter()
    envs = ParallelEnv(args.n_envs, partial(_torchrl_env, args.env_id, args.copy),
                       mp_start_method=args.mp_start_method)
    envs.set_seed(args.seed)
    td = envs.reset()
    startup = time.perf_counter() - start
    calls = max(args.steps // args.n_envs, 1)
    start = time.perf_counter()
    for _ in range(calls):
        envs.rand_action(td)                     # uniform, from the action spec
        _, td = envs.step_and_maybe_reset(td)    # an ended copy resets
    elapsed = time.perf_counter() - start
    envs.close()
    return startup, calls * args.n_envs / elapsed


def _torchrl_env(env_id: str, copy: bool):
    import gnn_mp_envs  # noqa: F401  (registers the ids in the worker)
    from torchrl.envs import GymEnv
    return GymEnv(env_id, split="test", copy_observations=copy)


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m tools.bench_vec", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401  (registers the ids)
    if args.env_id not in gym.registry:
        parser.error(f"unknown env id {args.env_id!r}")
    unknown = [m for m in args.modes if m not in MODES]
    if unknown:
        parser.error(f"unknown mode(s) {unknown}; known: {', '.join(MODES)}")
    print(f"{args.env_id}, {args.steps} env steps per mode, {args.n_envs} copies in the vectorised modes"
          + ("" if args.copy else ", copy_observations=False"))
    print(f"{'mode':<28} {'steps/s':>9} {'start-up [s]':>13}")
    label = {"single": "one env", "sync": "make_vec, sync", "async": "make_vec, async",
             "parallelenv": "TorchRL ParallelEnv"}
    for mode in args.modes:
        if mode == "single":
            startup, rate = single(args)
        elif mode == "parallelenv":
            startup, rate = parallel_env(args)
        else:
            startup, rate = vector(args, mode)
        print(f"{label[mode]:<28} {rate:>9,.0f} {startup:>13.1f}", flush=True)
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
