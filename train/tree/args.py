"""Flags of ``gnn-mp train sampler`` without torch: ``--help`` and bad flags answer at once, and an
install without the ``agents`` extra gets its one-line refusal before anything heavy is imported."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from train.args import (MAX_MINUTES, UsageError, arg, check_fits_in_memory, minutes_float, non_negative_int,
                        positive_float, positive_int, seed_int, size_int, worker_count)
from train.run import RunFlags
from train.tree.data import VIEWS

#: The learned tree samplers ``--model`` trains (``train.tree.adapters.ADAPTERS`` holds one adapter each).
MODELS = ("gnn", "cvae", "gnn-cvae")


@dataclass
class TrainArgs(RunFlags):
    """Flags of ``gnn-mp train sampler`` (the run shell's from :class:`train.run.RunFlags`)."""

    task: str = arg("pendulum", "task (any registered task; --import adds your own)")
    model: str = arg("gnn", "model", choices=MODELS)
    problems: int = arg(400, "training problems solved by the uniform sampler (split train)", parse=positive_int)
    scene: str | None = arg(None, "scene family of the training problems (default: the task's training family; "
                            "maze2d / pendulum: 'mixed' is the domain randomisation over kinds); OOD scenes "
                            "are refused")
    augment: bool = arg(False, "augment every training batch with the task's symmetries (TaskSpec.symmetries: "
                        "maze2d's eight rotations/reflections, the pendulum's mirror)")
    relative_inputs: bool = arg(False, "gnn (node mixture) and gnn-cvae: read no absolute position, only the "
                                "nodes' offsets to start and goal")
    hidden: int | None = arg(None, "hidden width of the model's layers (default: the shipped architecture's: "
                             "gnn and gnn-cvae 64, cvae 128)", parse=size_int)
    view: str = arg("grown", "training graphs: grown (the trees the planner grew) or prefix (the paper's "
                    "start + path prefix)", choices=VIEWS)
    minutes: float = arg(10.0, "gradient-step budget of the first training phase (minutes); planning the dataset, "
                                   "each DAgger round (--dagger-minutes plus its planning) and the final evaluation "
                                   "come on top", parse=minutes_float)
    dagger_rounds: int = arg(1, "DAgger rounds: plan with the sampler, relabel its own trees, fine-tune",
                             parse=non_negative_int)
    dagger_problems: int = arg(400, "fresh training problems planned per DAgger round", parse=positive_int)
    dagger_minutes: float = arg(6.0, "gradient-step budget per DAgger round (minutes), on top of --minutes; the "
                                         "round's planning comes on top", parse=minutes_float)
    batch_size: int = arg(8, "runs (solved problems) per optimisation step", parse=positive_int)
    lr: float = arg(2e-3, "Adam learning rate (cosine-annealed)", parse=positive_float)
    max_snapshots: int = arg(96, "snapshots per run in an epoch (the scorer: negative samples per run)",
                             parse=positive_int)
    eval_problems: int = arg(60, "validation problems planned at the end (sampler and uniform)",
                             parse=non_negative_int)
    seed: int = arg(0, "seed of data, initialisation, batching and evaluation", parse=seed_int)
    data_dir: Path = arg(Path("data/tree_samplers"), "dataset cache directory")
    workers: int = arg(1, "processes that plan the training problems (the dataset is the same for any count)",
                       parse=worker_count)
    ray: str | None = arg(None, "plan the training problems on --workers Ray actors, as gnn-mp benchmark --ray: no "
                          "ADDRESS starts a local Ray instance; 'auto' or ray://HOST:10001 joins a running cluster "
                          "(the same dataset)", metavar="ADDRESS", const="local")
    resume: bool = arg(False, "continue the first phase from the run directory's resume state (needs --out)")


#: The least a solved training problem takes in memory (its start, goal, tree rows and path: 2.3 KiB on a
#: 2-D task without obstacles, 35 KiB on maze2d), and an evaluation run's record (its counters).
PROBLEM_BYTES, RUN_BYTES = 2 * 1024, 1024


def check_counts(args: TrainArgs) -> None:
    """Counts that could not finish on this machine, refused in one line before any work: the training
    problems of the first phase and of every DAgger round (all kept in memory), the evaluation runs
    (sampler and uniform), the training time of all phases (at most 30 days, as each budget)."""
    problems = args.problems + args.dagger_rounds * args.dagger_problems
    check_fits_in_memory("--problems + --dagger-rounds x --dagger-problems", problems, PROBLEM_BYTES,
                         "solved training problems")
    check_fits_in_memory("--eval-problems", 2 * args.eval_problems, RUN_BYTES, "evaluation runs (sampler and "
                         "uniform)")
    minutes = args.minutes + args.dagger_rounds * args.dagger_minutes
    if minutes > MAX_MINUTES:
        raise UsageError(f"--minutes + --dagger-rounds x --dagger-minutes: {minutes:,.0f} minutes of training, more "
                         f"than 30 days ({MAX_MINUTES:,} minutes)")
