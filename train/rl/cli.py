"""``gnn-mp train rl``: train an RL sampler with Stable-Baselines3 (PPO, SAC) or TorchRL (PPO).

    gnn-mp train rl --algo ppo --lib sb3 --task maze2d --total-steps 50000 --tune-mix 0,0.25,0.5
    gnn-mp train rl --algo sac --lib sb3 --task pendulum --total-steps 20000
    gnn-mp train rl --algo ppo --lib torchrl --task arm --total-steps 2000

The flags are the fields of :class:`train.rl.args.RLArgs`; the library's script
(:mod:`train.rl.sb3`, :mod:`train.rl.torchrl`) does the rest. The trained policy is the
sampler ``rl-ppo`` / ``rl-sac`` / ``rl-ppo-torchrl`` (``gnn-mp benchmark --samplers rl-ppo
--checkpoint rl-ppo=runs/rl/.../best.pt``, or ``--ship`` it as the task's default weights).
"""

from __future__ import annotations

import sys

from train.args import OneLineParser, add_dataclass_arguments, from_namespace
from train.rl.args import RLArgs, check_args


def parse(argv: list[str]) -> RLArgs:
    parser = OneLineParser(prog="gnn-mp train rl", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, RLArgs)
    args = from_namespace(RLArgs, parser.parse_args(argv))
    try:
        check_args(args)
    except ValueError as exc:
        parser.error(str(exc))
    return args


def main(argv: list[str] | None = None) -> int:
    from train.run import RunError
    args = parse(list(sys.argv[1:] if argv is None else argv))
    if args.lib == "sb3":
        from train.rl.sb3 import train
    else:
        from train.rl.torchrl import train
    try:
        train(args)
    except RunError as exc:
        print(f"gnn-mp train rl: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
