"""Scoring: predictions, accuracy, hit rate, distance to the labels, and planning with k samples.

Metrics (per problem, then over problems), for a model's point prediction and for its k
chosen samples (``KS`` = 1, 3, 10):

* accuracy: the paper's ``1 - MSE``; with several bottleneck labels the error is to the
  nearest label and MSE averages the squared error over the two coordinates (for k samples:
  the best of them). Compressed near 1: the unit square bounds the error;
* hit rate: a prediction within one graph radius ``r`` of a label (for k samples: any);
* median distance to the nearest label, in units of ``r`` (k samples: the nearest of them).

The k samples (:func:`choose`): models that score the graph's nodes (attention readout,
heat-map CNN, attention GNN-CVAE: the mixture over latents) give their top-k nodes, no two
within ``min_sep``; CVAEs without node scores give their first k decoded samples that keep
the same separation; point-only models give their point.

Planning (:func:`evaluate`): the r-disc planner on the sparse graph, plus each model's point
and its k samples for every k, plus k uniform random states (a control), plus the labels
(oracle), and the dense graph. Every JSON row carries ``"model"`` and ``"k"``.

Several checkpoint directories (e.g. one per training seed) give mean and standard deviation
over them for every model row.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from agents.checkpoints import load_checkpoint
from agents.critical.data import label_positions
from agents.critical.models import MODELS, kind_of, name_of
from gnn_mp_envs.critical.dataset import CriticalProblems, DatasetConfig, eval_config, load_or_generate
from gnn_mp_envs.critical.halton import SPARSE_NODES, HaltonGraph, default_radius, halton_graph, halton_points
from gnn_mp_envs.critical.planning import SPARSE_RADIUS_FACTOR, compare_planners, path_is_valid, plan_rdisc, summarize
from gnn_mp_envs.critical.selection import first_k_diverse, sample_k_diverse, top_k_diverse
from gnn_mp_envs.utils.io import atomic_write_text
from train.critical.args import CHECKPOINT_DIR, DEFAULT_DATA_DIR, EVAL_SAMPLES, KS, MIN_SEP_R, checkpoint_name
from train.critical.data import inputs_for

#: CVAEs: latent samples decoded per problem, the candidates the k samples are chosen from.
CANDIDATE_SAMPLES = 64
#: How the k samples are taken from a node distribution.
SELECTIONS = ("top", "sample")
#: Rows that do not depend on a checkpoint (computed once).
REFERENCE_MODELS = ("sparse", "dense", "oracle", "uniform random", "mean label")


def load_model(path: str | Path, name: str | None = None) -> tuple[torch.nn.Module, str, dict]:
    """A critical model (eval mode), its name and the checkpoint record.

    ``name`` (e.g. ``"gnn"``) refuses a file holding another model; without it any critical
    kind is accepted. Raises :class:`agents.checkpoints.CheckpointError` (one line).
    """
    expected = kind_of(name) if name is not None else [kind_of(n) for n in MODELS]
    model, record = load_checkpoint(path, expected_kind=expected)
    return model, name_of(record["kind"]), record


@dataclass
class Predictions:
    """A model's outputs on a set of problems."""

    point: np.ndarray                  # (P, 2) point predictions
    samples: np.ndarray | None         # (P, M, 2) decoded samples (CVAEs), in draw order
    log_scores: np.ndarray | None      # (P, N) log node distribution over the fixed graph


def has_node_scores(model: torch.nn.Module) -> bool:
    return bool(getattr(model, "has_node_scores", False))


