"""The training loop: best-validation checkpoint, per-epoch resume state, run directories.

Where a run writes (:func:`run_paths`):

* default: a fresh run directory ``runs/critical/<model>-seed<S>-<YYYYmmdd-HHMMSS>/`` with
  ``critical_<model>.pt`` (best-validation weights), ``critical_<model>.json`` (the flags,
  hyper-parameters, dataset config, per-epoch history; written before the first epoch),
  ``critical_<model>.resume.pt`` (optimizer, epoch, history; after every epoch) and
  TensorBoard events in ``tb/critical_<model>/`` (``train/loss`` and ``train/lr`` per step, the
  validation scores per epoch: ``tensorboard --logdir runs/critical``);
* ``--out FILE``: the same files named after ``FILE`` (events in ``tb/<stem>/`` beside it);
* ``--resume``: continues the run of ``--out``, or the latest run of the model and seed;
* ``--ship``: when done, the checkpoint and its ``.json`` are also copied into
  ``agents/checkpoints/`` (the shipped weights). Nothing else writes into the package.

Everything is written atomically and read back with ``torch.load(weights_only=True)``
(:mod:`agents.checkpoints`). Shuffles derive from ``[seed, epoch]``, so a resumed run sees
the same batches as an uninterrupted one.

The best epoch is the one with the highest validation hit rate (mean over k = 1, 3, 10,
:data:`SELECT_ON`); the history also records the point accuracy, wall and CPU seconds.
``--max-steps`` bounds the optimizer steps, so runs of several seeds do the same work
whatever the machine's load (a wall-clock ``--time-budget`` does not).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from agents.checkpoints import (CheckpointError, count_parameters, load_checkpoint, load_training_state, plain,
                                save_checkpoint, save_training_state)
from agents.critical.models import MODELS, build_model, kind_of
from gnn_mp_envs.critical.dataset import DatasetConfig, check_has_split, load_or_generate
from gnn_mp_envs.critical.halton import halton_graph
from gnn_mp_envs.utils.io import atomic_write_text
from train.args import UsageError
from train.critical.args import CHECKPOINT_DIR, RUNS_DIR, VAL_PROBLEMS, Optim, TrainArgs, checkpoint_name
from train.critical.data import inputs_for
from train.critical.evaluation import validation_scores
from train.critical.losses import loss as loss_fn
from train.run import finite_loss, inside


#: Validation metric that picks the best epoch: the mean hit rate of the k = 1, 3, 10 samples
#: on the validation problems (``evaluate.validation_scores``).
SELECT_ON = "val_score"


class TrainError(UsageError, ValueError):
    """A training request that cannot be carried out (one line)."""


@dataclass(frozen=True)
class RunPaths:
    """The files of one training run."""

    checkpoint: Path   # best-validation weights (agents.checkpoints format)
    meta: Path         # .json: flags, hyper-parameters, dataset, history
    resume: Path       # resume state after the last finished epoch
    tb: Path           # TensorBoard events: tb/<checkpoint stem>/ beside the checkpoint


def paths_for(checkpoint: Path) -> RunPaths:
    checkpoint = Path(checkpoint)
    return RunPaths(checkpoint, checkpoint.with_suffix(".json"),
                    checkpoint.with_name(checkpoint.stem + ".resume.pt"), checkpoint.parent / "tb" / checkpoint.stem)


def run_paths(args: TrainArgs, runs_dir: Path = RUNS_DIR, now: float | None = None) -> RunPaths:
    """Where ``args`` trains to (see the module docstring)."""
    name = checkpoint_name(args.model)
    if args.out is not None:
        if inside(Path(args.out), CHECKPOINT_DIR):
            raise TrainError(f"--out {args.out} is inside the shipped checkpoint directory {CHECKPOINT_DIR}; "
                             "train elsewhere and pass --ship to copy the result there")
        return paths_for(Path(args.out))
    prefix = f"{args.model}-seed{args.seed}-"
    if args.resume:
        runs = sorted(d for d in Path(runs_dir).glob(prefix + "*") if paths_for(d / name).resume.exists())
        if not runs:
            raise TrainError(f"--resume: no run of {args.model} with seed {args.seed} under {runs_dir} "
                             "has a resume state; pass --out to name the checkpoint of the run")
        return paths_for(runs[-1] / name)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    run, k = Path(runs_dir) / (prefix + stamp), 1
    while run.exists():
        k += 1
        run = Path(runs_dir) / f"{prefix}{stamp}-{k}"
    return paths_for(run / name)


def _hparams(ctor: dict, optim: Optim, args: TrainArgs) -> dict[str, Any]:
    return {"model": ctor, **asdict(optim), "time_budget_min": args.time_budget,
            "max_steps": args.max_steps, "max_train_problems": args.max_train_problems}


def _write_meta(path: Path, meta: dict) -> None:
    atomic_write_text(path, json.dumps(plain(meta, "meta"), indent=2))


def train(args: TrainArgs, dataset: DatasetConfig | None = None, progress: bool = True,
          runs_dir: Path = RUNS_DIR) -> dict[str, Any]:
    """Train ``args.model``; keeps the best-validation weights (see :func:`run_paths`).

    ``dataset`` defaults to ``args.dataset()``. Returns the checkpoint path, the best epoch
    and the history.
    """
    if args.model not in MODELS:
        raise TrainError(f"unknown model {args.model!r}; known: {', '.join(sorted(MODELS))}")
    try:
        ctor, optim = args.resolve()
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    cfg = dataset or args.dataset()
    try:
        check_has_split(cfg, "val", "train selects its weights on the validation problems")
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    paths = run_paths(args, runs_dir)
    name, kind = args.model, kind_of(args.model)
    hp = _hparams(ctor, optim, args)
    meta = {"model": name, "kind": kind, "hparams": hp, "seed": args.seed, "dataset": asdict(cfg),
            "args": asdict(args), "best": None, "history": [], "train_wall_seconds": 0.0}

    torch.manual_seed(args.seed)
    model = build_model(name, **ctor)
    opt = torch.optim.Adam(model.parameters(), lr=optim.lr)
    start_epoch, history, best, best_state, wall = 0, [], {SELECT_ON: -math.inf, "epoch": -1}, None, 0.0
    cpu, done_steps = 0.0, 0
    if args.resume:
        state = _load_resume(paths.resume, kind, ctor, args.seed, cfg)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start_epoch, history, best, wall = state["epoch"], state["history"], state["best"], state["wall"]
        best_state = state["best_state"]
        cpu = state.get("cpu", 0.0)
        done_steps = sum(h["steps"] for h in history)
        print(f"[{name}] resuming {paths.resume} after epoch {start_epoch}", flush=True)
    elif paths.checkpoint.exists():
        raise TrainError(f"{paths.checkpoint} exists; pass --resume to continue that run or choose another --out")
    _write_meta(paths.meta, {**meta, "best": best if history else None, "history": history})

    graph = halton_graph(cfg.graph_nodes)
    labelled = load_or_generate(cfg, args.data, "labelled", progress)
    train_set, val_set = labelled.split_subset("train"), labelled.split_subset("val")
    if args.max_train_problems is not None and args.max_train_problems < len(train_set):
        train_set = train_set.subset(np.arange(args.max_train_problems))
    val_set = val_set.subset(np.arange(min(VAL_PROBLEMS, len(val_set))))
    inputs = inputs_for(model, name, train_set, graph)

    from torch.utils.tensorboard import SummaryWriter
    writer = SummaryWriter(str(paths.tb), purge_step=done_steps if args.resume else None)   # resumed: drop later events
    gen = torch.Generator().manual_seed(args.seed)
    budget_s = None if args.time_budget is None else 60.0 * args.time_budget
    t_start, c_start = time.perf_counter() - wall, time.process_time() - cpu
    steps_per_epoch = math.ceil(len(train_set) / optim.batch_size)
    total_steps = optim.epochs * steps_per_epoch if args.max_steps is None else min(
        args.max_steps, optim.epochs * steps_per_epoch)
    for epoch in range(start_epoch, optim.epochs):
        if done_steps >= total_steps:
            break
        model.train()
        order = np.random.default_rng([args.seed, epoch]).permutation(len(train_set))
        gen.manual_seed(args.seed * 100003 + epoch)
        losses = []
        bar = tqdm(range(steps_per_epoch), desc=f"{name} epoch {epoch + 1}/{optim.epochs}", disable=not progress)
        out_of_time = False
        for step in bar:
            idx = order[step * optim.batch_size:(step + 1) * optim.batch_size]
            if optim.cosine:
                # learning rate on a cosine over the wall-clock budget, else over the planned
                # steps (anneals to 5% of lr)
                frac = (min(1.0, (time.perf_counter() - t_start) / budget_s) if budget_s is not None
                        else done_steps / total_steps)
                for group in opt.param_groups:
                    group["lr"] = optim.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * frac)))
            loss = loss_fn(model, name, inputs(idx), optim, gen)
            value = finite_loss(loss, f"{name} epoch {epoch + 1}, step {step}", optim.lr)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(value)
            done_steps += 1
            writer.add_scalar("train/loss", value, done_steps)
            writer.add_scalar("train/lr", opt.param_groups[0]["lr"], done_steps)
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
            if budget_s is not None and time.perf_counter() - t_start > budget_s:
                out_of_time = True
                break
            if done_steps >= total_steps:
                break
        train_cpu = time.process_time() - c_start
        val = validation_scores(model, name, val_set, graph, seed=args.seed)
        wall, cpu = time.perf_counter() - t_start, time.process_time() - c_start
        history.append({"epoch": epoch + 1, "train_loss": float(np.mean(losses)), **val,
                        "steps": len(losses), "wall_seconds": wall, "cpu_seconds": cpu,
                        "train_cpu_seconds": train_cpu})
        writer.add_scalar("epoch/train_loss", history[-1]["train_loss"], done_steps)
        for key, score in val.items():
            writer.add_scalar(f"val/{key}", score, done_steps)
        writer.flush()
        print(f"[{name}] epoch {epoch + 1}: loss {np.mean(losses):.4f}  val accuracy {val['val_accuracy']:.4f}  "
              + "  ".join(f"{k[4:]} {v:.3f}" for k, v in val.items() if k.startswith("val_hit"))
              + f"  ({wall / 60:.1f} min, {cpu / 60:.1f} CPU min)", flush=True)
        if val[SELECT_ON] > best[SELECT_ON]:
            best = {SELECT_ON: val[SELECT_ON], "val_accuracy": val["val_accuracy"], "epoch": epoch + 1}
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        save_training_state(paths.resume, {
            "kind": kind, "ctor_args": ctor, "seed": args.seed, "dataset": asdict(cfg),
            "model": model.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch + 1,
            "history": history, "best": best, "best_state": best_state, "wall": wall, "cpu": cpu})
        meta.update(best=best, history=history, train_wall_seconds=wall, train_cpu_seconds=cpu)
        if best_state is not None:
            meta["parameters"] = count_parameters(best_state)
            save_checkpoint(paths.checkpoint, best_state, kind, ctor, meta=plain(meta, "meta"))
        _write_meta(paths.meta, meta)
        if out_of_time:
            print(f"[{name}] time budget reached", flush=True)
            break
    writer.close()
    result = {"checkpoint": str(paths.checkpoint), "best": best, "history": history}
    if args.ship:
        result["shipped"] = str(ship(paths, name))
    return result


def _load_resume(path: Path, kind: str, ctor: dict, seed: int, cfg: DatasetConfig) -> dict:
    if not path.exists():
        raise TrainError(f"--resume: no resume state at {path}")
    state = load_training_state(path)
    want = {"kind": kind, "ctor_args": ctor, "seed": seed, "dataset": asdict(cfg)}
    for key, value in want.items():
        have = state.get(key)
        if key == "dataset" and isinstance(have, dict):   # tuples come back as tuples, json-like lists differ
            have, value = json.loads(json.dumps(have)), json.loads(json.dumps(value))
        if have != value:
            raise CheckpointError(f"{path}: resume state of another run ({key} {have!r}, this run {value!r})")
    return state


def ship(paths: RunPaths, model: str) -> Path:
    """Copy a run's checkpoint and ``.json`` into the shipped directory as ``critical_<model>.pt``
    (:meth:`train.run.TrainingRun.ship`)."""
    from train.run import RunError, TrainingRun
    try:
        return TrainingRun(paths.checkpoint.parent).ship(paths.checkpoint, f"critical_{model}",
                                                          expected_kind=kind_of(model))
    except RunError as exc:
        raise TrainError(str(exc)) from None
