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

import dataclasses
from typing import Any

from train.args import MAX_COUNT, OneLineParser, UsageError, add_dataclass_arguments, from_namespace, import_modules
from train.rl.args import RLArgs, check_args, hyperparams_file, read_hyperparams


def hyperparam_tokens(values: dict[str, Any]) -> list[str]:
    """Flag values (field name -> value) as command-line tokens, so that a YAML file's values are
    parsed and checked exactly as flags (``[--lr, 0.0003, --tree-context, ...]``)."""
    fields = {f.name: f for f in dataclasses.fields(RLArgs)}
    tokens: list[str] = []
    for name, value in values.items():
        field = fields[name]
        default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
        if isinstance(default, bool):
            if bool(value) != default:
                tokens.append(field.metadata.get("flag") or ("--no-" if default else "--") + name.replace("_", "-"))
            continue
        text = ",".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)
        if isinstance(value, (list, tuple)) and not value:
            text = "none"
        tokens += [f"--{name.replace('_', '-')}", text]
    return tokens


#: Flags that describe a picker (``--action pick``): a box run ignores them in a YAML file, whose
#: section describes the task's picker (the pendulum's file sets a candidate prior).
PICK_ONLY_FLAGS = ("candidates", "local_scale", "target_scale", "pi_arch", "pick_head", "candidate_hidden",
                   "candidate_embed", "tree_context", "prior", "prior_temperature", "prior_scale")


def build_parser() -> OneLineParser:
    """The flags of ``gnn-mp train rl`` (the fields of :class:`~train.rl.args.RLArgs`)."""
    parser = OneLineParser(prog="gnn-mp train rl", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, RLArgs)
    return parser


def picker_flags_given(args: RLArgs) -> list[str]:
    """The picker's flags given on the command line with values other than their defaults (``--tree-context``
    and ``--prior`` are refused by :func:`~train.rl.args.check_args`, with their own message)."""
    given = []
    for field in dataclasses.fields(RLArgs):
        if field.name not in PICK_ONLY_FLAGS or field.name in ("tree_context", "prior"):
            continue
        default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
        if getattr(args, field.name) != default:
            given.append("--" + field.name.replace("_", "-"))
    return given


def parse(argv: list[str]) -> RLArgs:
    """The flags: the dataclass's defaults, then the task's YAML section (``--hyperparams``, by
    default ``train/rl/hyperparams/<task>.yml``; a box run skips its picker keys), then the
    command line."""
    parser = build_parser()
    first = from_namespace(RLArgs, parser.parse_args(argv))
    try:
        import_modules(first.modules)
        path = hyperparams_file(first)
        values = read_hyperparams(path, first.lib, first.algo, first.task, first.planner, first.action) if path else {}
        explicit_action = any(a == "--action" or a.startswith("--action=") for a in argv)
        action = first.action if explicit_action else values.get("action", first.action)
        if action == "box":
            values = {k: v for k, v in values.items() if k not in PICK_ONLY_FLAGS}
            ignored = picker_flags_given(first)
            if ignored:
                raise ValueError(f"--action box ignores the picker's flags (--action pick): {', '.join(ignored)}")
        tokens = hyperparam_tokens(values)
    except ValueError as exc:
        parser.error(str(exc))
    if tokens:
        checker = OneLineParser(prog=f"gnn-mp train rl: {path}", add_help=False)
        add_dataclass_arguments(checker, RLArgs)
        checker.parse_args(tokens)           # a bad value names the file
    args = from_namespace(RLArgs, parser.parse_args(tokens + argv))
    args.hyperparams = path
    if args.minutes is not None and not any(a == "--total-steps" or a.startswith("--total-steps=") for a in argv):
        args.total_steps = MAX_COUNT         # --minutes alone: the clock ends the run, not the file's step count
    try:
        check_args(args)
    except ValueError as exc:
        parser.error(str(exc))
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse(list(sys.argv[1:] if argv is None else argv))
    if args.lib == "sb3":
        from train.rl.sb3 import train
    else:
        from train.rl.torchrl import train
    try:
        train(args)
    except UsageError as exc:        # a RunError
        print(f"gnn-mp train rl: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