@torch.no_grad()
def predict_all(model: torch.nn.Module, name: str, problems: CriticalProblems, graph: HaltonGraph,
                num_samples: int = EVAL_SAMPLES, seed: int = 0, batch_size: int = 16,
                progress: bool = False) -> Predictions:
    """Point predictions, decoded samples and node scores in one pass over the problems.

    CVAEs decode ``max(num_samples, CANDIDATE_SAMPLES)`` latents per problem; the point
    prediction is the mean of the first ``num_samples``. An attention GNN-CVAE's node
    distribution is the mixture of its attention over the same latents.
    """
    model.eval()
    kind, out = MODELS[name][1], MODELS[name][2]
    inputs = inputs_for(model, name, problems, graph)
    gen = torch.Generator().manual_seed(seed)
    scored = has_node_scores(model)
    m = max(num_samples, CANDIDATE_SAMPLES)
    points, samples, scores = [], [], []
    for s in tqdm(range(0, len(problems), batch_size), desc=f"predict {name}", disable=not progress):
        inp = inputs(np.arange(s, min(s + batch_size, len(problems))))
        b = inp["size"]
        if out == "det":
            if kind == "graph":
                res = model(inp["x"], inp["edge_index"], inp["batch"], inp["pos"], return_log_attention=scored)
            else:
                res = model(inp["image"], inp["pos"], return_log_attention=True) if scored else model(inp["image"])
            p, la = res if scored else (res, None)
            points.append(p.numpy())
        else:
            la = None
            if kind == "graph" and scored:
                smp, la = model.sample_with_node_scores(inp["x"], inp["edge_index"], inp["batch"], m, gen, inp["pos"])
            elif kind == "graph":
                smp = model.sample(inp["x"], inp["edge_index"], inp["batch"], m, gen, inp["pos"])
            else:
                smp = model.sample(inp["image"], m, gen)
            samples.append(smp.numpy())
            points.append(smp[:, :num_samples].mean(1).numpy())
        if la is not None:
            scores.append(la.reshape(b, -1).numpy())
    return Predictions(np.concatenate(points), np.concatenate(samples) if samples else None,
                       np.concatenate(scores) if scores else None)


def predict(model: torch.nn.Module, name: str, problems: CriticalProblems, graph: HaltonGraph,
            num_samples: int = EVAL_SAMPLES, seed: int = 0, batch_size: int = 16,
            progress: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Point predictions (P, 2) and, for CVAEs, ``num_samples`` decoded samples (P, k, 2)."""
    pred = predict_all(model, name, problems, graph, num_samples, seed, batch_size, progress)
    return pred.point, (pred.samples[:, :num_samples] if pred.samples is not None else None)


def choose(pred: Predictions, i: int, k: int, graph: HaltonGraph, min_sep: float,
           select: str = "top", rng: np.random.Generator | None = None) -> np.ndarray:
    """Problem ``i``'s k planning samples (at most k states, (k', 2)); see the module docstring."""
    if pred.log_scores is not None:
        if select == "sample":
            idx = sample_k_diverse(pred.log_scores[i], graph.nodes, k, min_sep, rng or np.random.default_rng(0))
        else:
            idx = top_k_diverse(pred.log_scores[i], graph.nodes, k, min_sep)
        return graph.nodes[idx]
    if pred.samples is not None:
        return first_k_diverse(pred.samples[i], k, min_sep)
    return pred.point[i][None]


def nearest_label_distance(states: Sequence[np.ndarray] | np.ndarray, problems: CriticalProblems,
                           graph: HaltonGraph) -> np.ndarray:
    """Per problem: Euclidean distance from the nearest of its states to the nearest label.

    ``states``: (P, 2), (P, k, 2) or a list of (k_i, 2) arrays; no states give ``inf``.
    """
    out = np.empty(len(problems))
    for i in range(len(problems)):
        s = np.asarray(states[i], dtype=np.float64).reshape(-1, 2)
        lab = label_positions(problems, graph, i)
        out[i] = np.sqrt(((s[:, None, :] - lab[None]) ** 2).sum(-1).min()) if len(s) else np.inf
    return out


def nearest_label_mse(pred: np.ndarray, problems: CriticalProblems, graph: HaltonGraph) -> np.ndarray:
    """Per problem: mean-over-coordinates squared error to the nearest label.

    ``pred`` (P, 2) or (P, k, 2); with samples the best (smallest) error over k is returned.
    """
    return nearest_label_distance(pred, problems, graph) ** 2 / 2


def accuracy(pred: np.ndarray, problems: CriticalProblems, graph: HaltonGraph) -> float:
    """The paper's accuracy: 1 - MSE (to the nearest label), averaged over problems."""
    return float(1.0 - nearest_label_mse(pred, problems, graph).mean())


