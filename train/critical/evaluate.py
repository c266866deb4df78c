"""Scoring: predictions, the paper's accuracy (1 - MSE to the nearest label), and planning.

Accuracy is the paper's ``1 - MSE`` between prediction and ground truth; with several
bottleneck labels per problem the error is to the nearest label, and MSE averages the
squared error over the two coordinates. CVAEs are scored on the mean of ``k`` decoded
samples and on the best of the ``k`` samples.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from agents.checkpoints import load_checkpoint
from agents.critical_data import label_positions
from agents.models.critical import MODELS, kind_of, name_of
from gnn_mp_envs.critical.dataset import CriticalProblems, DatasetConfig, load_or_generate
from gnn_mp_envs.critical.halton import HaltonGraph, halton_graph
from gnn_mp_envs.critical.planning import compare_planners, path_is_valid, summarize
from gnn_mp_envs.utils.io import atomic_write_text
from train.critical.config import CHECKPOINT_DIR, DEFAULT_DATA_DIR, EVAL_SAMPLES, checkpoint_name
from train.critical.data import inputs_for


def load_model(path: str | Path, name: str | None = None) -> tuple[torch.nn.Module, str, dict]:
    """A critical model (eval mode), its name and the checkpoint record.

    ``name`` (e.g. ``"gnn"``) refuses a file holding another model; without it any critical
    kind is accepted. Raises :class:`agents.checkpoints.CheckpointError` (one line).
    """
    expected = kind_of(name) if name is not None else [kind_of(n) for n in MODELS]
    model, record = load_checkpoint(path, expected_kind=expected)
    return model, name_of(record["kind"]), record


@torch.no_grad()
def predict(model: torch.nn.Module, name: str, problems: CriticalProblems, graph: HaltonGraph,
            num_samples: int = EVAL_SAMPLES, seed: int = 0, batch_size: int = 16,
            progress: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Point predictions (P, 2) and, for CVAEs, decoded samples (P, k, 2).

    For CVAEs the point prediction is the mean of the ``k`` samples from N(0, I).
    """
    model.eval()
    kind, out = MODELS[name][1], MODELS[name][2]
    inputs = inputs_for(model, name, problems, graph)
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


def evaluate(models: Sequence[str] = tuple(MODELS), checkpoint_dir: str | Path = CHECKPOINT_DIR,
             data_dir: str | Path = DEFAULT_DATA_DIR, num_problems: int | None = None,
             num_samples: int = EVAL_SAMPLES, plan_samples: int = 10, seed: int = 0,
             json_path: str | Path | None = None, plot_path: str | Path | None = None,
             dataset: DatasetConfig | None = None, progress: bool = True) -> dict[str, Any]:
    """Accuracy per model in-distribution and on blob maps, plus the planning comparison.

    Planning: per problem, sparse Halton graph; sparse + each model's prediction (CVAEs:
    ``plan_samples`` decoded samples); sparse + ``plan_samples`` uniform random states
    (control: more nodes without learning); sparse + ground-truth labels (oracle); dense.

    ``checkpoint_dir/critical_<model>.pt`` must hold that model (its kind is checked);
    missing files are skipped with a message. Checkpoints are loaded before any data, so a
    bad file fails fast (:class:`agents.checkpoints.CheckpointError`).
    """
    loaded: dict[str, torch.nn.Module] = {}
    for name in models:
        path = Path(checkpoint_dir) / checkpoint_name(name)
        if not path.exists():
            print(f"skipping {name}: no checkpoint at {path}")
            continue
        loaded[name] = load_model(path, name)[0]
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
    for name, model in loaded.items():
        entry = {}
        for key, probs in sets.items():
            point, samples = predict(model, name, probs, graph, num_samples, seed, progress=progress)
            preds[key][name] = (point, samples)
            entry[key] = accuracy(point, probs, graph)
            if samples is not None:
                entry[f"{key}_best_of_{num_samples}"] = accuracy(samples, probs, graph)
        report["accuracy"][name] = entry
    for key, probs in sets.items():
        report["planning"][key] = planning_comparison(probs, graph, preds[key], plan_samples, seed, progress,
                                                      desc=f"planning {key}")
    if json_path:
        atomic_write_text(json_path, json.dumps(report, indent=2))
    if plot_path:
        from train.critical.plots import plot_predictions
        plot_predictions(sets, preds, graph, plot_path)
    return report


def planning_comparison(probs: CriticalProblems, graph: HaltonGraph, preds: dict[str, tuple],
                        plan_samples: int, seed: int, progress: bool = False,
                        desc: str = "planning") -> dict[str, Any]:
    """Summary of the r-disc planner on the sparse graph with each model's predictions added.

    ``preds``: model name -> (points (P, 2), samples (P, k, 2) or None). Every returned path
    is checked edge by edge.
    """
    rng = np.random.default_rng([seed, 7])
    results = []
    for i in tqdm(range(len(probs)), desc=desc, disable=not progress):
        extra = {f"sparse+{name}": (s[i][:plan_samples] if s is not None else p[i][None])
                 for name, (p, s) in preds.items()}
        extra[f"sparse+{plan_samples} random"] = rng.uniform(0, 1, (plan_samples, 2))
        extra["sparse+labels (oracle)"] = label_positions(probs, graph, i)
        res = compare_planners(probs.maze(i), probs.start[i], probs.goal[i], extra)
        for r in res.values():
            if r.success and not path_is_valid(probs.maze(i), r.path):
                raise AssertionError("planner returned a path through an obstacle")
        results.append(res)
    return summarize(results)


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
