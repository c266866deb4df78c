"""``gnn-mp train sampler``: the offline part of Algorithm 1 plus DAgger, read top to bottom.

1. Solve ``--problems`` seeded training problems with the uniform sampler (cached dataset).
2. Train the model on snapshots of those trees (``--view grown``, the remedy; ``prefix`` is
   the paper's path-prefix graphs), ``--minutes`` of Adam with a cosine schedule; the
   held-out tenth of the problems is the validation loss; the best epoch is kept.
3. ``--dagger-rounds`` times: plan fresh training problems with the current sampler, label
   its own trees with the paths it found, and fine-tune on everything.
4. Plan ``--eval-problems`` validation problems with the sampler and with uniform (the same
   problems and seeds) and report both; save the checkpoint (sampling settings and config in
   its meta, the config beside it as JSON), TensorBoard events and a learning-curve figure.

Everything goes to a run directory (:class:`train.run.TrainingRun`:
``runs/tree/<task>-<model>-seed<S>-<time>/`` with ``config.json``, ``model.pt`` + ``model.json``,
``tb/``, ``learning_curve.png``, ``resume.pt``); ``--ship`` copies the checkpoint into the
package (``agents/checkpoints/<model>_<task>.pt`` + ``.json``). Tasks registered outside the
package train too: ``--import MODULE`` imports the module that calls ``register_task``.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from agents.checkpoints import load_training_state, save_checkpoint, save_training_state
from train.args import UsageError
from train.run import RunError, TrainingRun, finite_loss, plot_learning_curve
from train.tree.adapters import adapter_for, task_scales
from train.tree.args import TrainArgs
from train.tree.data import VIEWS, TreeDataConfig, TreeDataset, load_or_generate
from train.tree.items import Symmetry, symmetries_of, transformed
from train.workers import SharedPool


class TrainError(UsageError):
    """A training request that cannot be carried out (one line)."""


# ---------------------------------------------------------------------------- one phase
def fit(model: torch.nn.Module, adapter, train_items: list, val_items: list, minutes: float, lr: float,
        batch_size: int, seed: int, writer, phase: str, progress: bool,
        resume: dict | None = None, resume_path: Path | None = None,
        resume_config: dict[str, Any] | None = None, augment: list[Symmetry] | None = None) -> dict[str, Any]:
    """Adam on ``train_items`` for ``minutes``; returns the history and leaves the best
    validation epoch's weights in ``model``. ``resume_path``: the state after every epoch, with
    ``resume_config`` (what a resumed run must match, :func:`check_resume`). ``augment``: each
    training item of a batch is mapped by one of these symmetries, drawn per item (validation
    items never are)."""
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    history: list[dict[str, float]] = []
    best = (math.inf, None)
    epoch, elapsed = 0, 0.0
    if resume is not None:
        model.load_state_dict(resume["model"])
        opt.load_state_dict(resume["optimizer"])
        history, epoch, elapsed = list(resume["history"]), int(resume["epoch"]), float(resume["elapsed"])
        best = (float(resume["best_loss"]), resume["best_state"])
    gen = torch.Generator().manual_seed(seed)
    budget = 60.0 * minutes
    bar = tqdm(total=round(budget), desc=f"{phase}", unit="s", disable=not progress, file=sys.stderr,
               initial=min(round(elapsed), round(budget)))
    t0 = time.perf_counter() - elapsed
    while time.perf_counter() - t0 < budget:
        order = np.random.default_rng([seed, epoch]).permutation(len(train_items))
        pick = np.random.default_rng([seed, epoch, 1])
        model.train()
        losses = []
        for k in range(0, len(order), batch_size):
            frac = (time.perf_counter() - t0) / budget
            if frac >= 1:
                break
            for group in opt.param_groups:
                group["lr"] = lr * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0)))
            batch = [train_items[i] for i in order[k:k + batch_size]]
            if augment:
                batch = [transformed(item, augment[int(pick.integers(len(augment)))]) for item in batch]
            loss, _, _ = adapter.loss(model, batch, gen)
            value = finite_loss(loss, f"{phase} epoch {epoch + 1}", lr)
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            losses.append(value)
            bar.n = min(round(time.perf_counter() - t0), round(budget))
            bar.refresh()
        val = evaluate_loss(model, adapter, val_items)
        epoch += 1
        row = {"epoch": epoch, "seconds": time.perf_counter() - t0, "train": float(np.mean(losses)) if losses else math.nan,
               "val": val}
        history.append(row)
        if writer is not None:
            writer.add_scalar(f"{phase}/train_loss", row["train"], epoch)
            writer.add_scalar(f"{phase}/val_loss", val, epoch)
        if val < best[0]:
            best = (val, {k: v.detach().clone() for k, v in model.state_dict().items()})
        bar.set_postfix(train=f"{row['train']:.3f}", val=f"{val:.3f}")
        if resume_path is not None:
            save_training_state(resume_path, {"model": model.state_dict(), "optimizer": opt.state_dict(),
                                              "history": history, "epoch": epoch, "elapsed": time.perf_counter() - t0,
                                              "best_loss": best[0], "best_state": best[1],
                                              "config": resume_config})
    bar.close()
    if best[1] is not None:
        model.load_state_dict(best[1])
    return {"history": history, "best_val": best[0], "epochs": epoch}


@torch.no_grad()
def evaluate_loss(model: torch.nn.Module, adapter, items: list, batch_size: int = 16) -> float:
    model.eval()
    total, count = 0.0, 0
    gen = torch.Generator().manual_seed(0)
    for k in range(0, len(items), batch_size):
        loss, n, _ = adapter.loss(model, items[k:k + batch_size], gen)
        total, count = total + float(loss) * n, count + n
    return total / max(count, 1)


def split_problems(data: TreeDataset, seed: int) -> tuple[TreeDataset, TreeDataset]:
    """(training, validation) problems: a fixed tenth held out, at least one while at least one is left
    to train on (a DAgger round that solved one problem trains on it; one that solved none adds nothing)."""
    order = np.random.default_rng(seed).permutation(len(data))
    cut = max(1, len(data) // 10) if len(data) >= 2 else 0
    return data.subset(sorted(order[cut:].tolist())), data.subset(sorted(order[:cut].tolist()))


#: The flags a resumed first phase must share with the run that wrote the resume state (with the
#: model's kind and constructor arguments): its data, model, schedule and random streams.
RESUME_KEYS = ("task", "model", "problems", "scene", "augment", "view", "minutes", "batch_size", "lr", "max_snapshots",
               "seed")


def resume_config(args: TrainArgs, kind: str, ctor_args: dict[str, Any]) -> dict[str, Any]:
    """What :func:`fit` stores with its resume state (plain JSON values)."""
    import json
    from agents.checkpoints import plain
    config = {**{key: getattr(args, key) for key in RESUME_KEYS}, "kind": kind, "ctor_args": ctor_args}
    return json.loads(json.dumps(plain(config, "resume config")))


def check_resume(path: Path, stored: Any, config: dict[str, Any]) -> None:
    """Refuse, in one line, a resume state written by another run (another model, task, data,
    learning rate, batch size, seed, ...): its weights would not load, or the run would go on
    with other settings than it began with, without a word."""
    if not isinstance(stored, dict):
        raise TrainError(f"--resume: {path} holds no run configuration (written by another command or an older "
                         "version); start a new run")
    for key, value in config.items():
        if stored.get(key) != value:
            raise TrainError(f"--resume: {path} is the state of another run ({key} {stored.get(key)!r} there, "
                             f"{value!r} here); resume with that run's flags or start a new --out")


# ---------------------------------------------------------------------------- the whole job
def train(args: TrainArgs) -> dict[str, Any]:
    """Data, training, DAgger, evaluation, checkpoint; returns the run's summary."""
    from gnn_mp_envs.registration import task_spec
    from train.args import import_modules
    try:
        import_modules(args.modules)
        spec = task_spec(args.task)
    except ValueError as exc:
        raise TrainError(str(exc)) from None
    scene = args.scene if args.scene is not None else spec.training_scene()
    if scene is not None and scene not in spec.scenes:
        raise TrainError(f"unknown scene {scene!r} for task {args.task}; known: {', '.join(spec.scenes) or 'none'}")
    if scene in spec.ood_scenes:
        raise TrainError(f"scene {scene!r} is an out-of-distribution test scene of {args.task}: it is never "
                         f"trained on (training scenes: "
                         f"{', '.join(s for s in spec.scenes if s not in spec.ood_scenes + spec.validation_scenes)})")
    if scene in spec.validation_scenes:
        raise TrainError(f"scene {scene!r} is a validation scene of {args.task} (held out from training, for "
                         "decisions)")
    if args.augment and not spec.symmetries:
        raise TrainError(f"--augment: task {args.task} declares no symmetries (TaskSpec.symmetries)")
    try:
        run = TrainingRun.create("tree", f"{args.task}-{args.model}", args.seed, out=args.out, resume=args.resume,
                                 overwrite=args.overwrite)
    except (ValueError, RunError) as exc:
        raise TrainError(str(exc)) from None
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    adapter = adapter_for(args.model, args.task)
    scales = task_scales(args.task)
    if args.relative_inputs and adapter.kind not in ("tree/gnn", "tree/gnn-cvae"):
        raise TrainError(f"--relative-inputs applies to the node-mixture gnn and gnn-cvae, not {adapter.kind}")
    try:
        overrides = ({"relative_inputs": True} if args.relative_inputs else {}) | \
            ({"hidden_channels": args.hidden} if args.hidden is not None else {})
        model, ctor_args = adapter.build(scales, **overrides)
    except ValueError as exc:
        raise TrainError(f"--model {args.model} on task {args.task}: {exc}") from None
    started = time.perf_counter()
    resume_path = run.path("resume.pt")      # checked before the data: a refusal costs nothing
    if args.resume and not resume_path.exists():
        raise TrainError(f"--resume: {resume_path} does not exist")
    config = resume_config(args, adapter.kind, ctor_args)
    resume = load_training_state(resume_path) if args.resume else None
    if resume is not None:
        check_resume(resume_path, resume.get("config"), config)

    # 1. data: uniform solutions of training problems
    data_config = TreeDataConfig(task=args.task, split="train", scene=scene, problems=args.problems, seed=args.seed)
    # one set of workers (processes or Ray actors) for the data and every DAgger round's planning
    with SharedPool(args.workers, args.ray, args.modules) as pool:
        data = load_or_generate(data_config, args.data_dir, progress=args.progress, pool=pool)
        rng = np.random.default_rng(args.seed)
        snapshots = args.max_snapshots
        if len(data) < 2:
            raise TrainError(f"only {len(data)} solved problem(s) in {data_config.file_name()}; raise --problems")
        train_data, val_data = split_problems(data, args.seed)
        train_items = adapter.items(model, train_data, args.view, rng, snapshots)
        val_items = adapter.items(model, val_data, args.view, rng, snapshots)

        summary: dict[str, Any] = {"config": asdict(args), "dataset": data_config.file_name(),
                                   "dataset_problems_solved": len(data), "items": len(train_items) + len(val_items)}
        augment = None
        if args.augment:
            low, high = spec.state_bounds()
            augment = symmetries_of(spec.symmetries, low, high, torch.as_tensor(spec.periodic_mask(len(low))))
        # 2. the first phase
        phases = [fit(model, adapter, train_items, val_items, args.minutes, args.lr, args.batch_size, args.seed,
                      run.writer, "phase0", args.progress, resume=resume, resume_path=resume_path, resume_config=config,
                      augment=augment)]
        # 3. DAgger
        settings = spec.sampler_defaults(args.model)
        for r in range(args.dagger_rounds):
            own_train, own_val = split_problems(plan_with(model, ctor_args, adapter, args, settings, round_index=r,
                                                          scene=scene, pool=pool), args.seed + r + 1)
            train_items += adapter.items(model, own_train, "grown", rng, snapshots)
            val_items += adapter.items(model, own_val, "grown", rng, snapshots)
            phases.append(fit(model, adapter, train_items, val_items, args.dagger_minutes, args.lr / 2,
                              args.batch_size, args.seed + r + 1, run.writer, f"dagger{r + 1}", args.progress,
                              augment=augment))
    summary["phases"] = phases
    # a resumed run counts the first phase's time spent before the interruption too
    summary["train_seconds"] = time.perf_counter() - started + (float(resume["elapsed"]) if resume else 0.0)
    # The train/online mismatch: the loss on both views of the held-out problems (online the
    # sampler sees grown trees, whichever view it was trained on).
    summary["validation_loss_by_view"] = {
        view: evaluate_loss(model, adapter, adapter.items(model, val_data, view, np.random.default_rng(1), snapshots))
        for view in VIEWS}

    # 4. save, evaluate, ship
    meta = {"task": args.task, "sampler": settings, "command": command_of(args), "config": summary["config"],
            "dataset": summary["dataset"], "train_seconds": summary["train_seconds"]}
    ckpt = run.save_checkpoint("model.pt", model, adapter.kind, ctor_args, meta=meta)
    if args.eval_problems:
        summary["validation"] = evaluate_online(args.task, ckpt, args.model, args.eval_problems, args.seed,
                                                args.progress)
        for name, stats in summary["validation"].items():
            run.writer.add_scalar(f"validation/{name}_median_nodes", stats["median_nodes"], 0)
        if spec.validation_scenes:
            summary["validation_kinds"] = {
                kind: evaluate_online(args.task, ckpt, args.model, min(args.eval_problems, KIND_EVAL_PROBLEMS),
                                      args.seed, args.progress, scene=kind)
                for kind in spec.validation_scenes}
        ckpt = run.save_checkpoint("model.pt", model, adapter.kind, ctor_args,
                                   meta={**meta, "validation": summary["validation"],
                                         "validation_kinds": summary.get("validation_kinds")})
    run.close()
    plot_phases(phases, run.path("learning_curve.png"), f"{args.task} {args.model}",
                getattr(adapter, "loss_name", "NLL per snapshot"))
    run.write_config(summary)
    if args.ship:
        summary["shipped"] = str(run.ship(ckpt, args.model, args.task, expected_kind=adapter.kind))
    summary["run_dir"] = str(run.dir)
    summary["checkpoint"] = str(ckpt)
    return summary