def distance_metrics(dist: np.ndarray, radius: float) -> dict[str, float]:
    """Accuracy (1 - mean of d^2 / 2), hit rate (d <= r) and median d / r of nearest-label distances."""
    return {"accuracy": float(1.0 - np.mean(dist ** 2 / 2)), "hit_rate": float(np.mean(dist <= radius)),
            "median_dist_r": float(np.median(dist) / radius)}


def score_predictions(pred: Predictions, problems: CriticalProblems, graph: HaltonGraph,
                      ks: Sequence[int] = KS, min_sep_r: float = MIN_SEP_R, select: str = "top",
                      seed: int = 0) -> tuple[dict[str, dict], dict[int, list[np.ndarray]]]:
    """Metrics of the point (key ``"point"``) and of the k samples (key ``k``), and the k samples."""
    r = graph.radius
    rng = np.random.default_rng([seed, 13])
    chosen = {k: [choose(pred, i, k, graph, min_sep_r * r, select, rng) for i in range(len(problems))] for k in ks}
    metrics = {"point": distance_metrics(nearest_label_distance(pred.point, problems, graph), r)}
    for k in ks:
        m = distance_metrics(nearest_label_distance(chosen[k], problems, graph), r)
        m["points"] = float(np.mean([len(c) for c in chosen[k]]))
        metrics[k] = m
    return metrics, chosen


def validation_scores(model: torch.nn.Module, name: str, problems: CriticalProblems, graph: HaltonGraph,
                      seed: int = 0, ks: Sequence[int] = KS) -> dict[str, float]:
    """What training validates: point accuracy, hit rate at each k, and their mean ``val_score``."""
    pred = predict_all(model, name, problems, graph, EVAL_SAMPLES, seed)
    metrics, _ = score_predictions(pred, problems, graph, ks, seed=seed)
    out = {"val_accuracy": metrics["point"]["accuracy"]}
    out.update({f"val_hit@{k}": metrics[k]["hit_rate"] for k in ks})
    out["val_score"] = float(np.mean([metrics[k]["hit_rate"] for k in ks]))
    return out


# ----------------------------------------------------------------------------- the report


def _row(model: str, k: int | None, selection: str, values: dict[str, float]) -> dict[str, Any]:
    return {"model": model, "k": k, "selection": selection, **values}


def _plan_problem(probs: CriticalProblems, i: int, rows: dict[str, np.ndarray],
                  baselines: bool) -> dict[str, Any]:
    """The r-disc planner on problem ``i``: sparse + each row's states (and sparse / dense)."""
    maze, start, goal = probs.maze(i), probs.start[i], probs.goal[i]
    if baselines:
        res = compare_planners(maze, start, goal, rows)
    else:
        sparse = halton_points(SPARSE_NODES)
        r = default_radius(SPARSE_NODES, factor=SPARSE_RADIUS_FACTOR)
        res = {name: plan_rdisc(maze, start, goal, np.vstack([sparse, np.reshape(s, (-1, 2))]), r)
               for name, s in rows.items()}
    for pr in res.values():
        if pr.success and not path_is_valid(maze, pr.path):
            raise AssertionError("planner returned a path through an obstacle")
    return res


def _aggregate(per_seed: list[dict[str, dict]]) -> dict[str, dict]:
    """Rows of several checkpoint directories -> one row each: mean, ``<metric>_std`` and ``values``."""
    out: dict[str, dict] = {}
    for name, first in per_seed[0].items():
        if name.startswith("_"):
            out[name] = {key: [rep[name][key] for rep in per_seed] if len(per_seed) > 1 else val
                         for key, val in first.items()}
            continue
        row = {key: first[key] for key in ("model", "k", "selection")}
        row["seeds"] = len(per_seed)
        for key, val in first.items():
            if key in row or not isinstance(val, (int, float)) or isinstance(val, bool):
                continue
            vals = np.array([rep[name][key] for rep in per_seed], dtype=np.float64)
            row[key] = float(vals.mean())
            row[f"{key}_std"] = float(vals.std(ddof=1)) if len(vals) > 1 else 0.0
            row.setdefault("values", {})[key] = vals.tolist()
        out[name] = row
    return out


