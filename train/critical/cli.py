"""``python -m train.critical`` / ``gnn-mp critical``: generate-data | train | evaluate.

The flags of each sub-command are the fields of its dataclass in :mod:`train.critical.args`
(``--help`` lists them with defaults). Bad input, unusable checkpoints and dataset or file
errors end with one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Sequence

import torch

from agents.checkpoints import CheckpointError
from gnn_mp_envs.critical.dataset import DatasetCacheError, generate_all
from train.args import OneLineParser, UsageError, add_dataclass_arguments, from_namespace
from train.critical.args import EvaluateArgs, GenerateArgs, TrainArgs

PROG = "critical"
#: sub-command -> (flags dataclass, help)
COMMANDS: dict[str, tuple[type, str]] = {
    "generate-data": (GenerateArgs, "generate and cache the critical-sample datasets"),
    "train": (TrainArgs, "train one critical-sample model"),
    "evaluate": (EvaluateArgs, "accuracy / hit-rate tables, figure and planning with k samples"),
}


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = OneLineParser(prog=prog or PROG, description="Critical samples: data generation, training and "
                           "evaluation of GNN / GAT / GNN-CVAE / CNN / CVAE (docs/critical.md).")
    add_subparsers(parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                         parser_class=OneLineParser))
    return parser


def add_subparsers(subparsers: Any) -> None:
    """Register ``generate-data``, ``train`` and ``evaluate`` on an argparse subparsers object."""
    for name, (cls, help_text) in COMMANDS.items():
        sub = subparsers.add_parser(name, help=help_text, description=(cls.__doc__ or help_text).strip())
        add_dataclass_arguments(sub, cls)
        sub.set_defaults(args_class=cls)


def cmd_generate(a: GenerateArgs) -> None:
    for key, path in generate_all(a.dataset(), a.data, overwrite=a.overwrite).items():
        print(f"{key}: {path}")


def cmd_train(a: TrainArgs) -> None:
    from train.critical.training import train
    res = train(a)
    print(json.dumps(res["best"]))
    print(f"checkpoint: {res['checkpoint']}")


def cmd_evaluate(a: EvaluateArgs) -> None:
    from gnn_mp_envs.critical.dataset import check_has_split
    from train.critical.evaluation import evaluate, format_table
    from train.critical.training import TrainError
    if a.split == "val":
        try:
            check_has_split(a.dataset(), "val", "--split val scores the validation problems")
        except ValueError as exc:
            raise TrainError(str(exc)) from None
    rep = evaluate(a.models, a.checkpoints, a.data, a.problems, a.samples, seed=a.seed,
                   json_path=a.json, plot_path=a.plot, dataset=a.dataset(), progress=a.progress,
                   eval_seed=a.eval_seed, ks=a.ks, min_sep_r=a.min_sep, select=a.select,
                   split=a.split)
    print(format_table(rep))


RUN = {GenerateArgs: cmd_generate, TrainArgs: cmd_train, EvaluateArgs: cmd_evaluate}


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the sub-command; returns the exit status (2: one-line error)."""
    # `gnn-mp critical ...` sets argv[0] to "gnn-mp critical" so messages name the real command
    prog = sys.argv[0] if sys.argv and sys.argv[0].startswith("gnn-mp") else PROG
    parser = build_parser(prog)
    ns = parser.parse_args(argv)
    args = from_namespace(ns.args_class, ns)
    if isinstance(args, TrainArgs) and args.model is None:
        parser.error("train: the following argument is required: --model")
    try:
        args.check_size()
    except UsageError as exc:
        parser.error(f"{ns.command}: {exc}")
    torch.set_num_threads(args.threads)
    try:
        RUN[type(args)](args)
    except (UsageError, CheckpointError, DatasetCacheError) as exc:     # TrainError, RunError
        return _fail(prog, str(exc))
    except OSError as exc:   # unreadable / unwritable files
        return _fail(prog, f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc))
    except KeyboardInterrupt:
        return _fail(prog, "interrupted", 130)
    return 0


def _fail(prog: str, message: str, code: int = 2) -> int:
    print(f"{prog}: error: {message}", file=sys.stderr)
    return code
