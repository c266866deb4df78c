"""``gnn-mp train sampler``: flags from :class:`~train.tree.args.TrainArgs`."""

from __future__ import annotations

import importlib.util
import json
import sys
from typing import Sequence

from train.args import OneLineParser, add_dataclass_arguments, from_namespace


def build_parser() -> OneLineParser:
    """The flags of ``gnn-mp train sampler`` (the fields of :class:`~train.tree.args.TrainArgs`)."""
    from train.tree.args import TrainArgs
    parser = OneLineParser(prog="gnn-mp train sampler",
                           description="Train a learned tree sampler (the paper's Algorithm 1, with DAgger) and "
                           "evaluate it against uniform on validation problems.")
    add_dataclass_arguments(parser, TrainArgs)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    if importlib.util.find_spec("torch") is None:     # an environments-only install: one line naming the extra
        raise ModuleNotFoundError("No module named 'torch'", name="torch")
    from train.tree.args import TrainArgs
    parser = build_parser()
    args = from_namespace(TrainArgs, parser.parse_args(argv))
    from train.args import UsageError, check_ray_address
    from train.tree.args import check_counts
    try:
        check_counts(args)
    except UsageError as exc:
        parser.error(str(exc))
    if args.ray not in (None, "local", "auto"):
        try:
            check_ray_address(args.ray)
        except UsageError as exc:
            parser.error(str(exc))
    from agents.checkpoints import CheckpointError       # torch: only once the flags are known to be good
    from gnn_mp_envs.utils.npz import DatasetCacheError
    from train.tree.training import train
    try:
        summary = train(args)
    except (UsageError, CheckpointError, DatasetCacheError) as exc:     # TrainError, RunError, a worker's
        print(f"gnn-mp train sampler: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({k: summary[k] for k in ("run_dir", "checkpoint", "items", "train_seconds", "validation",
                                              "shipped")
                      if k in summary}, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