def evaluate(models: Sequence[str] = tuple(MODELS),
             checkpoint_dir: str | Path | Sequence[str | Path] = CHECKPOINT_DIR,
             data_dir: str | Path = DEFAULT_DATA_DIR, num_problems: int | None = None,
             num_samples: int = EVAL_SAMPLES, seed: int = 0,
             json_path: str | Path | None = None, plot_path: str | Path | None = None,
             dataset: DatasetConfig | None = None, progress: bool = True, eval_seed: int | None = None,
             ks: Sequence[int] = KS, min_sep_r: float = MIN_SEP_R, select: str = "top",
             split: str = "eval") -> dict[str, Any]:
    """Accuracy, hit rate, distance and planning of every model in distribution and on blob maps.

    ``checkpoint_dir``: one directory or several (e.g. one per training seed); each
    ``critical_<model>.pt`` must hold that model (its kind is checked); missing files are
    skipped with a message. All checkpoints are loaded before any data, so a bad file fails
    fast (:class:`agents.checkpoints.CheckpointError`). Model rows are the mean over the
    directories, with ``<metric>_std`` (sample standard deviation) and the per-directory
    ``values``. ``eval_seed``: fresh evaluation problems drawn from that seed (default: the
    shipped sets, drawn from the data seed). ``split="val"``: the labelled set's validation
    problems instead (one set, ``"val"``), for tuning.
    """
    if select not in SELECTIONS:
        raise ValueError(f"select must be one of {SELECTIONS}, got {select!r}")
    if split not in ("eval", "val"):
        raise ValueError(f"split must be 'eval' or 'val', got {split!r}")
    dirs = [Path(checkpoint_dir)] if isinstance(checkpoint_dir, (str, Path)) else [Path(d) for d in checkpoint_dir]
    loaded: list[dict[str, torch.nn.Module]] = []
    for d in dirs:
        found = {}
        for name in models:
            path = d / checkpoint_name(name)
            if not path.exists():
                print(f"skipping {name}: no checkpoint at {path}")
                continue
            found[name] = load_model(path, name)[0]
        loaded.append(found)
    names = [n for n in models if all(n in found for found in loaded)]
    if not names:   # before any data is labelled (that takes minutes)
        from agents.checkpoints import CheckpointError
        where = ", ".join(str(d) for d in dirs)
        raise CheckpointError(f"no checkpoints in {where} (expected critical_<model>.pt for "
                              f"{', '.join(models)})")
    cfg = dataset or DatasetConfig()
    graph = halton_graph(cfg.graph_nodes)
    r = graph.radius
    labelled = load_or_generate(cfg, data_dir, "labelled", progress)
    sets = {}
    for key in (("test", "blob") if split == "eval" else ("val",)):
        probs = (labelled.split_subset("val") if key == "val"
                 else load_or_generate(cfg, data_dir, key, progress, eval_seed=eval_seed))
        n = len(probs) if num_problems is None else min(num_problems, len(probs))
        sets[key] = probs.subset(np.arange(n))
    mean_label = graph.nodes[labelled.split_subset("train").label_nodes].mean(0)
    report: dict[str, Any] = {"settings": {
        "dataset": asdict(cfg), "eval_seed": eval_config(cfg, eval_seed).seed, "split": split,
        "problems": {k: len(v) for k, v in sets.items()}, "checkpoints": [str(d) for d in dirs],
        "models": names, "ks": list(ks), "min_sep_r": min_sep_r, "select": select, "radius": r,
        "cvae_samples": num_samples, "candidate_samples": max(num_samples, CANDIDATE_SAMPLES), "seed": seed,
        "metrics": {"accuracy": "1 - mean over problems of mean-over-coordinates squared error to the nearest "
                                "label (k samples: the nearest of them)",
                    "hit_rate": "fraction of problems with a prediction within r of a label (k samples: any)",
                    "median_dist_r": "median over problems of the distance to the nearest label, in units of r"}},
        "accuracy": {}, "planning": {}, "per_checkpoint_dir": []}

    # Rows without a checkpoint: mean label, uniform random states, oracle, sparse, dense.
    fixed_acc: dict[str, dict] = {}
    fixed_plan: dict[str, list] = {}
    for key, probs in sets.items():
        rng = np.random.default_rng([seed, 7, {"test": 0, "blob": 1, "val": 2}[key]])
        rand = {k: rng.uniform(0, 1, (len(probs), k, 2)) for k in ks}
        rows = {"mean label": _row("mean label", 1, "point", distance_metrics(
            nearest_label_distance(np.tile(mean_label, (len(probs), 1)), probs, graph), r))}
        for k in ks:
            rows[f"uniform random k={k}"] = _row("uniform random", k, "uniform", distance_metrics(
                nearest_label_distance(rand[k], probs, graph), r))
        fixed_acc[key] = rows
        plans = []
        for i in tqdm(range(len(probs)), desc=f"planning {key} (references)", disable=not progress):
            extra = {f"uniform random k={k}": rand[k][i] for k in ks}
            extra["oracle (labels)"] = label_positions(probs, graph, i)
            plans.append(_plan_problem(probs, i, extra, baselines=True))
        fixed_plan[key] = plans
    plan_meta = {"sparse": ("sparse", 0, "-"), "dense": ("dense", None, "-"),
                 "oracle (labels)": ("oracle", None, "labels"),
                 **{f"uniform random k={k}": ("uniform random", k, "uniform") for k in ks}}

    first_preds: dict[str, dict[str, tuple]] = {k: {} for k in sets}
    first_chosen: dict[str, dict[str, dict]] = {k: {} for k in sets}
    per_dir_acc, per_dir_plan = [], []
    for d, found in zip(dirs, loaded):
        acc_rep, plan_rep = {}, {}
        for key, probs in sets.items():
            acc_rows = dict(fixed_acc[key])
            plan_rows: dict[str, dict[int | str, list]] = {}
            meta = dict(plan_meta)
            for name in names:
                pred = predict_all(found[name], name, probs, graph, num_samples, seed, progress=progress)
                metrics, chosen = score_predictions(pred, probs, graph, ks, min_sep_r, select, seed)
                how = ("top-k nodes" if select == "top" else "sampled nodes") if pred.log_scores is not None \
                    else "decoded samples" if pred.samples is not None else "point"
                acc_rows[f"{name} point"] = _row(name, 1, "point", metrics["point"])
                if pred.samples is not None:    # the first round's CVAE metric: best of num_samples
                    acc_rows[f"{name} point"][f"best_of_{num_samples}_accuracy"] = accuracy(
                        pred.samples[:, :num_samples], probs, graph)
                for k in ks:
                    acc_rows[f"{name} k={k}"] = _row(name, k, how, metrics[k])
                plan_rows[f"{name} point"] = [p[None] for p in pred.point]
                meta[f"{name} point"] = (name, 1, "point")
                for k in ks:
                    plan_rows[f"{name} k={k}"] = chosen[k]
                    meta[f"{name} k={k}"] = (name, k, how)
                if d == dirs[0]:
                    first_preds[key][name] = (pred.point, pred.samples, pred.log_scores)
                    first_chosen[key][name] = chosen
            results = []
            for i in tqdm(range(len(probs)), desc=f"planning {key} ({d})", disable=not progress):
                res = dict(fixed_plan[key][i])
                res.update(_plan_problem(probs, i, {n: v[i] for n, v in plan_rows.items()}, baselines=False))
                results.append(res)
            summ = summarize(results)
            plan_rep[key] = {n: ({**_row(*meta[n], s), "points": _mean_points(n, plan_rows, s)}
                                 if not n.startswith("_") else s) for n, s in summ.items()}
            acc_rep[key] = acc_rows
        per_dir_acc.append(acc_rep)
        per_dir_plan.append(plan_rep)
        report["per_checkpoint_dir"].append({"checkpoints": str(d), "accuracy": acc_rep, "planning": plan_rep})
    for key in sets:
        report["accuracy"][key] = _aggregate([rep[key] for rep in per_dir_acc])
        report["planning"][key] = _aggregate([rep[key] for rep in per_dir_plan])
    if len(dirs) == 1:
        del report["per_checkpoint_dir"]
    if json_path:
        atomic_write_text(json_path, json.dumps(report, indent=2))
    if plot_path:
        from train.critical.plots import plot_predictions
        plot_predictions(sets, first_preds, graph, plot_path, chosen=first_chosen, k=max(ks))
    return report