def command_of(args: TrainArgs) -> str:
    """The command line that reproduces the run (what a shipped sidecar records)."""
    imports = "".join(f" --import {m}" for m in args.modules)
    extra = ((f" --scene {args.scene}" if args.scene is not None else "") + (" --augment" if args.augment else "")
             + (" --relative-inputs" if args.relative_inputs else "")
             + (f" --hidden {args.hidden}" if args.hidden is not None else ""))
    return (f"gnn-mp train sampler{imports} --task {args.task}{extra} --model {args.model} --problems {args.problems} "
            f"--view {args.view} --minutes {args.minutes} --dagger-rounds {args.dagger_rounds} --dagger-problems "
            f"{args.dagger_problems} --dagger-minutes {args.dagger_minutes} --eval-problems {args.eval_problems} "
            f"--seed {args.seed}")


def plan_with(model, ctor_args, adapter, args: TrainArgs, settings: dict, round_index: int,
              scene: str | None = None, pool: SharedPool | None = None) -> TreeDataset:
    """DAgger data: fresh training problems (of ``scene``) planned by the current sampler (on the run's
    ``pool``, else as ``args`` say), labelled by the paths it found itself."""
    import tempfile

    from train.tree.data import generate
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = save_checkpoint(Path(tmp) / "current.pt", model, adapter.kind, ctor_args,
                               meta={"task": args.task, "sampler": settings})
        config = TreeDataConfig(task=args.task, split="train", scene=scene,
                                problems=args.dagger_problems, seed=args.seed + 1000 * (round_index + 1),
                                first_problem=args.problems + round_index * args.dagger_problems, sampler=args.model)
        return generate(config, progress=args.progress, checkpoint=str(ckpt), workers=args.workers, ray=args.ray,
                        pool=pool)


