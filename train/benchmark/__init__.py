"""Benchmark samplers side by side on the held-out problems of a task.

Every sampler plans the same problems (``split="test"``, indices ``0..N-1``) with the
same per-problem seed, derived from ``--seed`` and the problem index. The planner, its
node budget and its counters are those of :class:`~gnn_mp_envs.envs.tree_env.TreePlanningEnv`;
OMPL planners (``ompl-rrtconnect``, ``ompl-rrt``, ``ompl-kpiece``) run the same problems
through the isolated runner of :mod:`gnn_mp_envs.baselines.ompl_runner`.

    gnn-mp benchmark --task maze2d --samplers uniform,goal-bias --problems 30 --seed 0 \\
        --json results/maze2d.json --plot results/maze2d.png
    gnn-mp benchmark --suite default --out results/      # what `make benchmark` runs

Files, by job: :mod:`.args` (the flags, one dataclass, and their checks), :mod:`.runs` (one
run through :func:`gnn_mp_envs.rollout.rollout`; all runs, serially or in workers),
:mod:`.stats` (summaries and the JSON report), :mod:`.tables`, :mod:`.plots`,
:mod:`.ompl_rows` (OMPL rows and logs), :mod:`.outputs` (run + print + write) and
:mod:`.suites`. The ``--json`` schema is documented in ``docs/results.md``.
"""

from train.benchmark.args import (
                                  OMPL_PREFIX,
                                  BenchmarkArgs,
                                  BenchmarkError,
                                  check_ompl,
                                  is_ompl,
                                  ompl_available,
                                  ompl_rows_for,
                                  validate_args,
)
from train.benchmark.ompl_rows import run_ompl_rows, write_ompl_logs
from train.benchmark.outputs import benchmark, write_outputs
from train.benchmark.plots import plot_report, render_growth
from train.benchmark.runs import BenchmarkIncomplete, run_benchmark, run_episode
from train.benchmark.stats import METRICS, build_report, sampler_summary, summarize
from train.benchmark.suites import SUITES, SuiteEntry, run_suite
from train.benchmark.tables import format_table

__all__ = ["METRICS", "OMPL_PREFIX", "SUITES", "BenchmarkArgs", "BenchmarkError", "BenchmarkIncomplete", "SuiteEntry",
           "benchmark", "build_report", "check_ompl", "format_table", "is_ompl", "ompl_available",
           "ompl_rows_for", "plot_report", "render_growth", "run_benchmark", "run_episode",
           "run_ompl_rows", "run_suite", "sampler_summary", "summarize", "validate_args", "write_ompl_logs",
           "write_outputs"]