def _mean_points(name: str, plan_rows: dict[str, list], summary_row: dict) -> float:
    """Mean number of states a row added to the sparse graph (before dropping those in obstacles)."""
    if name in plan_rows:
        return float(np.mean([len(np.reshape(s, (-1, 2))) for s in plan_rows[name]]))
    return float("nan")


# ----------------------------------------------------------------------------- tables


def _cell(row: dict, key: str, fmt: str) -> str:
    if row is None or key not in row:
        return "-"
    text = format(row[key], fmt)
    if row.get("seeds", 1) > 1 and row["model"] not in REFERENCE_MODELS:
        text += " ± " + format(row[f"{key}_std"], fmt)
    return text


def _label(key: str) -> str:
    return {"test": "in-distribution", "blob": "blob maps", "val": "validation problems"}[key]


def format_table(report: dict[str, Any]) -> str:
    """Markdown tables: accuracy / hit rate / distance, planning success per k, planning details."""
    ks = report["settings"]["ks"]
    seeds = len(report["settings"]["checkpoints"])
    lines = []
    if seeds > 1:
        lines += [f"(model rows: mean ± std over {seeds} checkpoint directories)", ""]
    for key, rows in report["accuracy"].items():
        n = report["settings"]["problems"][key]
        models = list(dict.fromkeys(r["model"] for r in rows.values()))
        lines += [f"accuracy on {_label(key)} ({n} problems); hit = within r = {report['settings']['radius']:.4f} "
                  "of a label; dist = median distance to the nearest label / r",
                  "| model | acc (point) | hit (point) | " + " | ".join(f"hit k={k}" for k in ks) + " | "
                  + " | ".join(f"dist k={k}" for k in ks) + " | dist (point) |",
                  "|---" * (3 + 2 * len(ks) + 1) + "|"]
        for m in models:
            pt = rows.get(f"{m} point") if m not in ("uniform random",) else None
            pt = pt or (rows.get(m) if m == "mean label" else None)
            cells = [_cell(pt, "accuracy", ".4f"), _cell(pt, "hit_rate", ".3f")]
            cells += [_cell(rows.get(f"{m} k={k}"), "hit_rate", ".3f") for k in ks]
            cells += [_cell(rows.get(f"{m} k={k}"), "median_dist_r", ".2f") for k in ks]
            cells += [_cell(pt, "median_dist_r", ".2f")]
            lines.append("| " + " | ".join([m] + cells) + " |")
        lines.append("")
    for key, rows in report["planning"].items():
        n = report["settings"]["problems"][key]
        models = [m for m in dict.fromkeys(r["model"] for n, r in rows.items() if not n.startswith("_"))
                  if m not in ("sparse", "dense", "oracle")]
        ref = {m: rows[n]["success_rate"] for n, m in (("sparse", "sparse"), ("oracle (labels)", "oracle"),
                                                       ("dense", "dense"))}
        lines += [f"planning success on {_label(key)} ({n} problems): sparse {ref['sparse']:.3f}, "
                  f"oracle (labels) {ref['oracle']:.3f}, dense {ref['dense']:.3f}",
                  "| model | point | " + " | ".join(f"k={k}" for k in ks) + " |", "|---" * (2 + len(ks)) + "|"]
        for m in models:
            cells = [_cell(rows.get(f"{m} point"), "success_rate", ".3f")]
            cells += [_cell(rows.get(f"{m} k={k}"), "success_rate", ".3f") for k in ks]
            lines.append("| " + " | ".join([m] + cells) + " |")
        lines += ["", "| graph | model | k | success | cost (common) | time ms | edges checked | nodes |",
                  "|---|---|---|---|---|---|---|---|"]
        for name, s in rows.items():
            if name.startswith("_"):
                continue
            lines.append(f"| {name} | {s['model']} | {'-' if s['k'] is None else s['k']} | "
                         f"{_cell(s, 'success_rate', '.3f')} | {s['mean_cost_common']:.3f} | "
                         f"{1000 * s['mean_seconds']:.2f} | {s['mean_edges_checked']:.0f} | {s['mean_nodes']:.0f} |")
        lines.append("")
    return "\n".join(lines).rstrip()
