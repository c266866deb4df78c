"""Sampler speed: to_pyg conversions/s and act() microseconds per call, single-threaded torch.

Run: ``.venv/bin/python -m tools.bench_sampler`` from the repository root.

1. ``to_pyg``: ``--batch`` maze2d observations of ``--nodes`` nodes each (``--trees`` distinct
   trees planned on validation problems with the goal test switched off, tiled to the batch)
   are converted to one PyG ``Batch``, ``--conversions`` times; reported for full trees and
   for mixed sizes (each tree cut to a random prefix of 50-100 % of its nodes), next to the
   per-graph reference converter (``agents.nn.graph.to_pyg_per_graph``, the old loop).
2. ``act()``: for every sampler in ``--samplers`` (default: all registered) and task in
   ``--tasks``, a tree is grown to ``--act-nodes`` nodes (validation problem 0, uniform
   samples) and ``sampler.act`` is called on its last ``--window`` prefixes, one node larger
   each call, as in a planning loop (learned samplers cache per node, so they pay for every
   new node); the best of ``--rounds`` rounds is reported in microseconds per call. Learned
   samplers load their shipped weights, or ``--checkpoint NAME=PATH``; plugin samplers come
   from ``--import MODULE`` (both repeatable, as in ``gnn-mp benchmark``; ``--samplers`` and
   ``--tasks`` are comma-separated lists, as there); a sampler that cannot serve a task prints ``n/a``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from tools import probes
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS
from gnn_mp_envs.registration import TASK_SPECS, task_spec
from train.args import (OneLineParser, add_dataclass_arguments, arg, from_namespace, import_modules, positive_int,
                        seed_int)
from train.benchmark.args import checkpoint_pair

SPLIT = "val"   # problems the trees are grown on (timing only; never the held-out split)


@dataclass
class Args:
    samplers: list[str] = arg([], "comma-separated samplers whose act() is timed; empty: every registered sampler")
    tasks: list[str] = arg(["maze2d", "pendulum"], "tasks whose observations act() is timed on")
    act_nodes: int = arg(1000, "tree size (nodes) of the observation act() is timed on", parse=positive_int)
    window: int = arg(200, "act() calls per round, each on a tree one node larger (its last nodes)",
                      parse=positive_int)
    rounds: int = arg(3, "timing rounds per measurement; the best is reported", parse=positive_int)
    batch: int = arg(256, "observations per to_pyg batch", parse=positive_int)
    nodes: int = arg(500, "nodes per observation of the to_pyg batch", parse=positive_int)
    trees: int = arg(16, "distinct trees in the to_pyg batch (tiled to --batch)", parse=positive_int)
    conversions: int = arg(20, "timed to_pyg conversions per round", parse=positive_int)
    reference: bool = arg(True, "skip timing the per-graph reference converter")
    skip_to_pyg: bool = arg(False, "skip the to_pyg measurement")
    skip_act: bool = arg(False, "skip the act() measurement")
    checkpoints: dict[str, Path] = arg({}, "checkpoint passed to sampler NAME's factory (repeatable)",
                                       flag="--checkpoint", metavar="NAME=PATH", parse=checkpoint_pair, append=True)
    modules: list[str] = arg([], "import MODULE first: it registers samplers or tasks (repeatable)",
                             flag=("--import", "--sampler-module"), metavar="MODULE", append=True)
    seed: int = arg(0, "seed of the problems, tree-growing actions and samplers", parse=seed_int)
    threads: int = arg(1, "torch threads", parse=positive_int)
    clock: str = arg("wall", "wall: elapsed time; cpu: this process's CPU time (steadier on a shared machine)",
                     choices=("wall", "cpu"))


# ---------------------------------------------------------------------------- observations
def grow(task: str, nodes: int, index: int, seed: int, max_nodes: int | None = None) -> dict[str, np.ndarray]:
    """An observation of ``task``'s problem ``index`` (split ``val``) grown to ``nodes`` nodes
    with uniform samples and the goal test off."""
    return probes.grow(task, nodes, index, seed, split=SPLIT, max_nodes=max_nodes)


def cut(obs: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """The observation of the first ``n`` nodes of a tree (nodes arrive in index order)."""
    out = {k: np.array(v) for k, v in obs.items()}
    for key in ("nodes", "node_features", "mask"):
        out[key][n:] = 0
    out["parent"][n:] = -1
    out["num_nodes"][0] = n
    return out


def stack(observations: list[dict[str, np.ndarray]]) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.stack([o[k] for o in observations])) for k in OBSERVATION_KEYS}


# ---------------------------------------------------------------------------- measurements
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def best_time(fn, repeats: int, rounds: int, clock=time.perf_counter) -> float:
    """Best (over ``rounds``) mean seconds per call of ``fn`` over ``repeats`` calls."""
    fn()
    best = float("inf")
    for _ in range(rounds):
        t0 = clock()
        for _ in range(repeats):
            fn()
        best = min(best, (clock() - t0) / repeats)
    return best


def measure_to_pyg(args: Args) -> dict[str, dict[str, float]]:
    """Seconds per batch conversion: ``{"full"|"mixed": {"vectorised": s, "per-graph": s}}``."""
    from agents.nn.graph import to_pyg, to_pyg_per_graph

    trees = [grow("maze2d", args.nodes, i, args.seed, max_nodes=args.nodes) for i in range(args.trees)]
    clock = CLOCKS[args.clock]
    rng = np.random.default_rng(args.seed)
    full = [trees[i % len(trees)] for i in range(args.batch)]
    mixed = [cut(o, int(rng.integers((args.nodes + 1) // 2, args.nodes + 1))) for o in full]
    out: dict[str, dict[str, float]] = {}
    for name, batch in (("full", stack(full)), ("mixed", stack(mixed))):
        def convert(fn, batch=batch):
            return lambda: fn(batch)
        out[name] = {"vectorised": best_time(convert(to_pyg), args.conversions, args.rounds, clock)}
        if args.reference:
            out[name]["per-graph"] = best_time(convert(to_pyg_per_graph), max(1, args.conversions // 10),
                                               args.rounds, clock)
    return out


def time_act(sampler, obs: dict[str, np.ndarray], args: Args) -> float:
    """Best (over ``--rounds``) mean seconds per ``sampler.act`` call while the tree grows by one
    node per call through its last ``--window`` nodes, as in a planning loop: samplers that
    cache per node (the learned ones) pay for each new node, not only for the query."""
    n = int(obs["num_nodes"][0])
    window = max(1, min(args.window, n - 2))
    prefixes = [cut(obs, n - window + k + 1) for k in range(window)]
    warm = cut(obs, n - window)
    clock = CLOCKS[args.clock]
    best = float("inf")
    for _ in range(args.rounds):
        sampler.reset(args.seed)
        sampler.act(warm)                      # the tree so far (untimed)
        t0 = clock()
        for p in prefixes:
            sampler.act(p)
        best = min(best, (clock() - t0) / window)
    return best
def measure_act(args: Args, samplers: list[str]) -> dict[tuple[str, str], float | None]:
    """Seconds per ``act()`` call for each (sampler, task); None where a sampler rejects the task."""
    from agents.samplers import load_sampler

    checkpoints = args.checkpoints
    out: dict[tuple[str, str], float | None] = {}
    for task in args.tasks:
        try:
            obs = grow(task, args.act_nodes, 0, args.seed, max_nodes=args.act_nodes)
        except RuntimeError as exc:
            print(f"act(): skipping {task}: {exc}", file=sys.stderr)
            out.update({(name, task): None for name in samplers})
            continue
        space = gym.make(task_spec(task).env_id).action_space
        for name in samplers:
            kwargs = {"checkpoint": checkpoints[name]} if name in checkpoints else {}
            try:
                sampler = load_sampler(name, task=task, seed=args.seed, **kwargs)
            except (ValueError, FileNotFoundError):   # not for this task, or no weights shipped for it
                out[name, task] = None
                continue
            out[name, task] = time_act(sampler, obs, args)
    return out


# ---------------------------------------------------------------------------- report
def report_to_pyg(args: Args, result: dict[str, dict[str, float]]) -> None:
    print(f"to_pyg: {args.batch} maze2d observations x {args.nodes} nodes ({args.trees} distinct trees), "
          f"torch threads {torch.get_num_threads()}, {args.clock} clock, best of {args.rounds}")
    for name, times in result.items():
        line = f"  {name + ' trees' if name == 'full' else 'mixed sizes':<12}"
        vec = times["vectorised"]
        line += f" vectorised {vec * 1e3:7.2f} ms/batch {args.batch / vec:>10,.0f} obs/s"
        if "per-graph" in times:
            ref = times["per-graph"]
            line += f" | per-graph reference {ref * 1e3:7.2f} ms/batch {args.batch / ref:>8,.0f} obs/s" \
                    f" | {ref / vec:5.1f}x"
        print(line)


def report_act(args: Args, samplers: list[str], result: dict[tuple[str, str], float | None]) -> None:
    print(f"act(): microseconds per call on a tree growing to {args.act_nodes} nodes (one node per call, last "
          f"{args.window}), {args.clock} clock, best of {args.rounds}")
    width = max(len(s) for s in samplers + ["sampler"])
    print(f"  {'sampler':<{width}} " + " ".join(f"{t:>10}" for t in args.tasks))
    for name in samplers:
        cells = [result[name, t] for t in args.tasks]
        print(f"  {name:<{width}} " + " ".join(f"{'n/a':>10}" if c is None else f"{c * 1e6:>10.1f}" for c in cells))


def run(args: Args) -> dict:
    """Both measurements (as configured); returns the raw seconds."""
    from agents.samplers import available_samplers

    torch.set_num_threads(args.threads)
    results: dict = {}
    if not args.skip_to_pyg:
        results["to_pyg"] = measure_to_pyg(args)
        report_to_pyg(args, results["to_pyg"])
    if not args.skip_act:
        samplers = list(args.samplers) or available_samplers()
        results["act"] = measure_act(args, samplers)
        report_act(args, samplers, results["act"])
    return results


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m tools.bench_sampler", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    from agents.samplers import available_samplers

    try:
        import_modules(args.modules)
    except ValueError as exc:
        parser.error(str(exc))
    unknown = [t for t in args.tasks if t not in TASK_SPECS]
    if unknown:
        parser.error(f"unknown task(s) {unknown}; known: {sorted(TASK_SPECS)}")
    unknown = [s for s in args.samplers if s not in available_samplers()]
    if unknown:
        parser.error(f"unknown sampler(s) {unknown}; known: {', '.join(available_samplers())}")
    for name, path in args.checkpoints.items():
        if not Path(path).exists():
            parser.error(f"checkpoint of {name}: {path} does not exist")
    run(args)
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
