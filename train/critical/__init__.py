"""Critical samples: data generation, training and evaluation of GNN/GAT/GNN-CVAE/CNN/CVAE.

Entry point ``main(argv)`` with three sub-commands (``--help`` on each lists every flag)::

    python -m train.critical generate-data [--data DIR] [--data-seed S]
    python -m train.critical train --model gnn|gat|gnn-cvae|cnn|cvae [--epochs N] [--seed S]
                                   [--out FILE] [--resume] [--ship] [--time-budget MIN]
    python -m train.critical evaluate [--models a,b] [--checkpoints DIR[,DIR...]] [--eval-seed S]
                                      [--ks 1,3,10] [--json FILE] [--plot FILE] [--problems N]

One file per job:

===================  ===============================================================
``args.py``          per-model defaults (:data:`DEFAULTS`) and the flags of each sub-command
``data.py``          problem indices -> model inputs (:class:`Inputs`)
``losses.py``        training losses, dispatched on the model family
``training.py``      the training loop, run directories, checkpoint and resume
``evaluation.py``    predictions, accuracy, planning comparison, report table
``plots.py``         the prediction figure
``cli.py``           argparse from the dataclasses; ``main(argv)``
===================  ===============================================================

Checkpoints are read and written by :mod:`agents.checkpoints` (``weights_only=True``).
"""

from agents.critical.models import MODELS
from train.critical.cli import main
from train.critical.args import (CHECKPOINT_DIR, DEFAULT_DATA_DIR, DEFAULTS, EVAL_SAMPLES, RUNS_DIR,
                                 VAL_PROBLEMS, EvaluateArgs, GenerateArgs, ModelDefaults, Optim, TrainArgs)
from train.critical.data import Inputs, inputs_for, uses_position
from train.critical.evaluation import (Predictions, accuracy, choose, evaluate, format_table, load_model,
                                       nearest_label_distance, nearest_label_mse, predict, predict_all,
                                       score_predictions, validation_scores)
from train.critical.losses import (label_log_likelihood, label_mean_log_prob, loss, nearest_label_loss,
                                   one_label_each)
from train.critical.plots import plot_predictions
from train.critical.training import RunPaths, TrainError, run_paths, ship, train

__all__ = ["main", "CHECKPOINT_DIR", "DEFAULT_DATA_DIR", "DEFAULTS", "EVAL_SAMPLES", "RUNS_DIR", "VAL_PROBLEMS",
           "EvaluateArgs", "GenerateArgs", "ModelDefaults", "Optim", "TrainArgs", "Inputs", "inputs_for",
           "uses_position", "Predictions", "accuracy", "choose", "evaluate", "format_table", "load_model",
           "nearest_label_distance", "nearest_label_mse", "predict", "predict_all", "score_predictions",
           "validation_scores", "label_log_likelihood", "label_mean_log_prob", "loss", "nearest_label_loss",
           "one_label_each", "plot_predictions", "RunPaths", "TrainError", "run_paths", "ship", "train", "MODELS"]
