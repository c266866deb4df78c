"""Critical samples: data generation, training and evaluation of GNN/GAT/GNN-CVAE/CNN/CVAE.

Entry point ``main(argv)`` with three sub-commands::

    python -m train.critical generate-data [--data DIR] [--seed S]
    python -m train.critical train --model gnn|gat|gnn-cvae|cnn|cvae [--epochs N] [--seed S]
                                   [--data DIR] [--resume] [--out FILE] [--time-budget MIN]
    python -m train.critical evaluate [--json FILE] [--plot FILE] [--problems N]

Accuracy is the paper's ``1 - MSE`` between prediction and ground truth; with several
bottleneck labels per problem the error is to the nearest label, and MSE averages the
squared error over the two coordinates. CVAEs are scored on the mean of ``k`` decoded
samples and on the best of the ``k`` samples.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from agents.critical_data import graph_batch, image_batch, label_positions, occupancy_images
from agents.models.critical import (MODELS, NODE_FEATURES, NODE_FEATURES_WITH_POSITION,
                                    build_model)
from gnn_mp_envs.critical.dataset import CriticalProblems, DatasetConfig, generate_all, load_or_generate
from gnn_mp_envs.critical.halton import HaltonGraph, halton_graph
from gnn_mp_envs.critical.planning import compare_planners, path_is_valid, summarize

#: Where cached datasets and resume states go (git-ignored).
DEFAULT_DATA_DIR = Path("data/critical")
#: Shipped checkpoints.
CHECKPOINT_DIR = Path(__file__).resolve().parent.parent / "agents" / "checkpoints"
#: Per-model defaults: architecture kwargs and optimisation settings.
HPARAMS: dict[str, dict[str, Any]] = {
    "gnn": {"model": {"in_channels": 7, "hidden_channels": 32, "num_layers": 3, "K": 3,
                      "readout": "attention", "edges": "all"},
            "lr": 3e-3, "batch_size": 16, "epochs": 3, "node_loss_weight": 0.05},
    "gat": {"model": {"in_channels": 7, "hidden_channels": 32, "num_layers": 3, "heads": 1,
                      "readout": "attention", "edges": "all"},
            "lr": 3e-3, "batch_size": 16, "epochs": 2, "node_loss_weight": 0.05},
    "gnn-cvae": {"model": {"in_channels": 7, "hidden_channels": 32, "num_layers": 3, "K": 3,
                           "latent_channels": 2, "readout": "attention", "edges": "all"},
                 "lr": 3e-3, "batch_size": 16, "epochs": 2, "kl_weight": 0.005,
                 "node_loss_weight": 0.05},
    "cnn": {"model": {"hidden_channels": 16, "num_layers": 4},
            "lr": 1e-3, "batch_size": 64, "epochs": 30},
    "cvae": {"model": {"hidden_channels": 16, "num_layers": 4, "latent_channels": 2},
             "lr": 1e-3, "batch_size": 64, "epochs": 30, "kl_weight": 0.005},
}
#: Problems of the validation split scored after each epoch (kept small for speed).
VAL_PROBLEMS = 200
#: Latent samples per problem when scoring CVAEs.
EVAL_SAMPLES = 16


# ----------------------------------------------------------------------------- inputs


class Inputs:
    """Turns problem indices into model inputs; caches occupancy images for the CNNs."""

    def __init__(self, problems: CriticalProblems, graph: HaltonGraph, kind: str,
                 with_position: bool = False, all_edges: bool = False) -> None:
        self.problems, self.graph, self.kind = problems, graph, kind
        self.with_position, self.all_edges = with_position, all_edges
        self.occupancy = occupancy_images(problems) if kind == "image" else None

    def __call__(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        if self.kind == "graph":
            b = graph_batch(self.problems, self.graph, idx, self.with_position, self.all_edges)
            n = self.graph.num_nodes
            ptr = self.problems.label_ptr
            lab = [self.problems.label_nodes[ptr[i]:ptr[i + 1]] + k * n for k, i in enumerate(idx)]
            return {"x": b.x, "edge_index": b.edge_index, "batch": b.batch, "pos": b.pos,
                    "y": b.y, "owner": b.y_batch, "size": len(idx),
                    "label_index": torch.from_numpy(np.concatenate(lab).astype(np.int64))}
        ys = [label_positions(self.problems, self.graph, int(i)) for i in idx]
        return {"image": image_batch(self.occupancy[idx], self.problems.start[idx], self.problems.goal[idx]),
                "y": torch.from_numpy(np.concatenate(ys).astype(np.float32)),
                "owner": torch.repeat_interleave(torch.arange(len(ys)), torch.tensor([len(v) for v in ys])),
                "size": len(idx)}


def _nearest_label_loss(pred: torch.Tensor, y: torch.Tensor, owner: torch.Tensor) -> torch.Tensor:
    """Mean over problems of the squared error to the nearest label (multi-label regression)."""
    se = ((pred[owner] - y) ** 2).sum(-1)
    best = torch.full((pred.shape[0],), float("inf")).scatter_reduce(0, owner, se, "amin")
    return best.mean()


def _one_label_each(y: torch.Tensor, owner: torch.Tensor, size: int, gen: torch.Generator,
                    return_index: bool = False):
    """One random label per problem (CVAE targets: the label distribution is the target)."""
    counts = torch.bincount(owner, minlength=size)
    start = torch.cumsum(counts, 0) - counts
    pick = start + (torch.rand(size, generator=gen) * counts).long().clamp(max=counts.max() - 1)
    pick = torch.minimum(pick, start + counts - 1)
    return (y[pick], pick) if return_index else y[pick]


def _label_log_likelihood(log_a: torch.Tensor, label_index: torch.Tensor, owner: torch.Tensor,
                          size: int) -> torch.Tensor:
    """Mean over problems of log(sum of attention on the problem's label nodes)."""
    la = log_a[label_index]
    m = la.detach().max()
    per = torch.zeros(size).index_add(0, owner, torch.exp(la - m))
    return (torch.log(per.clamp_min(1e-30)) + m).mean()


def uses_position(model: torch.nn.Module) -> bool:
    """Whether a graph model reads the 7 node features (``x_n`` appended) rather than 5."""
    return getattr(model, "in_channels", NODE_FEATURES) == NODE_FEATURES_WITH_POSITION


def graph_inputs_of(model: torch.nn.Module, problems: CriticalProblems, graph: HaltonGraph,
                    kind: str) -> "Inputs":
    """The input builder matching a model's feature width and edge mode."""
    if kind != "graph":
        return Inputs(problems, graph, kind)
    return Inputs(problems, graph, kind, uses_position(model), getattr(model, "edges", "valid") == "all")


def _loss(model: torch.nn.Module, name: str, inp: dict, hp: dict, gen: torch.Generator) -> torch.Tensor:
    kind, out = MODELS[name][1], MODELS[name][2]
    node_w = hp.get("node_loss_weight", 0.0) if getattr(model, "readout", "max") == "attention" else 0.0
    if out == "det":
        if kind == "graph" and node_w > 0:
            pred, log_a = model(inp["x"], inp["edge_index"], inp["batch"], inp["pos"], return_log_attention=True)
            return (_nearest_label_loss(pred, inp["y"], inp["owner"])
                    - node_w * _label_log_likelihood(log_a, inp["label_index"], inp["owner"], inp["size"]))
        pred = (model(inp["x"], inp["edge_index"], inp["batch"], inp["pos"]) if kind == "graph"
                else model(inp["image"]))
        return _nearest_label_loss(pred, inp["y"], inp["owner"])
    y, pick = _one_label_each(inp["y"], inp["owner"], inp["size"], gen, return_index=True)
    if kind == "graph":
        mu, logstd = model.encode(inp["x"], inp["edge_index"], y, inp["pos"], inp["batch"])
        z = model.reparametrize(mu, logstd, gen)
        if node_w > 0:
            y_hat, log_a = model.decode(z, inp["x"], inp["edge_index"], inp["batch"], inp["pos"],
                                        return_log_attention=True)
            ll = log_a[inp["label_index"][pick]].mean()
            return (model.recon_loss(y_hat, y) + hp["kl_weight"] * model.kl_loss(mu, logstd)
                    - node_w * ll)
        y_hat = model.decode(z, inp["x"], inp["edge_index"], inp["batch"], inp["pos"])
    else:
        mu, logstd = model.encode(inp["image"], y)
        y_hat = model.decode(model.reparametrize(mu, logstd, gen), inp["image"])
    return model.recon_loss(y_hat, y) + hp["kl_weight"] * model.kl_loss(mu, logstd)


# ----------------------------------------------------------------------------- prediction


@torch.no_grad()
def predict(model: torch.nn.Module, name: str, problems: CriticalProblems, graph: HaltonGraph,
            num_samples: int = EVAL_SAMPLES, seed: int = 0, batch_size: int = 16,
            progress: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Point predictions (P, 2) and, for CVAEs, decoded samples (P, k, 2).

    For CVAEs the point prediction is the mean of the ``k`` samples from N(0, I).
    """
    model.eval()
    kind, out = MODELS[name][1], MODELS[name][2]
    inputs = graph_inputs_of(model, problems, graph, kind)
    gen = torch.Generator().manual_seed(seed)
    points, samples = [], []
    for s in tqdm(range(0, len(problems), batch_size), desc=f"predict {name}", disable=not progress):
        inp = inputs(np.arange(s, min(s + batch_size, len(problems))))
        if out == "det":
            p = (model(inp["x"], inp["edge_index"], inp["batch"], inp["pos"]) if kind == "graph"
                 else model(inp["image"]))
            points.append(p.numpy())
        else:
            smp = (model.sample(inp["x"], inp["edge_index"], inp["batch"], num_samples, gen, inp["pos"])
                   if kind == "graph" else model.sample(inp["image"], num_samples, gen))
            samples.append(smp.numpy())
            points.append(smp.mean(1).numpy())
    return np.concatenate(points), (np.concatenate(samples) if samples else None)


def nearest_label_mse(pred: np.ndarray, problems: CriticalProblems, graph: HaltonGraph) -> np.ndarray:
    """Per problem: mean-over-coordinates squared error to the nearest label.

    ``pred`` (P, 2) or (P, k, 2); with samples the best (smallest) error over k is returned.
    """
    pred = pred[:, None, :] if pred.ndim == 2 else pred
    out = np.empty(len(problems))
    for i in range(len(problems)):
        lab = label_positions(problems, graph, i)
        err = ((pred[i][:, None, :] - lab[None]) ** 2).mean(-1)  # (k, L)
        out[i] = err.min()
    return out


def accuracy(pred: np.ndarray, problems: CriticalProblems, graph: HaltonGraph) -> float:
    """The paper's accuracy: 1 - MSE (to the nearest label), averaged over problems."""
    return float(1.0 - nearest_label_mse(pred, problems, graph).mean())


# ----------------------------------------------------------------------------- training


def _checkpoint_paths(name: str, out: str | Path | None, data_dir: Path) -> tuple[Path, Path, Path]:
    ckpt = Path(out) if out else CHECKPOINT_DIR / f"critical_{name}.pt"
    return ckpt, ckpt.with_suffix(".json"), data_dir / f"resume_{name}.pt"


def train(model_name: str, data_dir: str | Path = DEFAULT_DATA_DIR, epochs: int | None = None,
          seed: int = 0, out: str | Path | None = None, resume: bool = False,
          time_budget_min: float | None = None, max_train_problems: int | None = None,
          dataset: DatasetConfig | None = None, progress: bool = True, lr: float | None = None,
          batch_size: int | None = None, model_overrides: dict[str, Any] | None = None,
          hp_overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train one model; keeps the best-validation weights in ``out`` (+ a json of metadata).

    ``lr``, ``batch_size`` and ``model_overrides`` (constructor kwargs, e.g.
    ``{"readout": "max", "in_channels": 5}``) override :data:`HPARAMS`.

    Resume state (optimizer, epoch, RNG-free since shuffles derive from ``[seed, epoch]``)
    is written to ``data_dir/resume_<model>.pt`` after every epoch.
    """
    if model_name not in MODELS:
        raise ValueError(f"unknown model {model_name!r}; known: {sorted(MODELS)}")
    data_dir = Path(data_dir)
    cfg = dataset or DatasetConfig()
    hp = dict(HPARAMS[model_name])
    hp["model"] = {**hp["model"], **(model_overrides or {})}
    hp.update(hp_overrides or {})
    if lr is not None:
        hp["lr"] = lr
    if batch_size is not None:
        hp["batch_size"] = batch_size
    epochs = int(epochs if epochs is not None else hp["epochs"])
    hp.update(epochs=epochs, time_budget_min=time_budget_min, max_train_problems=max_train_problems)
    graph = halton_graph(cfg.graph_nodes)
    labelled = load_or_generate(cfg, data_dir, "labelled", progress)
    train_set, val_set = labelled.split_subset("train"), labelled.split_subset("val")
    if max_train_problems is not None and max_train_problems < len(train_set):
        train_set = train_set.subset(np.arange(max_train_problems))
    val_set = val_set.subset(np.arange(min(VAL_PROBLEMS, len(val_set))))
    kind = MODELS[model_name][1]
    torch.manual_seed(seed)
    model = build_model(model_name, **hp["model"])
    inputs = graph_inputs_of(model, train_set, graph, kind)
    opt = torch.optim.Adam(model.parameters(), lr=hp["lr"])
    ckpt_path, meta_path, resume_path = _checkpoint_paths(model_name, out, data_dir)
    start_epoch, history, best = 0, [], {"val_accuracy": -math.inf, "epoch": -1}
    best_state = None
    wall = 0.0
    if resume and resume_path.exists():
        state = torch.load(resume_path, weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start_epoch, history, best, wall = state["epoch"], state["history"], state["best"], state["wall"]
        best_state = state["best_state"]
    gen = torch.Generator().manual_seed(seed)
    budget_s = None if time_budget_min is None else 60.0 * time_budget_min
    t_start = time.perf_counter() - wall
    steps_per_epoch = math.ceil(len(train_set) / hp["batch_size"])
    for epoch in range(start_epoch, epochs):
        model.train()
        order = np.random.default_rng([seed, epoch]).permutation(len(train_set))
        gen.manual_seed(seed * 100003 + epoch)
        losses = []
        bar = tqdm(range(steps_per_epoch), desc=f"{model_name} epoch {epoch + 1}/{epochs}", disable=not progress)
        out_of_time = False
        for step in bar:
            idx = order[step * hp["batch_size"]:(step + 1) * hp["batch_size"]]
            if hp.get("cosine") and budget_s is not None:
                # learning rate on a cosine over the wall-clock budget (anneals to 5% of lr)
                frac = min(1.0, (time.perf_counter() - t_start) / budget_s)
                for group in opt.param_groups:
                    group["lr"] = hp["lr"] * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * frac)))
            loss = _loss(model, model_name, inputs(idx), hp, gen)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
            if budget_s is not None and time.perf_counter() - t_start > budget_s:
                out_of_time = True
                break
        pred, _ = predict(model, model_name, val_set, graph, seed=seed)
        val_acc = accuracy(pred, val_set, graph)
        wall = time.perf_counter() - t_start
        history.append({"epoch": epoch + 1, "train_loss": float(np.mean(losses)), "val_accuracy": val_acc,
                        "steps": len(losses), "wall_seconds": wall})
        print(f"[{model_name}] epoch {epoch + 1}: loss {np.mean(losses):.4f}  val accuracy {val_acc:.4f}"
              f"  ({wall / 60:.1f} min)", flush=True)
        if val_acc > best["val_accuracy"]:
            best = {"val_accuracy": val_acc, "epoch": epoch + 1}
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        resume_path.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch + 1,
                    "history": history, "best": best, "best_state": best_state, "wall": wall}, resume_path)
        _save_checkpoint(model_name, best_state, hp, cfg, seed, history, best, ckpt_path, meta_path)
        if out_of_time:
            print(f"[{model_name}] time budget reached", flush=True)
            break
    return {"checkpoint": str(ckpt_path), "best": best, "history": history}


def _save_checkpoint(name: str, state: dict, hp: dict, cfg: DatasetConfig, seed: int,
                     history: list, best: dict, ckpt_path: Path, meta_path: Path) -> None:
    meta = {"model": name, "hparams": hp, "seed": seed, "dataset": asdict(cfg), "best": best,
            "history": history, "train_wall_seconds": history[-1]["wall_seconds"] if history else 0.0,
            "parameters": int(sum(v.numel() for v in state.values()))}
    ckpt_path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"model": name, "hparams": hp, "state_dict": state, "meta": meta}, ckpt_path)
    meta_path.write_text(json.dumps(meta, indent=2))


def load_checkpoint(path: str | Path) -> tuple[torch.nn.Module, str, dict]:
    """Model (eval mode), its name and metadata from a shipped checkpoint."""
    ckpt = torch.load(path, weights_only=False)
    model = build_model(ckpt["model"], **ckpt["hparams"]["model"])
    model.load_state_dict(ckpt["state_dict"])
    model.eval()
    return model, ckpt["model"], ckpt["meta"]


# ----------------------------------------------------------------------------- evaluation


def evaluate(models: Sequence[str] = tuple(MODELS), checkpoint_dir: str | Path = CHECKPOINT_DIR,
             data_dir: str | Path = DEFAULT_DATA_DIR, num_problems: int | None = None,
             num_samples: int = EVAL_SAMPLES, plan_samples: int = 10, seed: int = 0,
             json_path: str | Path | None = None, plot_path: str | Path | None = None,
             dataset: DatasetConfig | None = None, progress: bool = True) -> dict[str, Any]:
    """Accuracy per model in-distribution and on blob maps, plus the planning comparison.

    Planning: per problem, sparse Halton graph; sparse + each model's prediction (CVAEs:
    ``plan_samples`` decoded samples); sparse + ``plan_samples`` uniform random states
    (control: more nodes without learning); sparse + ground-truth labels (oracle); dense.
    """
    cfg = dataset or DatasetConfig()
    graph = halton_graph(cfg.graph_nodes)
    sets = {}
    for key in ("test", "blob"):
        probs = load_or_generate(cfg, data_dir, key, progress)
        n = len(probs) if num_problems is None else min(num_problems, len(probs))
        sets[key] = probs.subset(np.arange(n))
    labelled = load_or_generate(cfg, data_dir, "labelled", progress)
    train_set = labelled.split_subset("train")
    mean_label = graph.nodes[train_set.label_nodes].mean(0)
    report: dict[str, Any] = {"accuracy": {}, "planning": {}, "settings": {
        "dataset": asdict(cfg), "problems": {k: len(v) for k, v in sets.items()},
        "cvae_samples": num_samples, "plan_samples": plan_samples, "seed": seed,
        "metric": "1 - mean over problems of mean-over-coordinates squared error to the nearest label"}}
    report["accuracy"]["mean-label (reference)"] = {
        k: accuracy(np.tile(mean_label, (len(v), 1)), v, graph) for k, v in sets.items()}
    # Uniform random states: what "best of k" is worth without any learning.
    ref_rng = np.random.default_rng([seed, 11])
    uniform = {}
    for k, v in sets.items():
        uniform[k] = accuracy(ref_rng.uniform(size=(len(v), 2)), v, graph)
        uniform[f"{k}_best_of_{num_samples}"] = accuracy(ref_rng.uniform(size=(len(v), num_samples, 2)), v, graph)
    report["accuracy"]["uniform random (reference)"] = uniform
    preds: dict[str, dict[str, tuple]] = {k: {} for k in sets}
    for name in models:
        path = Path(checkpoint_dir) / f"critical_{name}.pt"
        if not path.exists():
            print(f"skipping {name}: no checkpoint at {path}")
            continue
        model, _, _ = load_checkpoint(path)
        entry = {}
        for key, probs in sets.items():
            point, samples = predict(model, name, probs, graph, num_samples, seed, progress=progress)
            preds[key][name] = (point, samples)
            entry[key] = accuracy(point, probs, graph)
            if samples is not None:
                entry[f"{key}_best_of_{num_samples}"] = accuracy(samples, probs, graph)
        report["accuracy"][name] = entry
    for key, probs in sets.items():
        rng = np.random.default_rng([seed, 7])
        results = []
        for i in tqdm(range(len(probs)), desc=f"planning {key}", disable=not progress):
            extra = {f"sparse+{name}": (s[i][:plan_samples] if s is not None else p[i][None])
                     for name, (p, s) in preds[key].items()}
            extra[f"sparse+{plan_samples} random"] = rng.uniform(0, 1, (plan_samples, 2))
            extra["sparse+labels (oracle)"] = label_positions(probs, graph, i)
            res = compare_planners(probs.maze(i), probs.start[i], probs.goal[i], extra)
            for r in res.values():
                if r.success and not path_is_valid(probs.maze(i), r.path):
                    raise AssertionError("planner returned a path through an obstacle")
            results.append(res)
        report["planning"][key] = summarize(results)
    if json_path:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps(report, indent=2))
    if plot_path:
        plot_predictions(sets, preds, graph, plot_path)
    return report


def plot_predictions(sets: dict[str, CriticalProblems], preds: dict[str, dict[str, tuple]],
                     graph: HaltonGraph, path: str | Path, per_set: int = 2) -> None:
    """Paper-style figure: one row per problem, one column per model; CVAE samples as clouds."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    names = list(next(iter(preds.values())).keys())
    rows = [(key, i) for key in sets for i in range(min(per_set, len(sets[key])))]
    fig, axes = plt.subplots(len(rows), max(len(names), 1), figsize=(2.4 * max(len(names), 1), 2.4 * len(rows)),
                             squeeze=False)
    for r, (key, i) in enumerate(rows):
        probs = sets[key]
        lab = label_positions(probs, graph, i)
        for c, name in enumerate(names):
            ax = axes[r][c]
            for w in probs.walls[i]:
                ax.add_patch(Rectangle(w[:2], w[2] - w[0], w[3] - w[1], color="0.25"))
            for b in probs.blobs[i]:
                ax.add_patch(Circle(b[:2], b[2], color="0.45"))
            point, samples = preds[key][name]
            if samples is not None:
                ax.scatter(samples[i, :, 0], samples[i, :, 1], s=6, c="tab:blue", alpha=0.5, label="samples")
            ax.scatter(lab[:, 0], lab[:, 1], s=14, marker="x", c="k", label="bottleneck")
            ax.scatter(*point[i], s=50, marker="*", c="tab:orange", label="prediction")
            ax.scatter(*probs.start[i], s=25, c="tab:green")
            ax.scatter(*probs.goal[i], s=25, c="tab:red")
            ax.set(xlim=(0, 1), ylim=(0, 1), xticks=[], yticks=[], aspect="equal")
            if r == 0:
                ax.set_title(name)
            if c == 0:
                ax.set_ylabel("in-dist" if key == "test" else "blob maps")
    axes[0][0].legend(loc="lower left", fontsize=5)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------- CLI


def _dataset_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", default=str(DEFAULT_DATA_DIR), help="dataset cache directory")
    p.add_argument("--data-seed", type=int, default=0, help="seed of the generated dataset")


def add_subparsers(subparsers: Any) -> None:
    """Register ``generate-data``, ``train`` and ``evaluate`` on an argparse subparsers object."""
    g = subparsers.add_parser("generate-data", help="generate and cache the critical-sample datasets")
    _dataset_args(g)
    g.add_argument("--num-maps", type=int, default=DatasetConfig.num_maps)
    g.add_argument("--pairs-per-map", type=int, default=DatasetConfig.pairs_per_map)
    g.add_argument("--eval-problems", type=int, default=DatasetConfig.eval_problems)
    g.add_argument("--overwrite", action="store_true")
    g.set_defaults(func=_cmd_generate)
    t = subparsers.add_parser("train", help="train one critical-sample model")
    t.add_argument("--model", required=True, choices=sorted(MODELS))
    t.add_argument("--epochs", type=int, default=None)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--resume", action="store_true")
    t.add_argument("--out", default=None, help="checkpoint path (default agents/checkpoints/critical_<model>.pt)")
    t.add_argument("--time-budget", type=float, default=None, help="stop after this many minutes")
    t.add_argument("--max-train-problems", type=int, default=None)
    t.add_argument("--lr", type=float, default=None, help="override the default learning rate")
    t.add_argument("--batch-size", type=int, default=None)
    t.add_argument("--hidden", type=int, default=None, help="override hidden_channels")
    t.add_argument("--readout", choices=["max", "attention"], default=None,
                   help="graph models: the paper's max pool + FC, or attention over node positions")
    t.add_argument("--features", choices=["paper", "position"], default=None,
                   help="graph models: eq. featurestate (5) or with x_n appended (7)")
    t.add_argument("--edges", choices=["valid", "all"], default=None,
                   help="graph models: collision-free edges only, or the whole fixed graph")
    t.add_argument("--node-loss", type=float, default=None,
                   help="attention readout: weight of the label-node log-likelihood term")
    t.add_argument("--cosine", action="store_true",
                   help="with --time-budget: cosine learning-rate decay over the wall-clock budget")
    t.add_argument("--threads", type=int, default=2, help="torch threads")
    _dataset_args(t)
    t.set_defaults(func=_cmd_train)
    e = subparsers.add_parser("evaluate", help="accuracy table, figure and planning comparison")
    e.add_argument("--models", nargs="+", default=list(MODELS), choices=sorted(MODELS))
    e.add_argument("--checkpoints", default=str(CHECKPOINT_DIR))
    e.add_argument("--json", default=None)
    e.add_argument("--plot", default=None)
    e.add_argument("--problems", type=int, default=None, help="first N of the 300 problems per set")
    e.add_argument("--samples", type=int, default=EVAL_SAMPLES, help="CVAE samples per problem")
    e.add_argument("--seed", type=int, default=0)
    _dataset_args(e)
    e.set_defaults(func=_cmd_evaluate)


def _cmd_generate(a: argparse.Namespace) -> None:
    cfg = DatasetConfig(seed=a.data_seed, num_maps=a.num_maps, pairs_per_map=a.pairs_per_map,
                        eval_problems=a.eval_problems)
    for key, path in generate_all(cfg, a.data, overwrite=a.overwrite).items():
        print(f"{key}: {path}")


def _cmd_train(a: argparse.Namespace) -> None:
    torch.set_num_threads(a.threads)
    over: dict[str, Any] = {}
    if a.hidden is not None:
        over["hidden_channels"] = a.hidden
    if a.readout is not None:
        over["readout"] = a.readout
    if a.features is not None:
        over["in_channels"] = NODE_FEATURES_WITH_POSITION if a.features == "position" else NODE_FEATURES
    if a.edges is not None:
        over["edges"] = a.edges
    hp_extra: dict[str, Any] = {}
    if a.node_loss is not None:
        hp_extra["node_loss_weight"] = a.node_loss
    if a.cosine:
        hp_extra["cosine"] = True
    res = train(a.model, a.data, a.epochs, a.seed, a.out, a.resume, a.time_budget,
                a.max_train_problems, DatasetConfig(seed=a.data_seed), lr=a.lr,
                batch_size=a.batch_size, model_overrides=over, hp_overrides=hp_extra)
    print(json.dumps(res["best"]))


def _cmd_evaluate(a: argparse.Namespace) -> None:
    rep = evaluate(a.models, a.checkpoints, a.data, a.problems, a.samples, seed=a.seed,
                   json_path=a.json, plot_path=a.plot, dataset=DatasetConfig(seed=a.data_seed))
    print(format_table(rep))


def format_table(report: dict[str, Any]) -> str:
    """Markdown tables of accuracy and planning results."""
    lines = ["| model | in-dist acc | blob acc | in-dist best-of-k | blob best-of-k |", "|---|---|---|---|---|"]
    for name, acc in report["accuracy"].items():
        bk = [v for k, v in acc.items() if "best_of" in k]
        cells = [f"{acc['test']:.4f}", f"{acc['blob']:.4f}"] + ([f"{v:.4f}" for v in bk] if bk else ["-", "-"])
        lines.append("| " + " | ".join([name] + cells) + " |")
    for key, summ in report["planning"].items():
        common = summ.get("_common", {})
        lines += ["", f"planning on {key} ({common.get('problems')} problems, {common.get('solved_by_all')} solved by all)",
                  "| graph | success | cost (common) | time ms | edges checked | nodes |", "|---|---|---|---|---|---|"]
        for name, s in summ.items():
            if name.startswith("_"):
                continue
            lines.append(f"| {name} | {s['success_rate']:.3f} | {s['mean_cost_common']:.3f} | "
                         f"{1000 * s['mean_seconds']:.2f} | {s['mean_edges_checked']:.0f} | {s['mean_nodes']:.0f} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    """``generate-data`` | ``train`` | ``evaluate`` (see module docstring)."""
    torch.set_num_threads(2)
    parser = argparse.ArgumentParser(prog="critical", description=__doc__.splitlines()[0])
    add_subparsers(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
