"""Hyper-parameters and command-line arguments of the critical-sample models, in one place.

* :data:`DEFAULTS`: per model, the constructor arguments (:class:`ModelDefaults.ctor`) and
  the optimisation settings (:class:`Optim`). The shipped checkpoints were trained with
  these plus the flags recorded in their ``.json`` sidecars.
* :class:`GenerateArgs`, :class:`TrainArgs`, :class:`EvaluateArgs`: one dataclass per
  sub-command; each field is one flag (``train/args.py`` turns them into argparse flags), so
  a default and its help text are written once.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from agents.checkpoints import SHIPPED_DIR, shipped_checkpoint
from agents.critical.models import MODELS, NODE_FEATURES, NODE_FEATURES_WITH_POSITION
from gnn_mp_envs.critical.dataset import DatasetConfig
from train.args import (MAX_SIZE, arg, check_fits_in_memory, figure_path, minutes_float, non_negative_float,
                        non_negative_int, positive_float, positive_int, seed_int, size_int, worker_count)

#: Where cached datasets go (git-ignored).
DEFAULT_DATA_DIR = Path("data/critical")
#: Where training runs go by default, one directory per run (git-ignored).
RUNS_DIR = Path("runs/critical")
#: Shipped checkpoints (``critical_<model>.pt`` + ``.json``); ``train --ship`` writes here.
CHECKPOINT_DIR = SHIPPED_DIR
#: Problems of the validation split scored after each epoch (kept small for speed).
VAL_PROBLEMS = 200
#: Latent samples per problem when scoring CVAEs.
EVAL_SAMPLES = 16
#: Numbers of planning samples per model (evaluation).
KS = (1, 3, 10)
#: Diversity of the k samples: no two within this many graph radii r.
MIN_SEP_R = 1.0


def checkpoint_name(model: str) -> str:
    """File name of a model's checkpoint: ``critical_<model>.pt`` (in run directories and shipped)."""
    return shipped_checkpoint(f"critical_{model}").name


@dataclass(frozen=True)
class Optim:
    """How one model is trained."""

    lr: float
    batch_size: int
    epochs: int
    #: CVAEs: weight of KL(q(z | x, y) || N(0, I)) in the loss.
    kl_weight: float = 0.0
    #: Models with node scores (attention readout, heat-map CNN): weight of the label-node term.
    node_loss_weight: float = 0.0
    #: The label-node term: "any" = log of the node distribution's mass on the labels (the
    #: first round's), "all" = mean log-probability of the labels (cross-entropy against the
    #: uniform distribution over them). See train/critical/losses.py.
    node_target: str = "any"
    #: Deterministic models: weight of the squared error of the point prediction to the nearest label.
    point_loss_weight: float = 1.0
    #: Cosine learning-rate decay (to 5% of lr) over the wall-clock budget if there is one,
    #: else over the planned steps.
    cosine: bool = False


@dataclass(frozen=True)
class ModelDefaults:
    """A model's default constructor arguments and optimisation settings."""

    ctor: dict[str, Any]
    optim: Optim


_GRAPH = {"in_channels": NODE_FEATURES_WITH_POSITION, "hidden_channels": 32, "num_layers": 3,
          "readout": "attention", "edges": "all"}
#: Node-level training: the label-node term at weight 1
#: next to the point regression. "any" and "all" targets were tied on validation (docs/journal/2026-12-05-critical-node-level-tuning-and-seeds.md).
_NODE = {"node_loss_weight": 1.0, "node_target": "any", "point_loss_weight": 1.0}
#: TAGConv models: 6 layers of 3 taps (18 hops) scored better on validation than 3 (9 hops).
_DEEP = {"num_layers": 6, "K": 3}
DEFAULTS: dict[str, ModelDefaults] = {
    "gnn": ModelDefaults({**_GRAPH, **_DEEP},
                         Optim(lr=3e-3, batch_size=16, epochs=3, **_NODE)),
    "gat": ModelDefaults({**_GRAPH, "heads": 1},
                         Optim(lr=3e-3, batch_size=16, epochs=2, **_NODE)),
    "gnn-cvae": ModelDefaults({**_GRAPH, **_DEEP, "latent_channels": 2},
                              Optim(lr=3e-3, batch_size=16, epochs=3, kl_weight=0.005, **_NODE)),
    "cnn": ModelDefaults({"hidden_channels": 16, "num_layers": 4, "readout": "heatmap"},
                         Optim(lr=1e-3, batch_size=64, epochs=4, **_NODE)),
    "cvae": ModelDefaults({"hidden_channels": 16, "num_layers": 4, "latent_channels": 2},
                          Optim(lr=1e-3, batch_size=64, epochs=30, kl_weight=0.005)),
}
assert set(DEFAULTS) == set(MODELS)