#: Validation problems per held-out kind (``TaskSpec.validation_scenes``) at the end of training.
KIND_EVAL_PROBLEMS = 20


def evaluate_online(task: str, checkpoint: Path, model: str, problems: int, seed: int,
                    progress: bool, scene: str | None = None) -> dict[str, dict[str, float]]:
    """Plan validation problems 0..N-1 (of ``scene``: default the split's own) with the trained
    sampler and with uniform (same seeds)."""
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problems, summarize
    env = evaluation_env(task, "val", scene=scene)
    problems = min(problems, env.task.num_problems("val") or problems)   # a fixed problem set (MBM) may hold fewer
    try:
        out = {}
        for name, extra in (("uniform", {}), (model, {"checkpoint": checkpoint})):
            sampler = load_sampler(name, task=task, seed=0, **extra)
            out[name] = summarize(plan_problems(sampler, env, range(problems), seed, progress=progress,
                                                desc=f"val {scene or ''} {name}"))
        return out
    finally:
        env.close()


def plot_phases(phases: list[dict], path: Path, title: str, loss_name: str = "NLL per snapshot") -> Path | None:
    """Train and validation loss against training time, the DAgger rounds dotted."""
    train_x, train_y, val_y, bounds, offset = [], [], [], [], 0.0
    for k, phase in enumerate(phases):
        h = phase["history"]
        if not h:
            continue
        if k:
            bounds.append(offset)
        t = [offset + r["seconds"] / 60 for r in h]
        train_x += t
        train_y += [r["train"] for r in h]
        val_y += [r["val"] for r in h]
        offset = t[-1]
    return plot_learning_curve(path, {"train": (train_x, train_y), "validation": (train_x, val_y)},
                               xlabel="training time [min] (dotted: DAgger rounds)", ylabel=f"loss ({loss_name})",
                               title=title, vlines=bounds)


__all__ = ["TrainArgs", "TrainError", "evaluate_online", "fit", "plot_phases", "train"]