def _shown(help_text: str, default: str) -> str:
    """Help text stating a default that is not the field's value (None: "the model's")."""
    return f"{help_text} (default: {default})%(default).0s"


def model_list(text: str) -> list[str]:
    """argparse type: comma-separated critical model names."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in MODELS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"expected comma-separated names from {', '.join(MODELS)}, "
                                         f"got {text!r}")
    return names


# ----------------------------------------------------------------------------- flags


@dataclass
class DataArgs:
    """Flags of every sub-command: the dataset (cache directory, seed, size) and torch threads. The
    size flags belong to every sub-command, so that ``train`` and ``evaluate`` use the dataset
    ``generate-data`` made with the same flags (a cache of another size is regenerated)."""

    data: Path = arg(DEFAULT_DATA_DIR, "dataset cache directory")
    data_seed: int = arg(0, "seed of the generated dataset", parse=seed_int)
    num_maps: int = arg(DatasetConfig.num_maps, "maps of the labelled set", parse=positive_int)
    pairs_per_map: int = arg(DatasetConfig.pairs_per_map, "start/goal pairs per map", parse=positive_int)
    eval_problems: int = arg(DatasetConfig.eval_problems, "problems of each evaluation set", parse=positive_int)
    threads: int = arg(2, "torch threads", parse=worker_count)

    def dataset(self) -> DatasetConfig:
        return DatasetConfig(seed=self.data_seed, num_maps=self.num_maps, pairs_per_map=self.pairs_per_map,
                             eval_problems=self.eval_problems)

    def check_size(self) -> None:
        """A dataset that could not be generated and held on this machine, refused in one line before any
        work (``--num-maps 10**9``: days of generation, then out of memory)."""
        problems = self.num_maps * self.pairs_per_map + 2 * self.eval_problems
        check_fits_in_memory("--num-maps x --pairs-per-map + 2 x --eval-problems", problems, PROBLEM_BYTES,
                             "critical-sample problems")


#: The least one critical-sample problem takes in memory: its Halton graph's node and edge validity bits
#: (2.3 KiB), the CNN's 64 x 64 occupancy image (4 KiB), walls and labels.
PROBLEM_BYTES = 8 * 1024


@dataclass
class GenerateArgs(DataArgs):
    """Generate and cache the three dataset files (labelled, eval_test, eval_blob)."""

    overwrite: bool = arg(False, "regenerate even if the cached files match")


@dataclass
class TrainArgs(DataArgs):
    """Train one model; flags left unset take the model's defaults (train/critical/args.py)."""

    model: str | None = arg(None, "model to train (required)%(default).0s", choices=sorted(MODELS))
    epochs: int | None = arg(None, _shown("passes over the training set", "the model's"), parse=positive_int)
    seed: int = arg(0, "seed of initialisation and shuffling", parse=seed_int)
    out: Path | None = arg(None, _shown("checkpoint file; its .json and resume state go beside it",
                                           "runs/critical/<model>-seed<S>-<time>/critical_<model>.pt"))
    ship: bool = arg(False, "when done, also copy the best checkpoint and its .json into "
                     "agents/checkpoints/ (replaces the shipped weights)")
    resume: bool = arg(False, "continue the run of --out, or without --out the latest run of this model and seed")
    time_budget: float | None = arg(None, _shown("stop after this many minutes", "no limit"), parse=minutes_float)
    max_train_problems: int | None = arg(None, _shown("use only the first N training problems", "all"), parse=positive_int)
    lr: float | None = arg(None, _shown("learning rate", "the model's"), parse=positive_float)
    batch_size: int | None = arg(None, _shown("problems per step", "the model's"), parse=positive_int)
    hidden: int | None = arg(None, _shown("hidden_channels", "the model's"), parse=size_int)
    layers: int | None = arg(None, _shown("num_layers (graph filters / conv layers)", "the model's"),
                             parse=size_int)
    readout: str | None = arg(None, _shown("graph models: the paper's max pool + FC (max) or attention over "
                                     "node positions; CNN: FC to a point (point) or a heat map over the image",
                                     "attention / heatmap"), choices=["max", "attention", "point", "heatmap"])
    features: str | None = arg(None, _shown("graph models: eq. featurestate (5) or with x_n appended (7)",
                                      "position"), choices=["paper", "position"])
    edges: str | None = arg(None, _shown("graph models: collision-free edges only, or the whole fixed graph",
                                   "all"), choices=["valid", "all"])
    context: str | None = arg(None, _shown("graph models, attention readout: node scores also see the graph's "
                                     "max-pooled embedding (max) or not (none)", "the model's"),
                              choices=["none", "max"])
    node_loss: float | None = arg(None, _shown("models with node scores: weight of the label-node term",
                                         "the model's"), parse=non_negative_float)
    node_target: str | None = arg(None, _shown("label-node term: mass on the labels (any) or cross-entropy "
                                         "against the uniform distribution over them (all)", "the model's"),
                                  choices=["any", "all"])
    point_loss: float | None = arg(None, _shown("deterministic models: weight of the point regression",
                                          "the model's"), parse=non_negative_float)
    max_steps: int | None = arg(None, _shown("stop after this many optimizer steps (then validate and save)",
                                       "epochs x steps per epoch"), parse=positive_int)
    cosine: bool = arg(False, "cosine learning-rate decay (to 5%% of lr) over --time-budget, else over the "
                       "planned steps")

    def resolve(self) -> tuple[dict[str, Any], Optim]:
        """The model's constructor arguments and optimisation settings with the flags applied."""
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; known: {', '.join(sorted(MODELS))}")
        defaults = DEFAULTS[self.model]
        ctor = dict(defaults.ctor)
        graph_only = {"features": self.features, "edges": self.edges, "context": self.context}
        if MODELS[self.model][1] != "graph":
            given = [f"--{k}" for k, v in graph_only.items() if v is not None]
            if given:
                raise ValueError(f"{', '.join(given)}: only for graph models, not {self.model}")
        readouts = {"graph": ("max", "attention"), "cnn": ("point", "heatmap")}.get(
            "graph" if MODELS[self.model][1] == "graph" else self.model, ())
        if self.readout is not None and self.readout not in readouts:
            raise ValueError(f"--readout {self.readout}: graph models take max|attention, the cnn point|heatmap; "
                             f"{self.model} takes {'|'.join(readouts) or 'none'}")
        if self.hidden is not None:
            ctor["hidden_channels"] = self.hidden
        if self.layers is not None:
            ctor["num_layers"] = self.layers
        if self.readout is not None:
            ctor["readout"] = self.readout
        if self.features is not None:
            ctor["in_channels"] = NODE_FEATURES_WITH_POSITION if self.features == "position" else NODE_FEATURES
        if self.edges is not None:
            ctor["edges"] = self.edges
        if self.context is not None:
            ctor["context"] = self.context
        optim = defaults.optim
        changes: dict[str, Any] = {"cosine": optim.cosine or self.cosine}
        for name, value in (("lr", self.lr), ("batch_size", self.batch_size), ("epochs", self.epochs),
                            ("node_loss_weight", self.node_loss), ("node_target", self.node_target),
                            ("point_loss_weight", self.point_loss)):
            if value is not None:
                changes[name] = value
        return ctor, replace(optim, **changes)


def path_list(text: str) -> list[Path]:
    """argparse type: comma-separated directories."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError("expected comma-separated directories")
    return [Path(p) for p in parts]


def k_list(text: str) -> list[int]:
    """argparse type: comma-separated positive sample counts."""
    try:
        ks = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}") from None
    if not ks or min(ks) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    if max(ks) > MAX_SIZE:
        raise argparse.ArgumentTypeError(f"at most {MAX_SIZE:,} samples per model, got {max(ks)}")
    return ks


@dataclass
class EvaluateArgs(DataArgs):
    """Accuracy, hit rate and planning (point and k samples per model) of saved checkpoints."""

    models: list[str] = arg(list(MODELS), "comma-separated models to score", parse=model_list)
    checkpoints: list[Path] = arg([CHECKPOINT_DIR], "directory with critical_<model>.pt files; several "
                                  "(comma-separated, e.g. one per training seed) give mean ± std", parse=path_list)
    eval_seed: int | None = arg(None, _shown("draw fresh evaluation problems (in-distribution and blob) from this "
                                       "seed, cached as eval_<set>_seed<S>.npz", "the shipped sets, drawn from "
                                       "--data-seed"), parse=non_negative_int)
    split: str = arg("eval", "eval: the in-distribution and blob evaluation sets; val: the labelled set's "
                     "validation problems (for tuning)", choices=["eval", "val"])
    json: Path | None = arg(None, _shown("write the report as JSON to this file", "none"))
    plot: Path | None = arg(None, _shown("write the prediction figure to this file (the suffix names the format: "
                                         ".png, .svg, .pdf)", "none"), parse=figure_path)
    problems: int | None = arg(None, _shown("first N of the 300 problems per set", "all"), parse=positive_int)
    samples: int = arg(EVAL_SAMPLES, "CVAE samples per problem for the point prediction (their mean) and "
                       "the best-of accuracy", parse=size_int)
    ks: list[int] = arg(list(KS), "numbers of planning samples per model", parse=k_list)
    min_sep: float = arg(MIN_SEP_R, "k samples: no two within this many graph radii r", parse=non_negative_float)
    select: str = arg("top", "k samples from a node distribution: the top-k nodes or draws from it "
                      "(both keep --min-sep)", choices=["top", "sample"])
    seed: int = arg(0, "seed of CVAE samples and random reference points", parse=seed_int)
    progress: bool = arg(True, "hide the progress bars")
