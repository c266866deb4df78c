"""Choose a learned sampler's batch (``samples_per_step``) and its share of uniform samples on split ``val``.

A sampler with ``samples_per_step=K`` proposes ``K`` samples from one forward over the tree as it stands
(:meth:`~agents.samplers.base.ModelSampler.act_batch`), and the planner consumes them in one compiled call
(``gym.make(id, samples_per_step=K)``): a larger ``K`` pays the forward and the step once per ``K``
samples, but the later samples of a batch do not see the nodes the earlier ones added (staleness: more
iterations). For each candidate pair ``(K, uniform_mix)``, problems ``0..N-1`` of split ``val`` (for tasks
with scenes, the training scenes' val problems) are planned under the benchmark's seeding rule in one
process, beside the reference rows (uniform and goal-bias at their own batch). Wall time, inference
included, is each problem's fastest of ``--repeats`` runs (the counters of a seed do not change between
repeats). Among the pairs whose success rate is no lower than uniform's, the one with the lowest median
wall time wins; pairs within 5% of it are a tie, broken by the smaller ``K``, then the larger
``uniform_mix`` (then the smaller ``refresh_growth``). With ``--refresh-growth`` (the tree GNN's: how
far the tree may grow before a batch reads it again) each pair is tried with each of its values too.
``--write`` stores the choice in the shipped checkpoint's ``meta["sampler"]`` and its
sidecar, with this table and its command (``batch_tuning``).

    .venv/bin/python -m tools.tune_batch --sampler gnn --task panda-mbm --problems 50 --batches 1,4,16,64 \\
        --uniform-mix 0.1,0.25
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.registry import load_sampler
from gnn_mp_envs.evaluation import evaluation_env, plan_problem
from train.args import OneLineParser, add_dataclass_arguments, arg, from_namespace, positive_int, seed_int
from tools.shipped_settings import store_tuned_setting, tool_command

#: Pairs within this factor of the fastest median wall time are a tie.
TIE = 1.05


def _floats(text: str, flag: str = "--uniform-mix", high: float = 1.0, what: str = "shares in [0, 1]") -> list[float]:
    """The comma-separated values of ``flag``, each finite and in ``[0, high]`` (refused in one line otherwise)."""
    values = [float(v) for v in str(text).split(",") if v.strip()]
    if not values or not all(math.isfinite(v) and 0.0 <= v <= high for v in values):
        raise ValueError(f"{flag} takes {what}, got {text!r}")
    return values


@dataclass
class Args:
    """Flags of ``python -m tools.tune_batch``."""

    sampler: str = arg("gnn", "learned sampler (gnn, cvae, gnn-cvae)")
    task: str = arg("panda-mbm", "task")
    batches: list[int] = arg([1, 4, 16, 64], "samples_per_step values to try")
    uniform_mix: str = arg("", "uniform_mix values to try, comma-separated (default: the stored one)")
    refresh_growth: str = arg("", "refresh_growth values to try (the tree GNN's), comma-separated (default: not "
                                  "varied)")
    problems: int = arg(50, "validation problems 0..N-1", parse=positive_int)
    seed: int = arg(0, "root seed of the problems' sampler seeds", parse=seed_int)
    repeats: int = arg(1, "timing repeats per problem (the fastest counts)", parse=positive_int)
    references: str = arg("uniform,goal-bias", "classical rows planned beside, at their own batch")
    checkpoint: str | None = arg(None, "weights to tune (default: the shipped ones); --write needs the shipped ones")
    write: bool = arg(False, "store the chosen pair in the shipped checkpoint and its sidecar")


def measure(env_cache: dict, name: str, task: str, problems: int, seed: int, repeats: int, checkpoint: str | None,
            **settings: Any) -> dict[str, Any]:
    """One row: per problem the counters and the fastest wall time of ``repeats`` runs; medians over problems."""
    sampler = load_sampler(name, task=task, seed=0, checkpoint=checkpoint, **settings)
    k = int(getattr(sampler, "samples_per_step", 1))
    if k not in env_cache:
        env_cache[k] = evaluation_env(task, "val", samples_per_step=k)
    env = env_cache[k]
    plan_problem(env, sampler, 0, seed)                  # first calls (compilation, caches) outside the timing
    forward0 = getattr(sampler, "forward_time_s", 0.0)
    runs = []
    for i in range(problems):
        best = None
        for _ in range(repeats):
            r = plan_problem(env, sampler, i, seed)
            if best is None or r.wall_time_s < best.wall_time_s:
                best = r
        runs.append(best)
    wall = np.array([r.wall_time_s for r in runs])
    sampler_time = sum(max(r.wall_time_s - r.env_time_s, 0.0) for r in runs)
    return {"samples_per_step": k, "success_rate": float(np.mean([r.success for r in runs])),
            "median_iterations": float(np.median([r.iterations for r in runs])),
            "mean_iterations": float(np.mean([r.iterations for r in runs])),
            "median_collision_checks": float(np.median([r.collision_checks for r in runs])),
            "median_wall_ms": 1e3 * float(np.median(wall)), "total_wall_s": float(wall.sum()),
            "sampler_share": sampler_time / max(float(wall.sum()), 1e-12),
            "forward_s": (getattr(sampler, "forward_time_s", 0.0) - forward0) / repeats}


def choose(rows: dict[str, dict[str, Any]], pairs: dict[str, tuple[int, float, float | None]], floor: float) -> str:
    """The rule of the module docstring: the label of the chosen pair."""
    allowed = [label for label in pairs if rows[label]["success_rate"] >= floor] or list(pairs)
    fastest = min(rows[label]["median_wall_ms"] for label in allowed)
    tied = [label for label in allowed if rows[label]["median_wall_ms"] <= TIE * fastest]
    return min(tied, key=lambda label: (pairs[label][0], -pairs[label][1], pairs[label][2] or 0.0))


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m tools.tune_batch", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    if args.write and args.checkpoint is not None:
        raise ValueError("--write stores the choice in the shipped checkpoint: leave out --checkpoint")
    if not all(1 <= int(k) for k in args.batches):
        raise ValueError(f"--batches takes integers >= 1, got {args.batches}")
    stored = load_sampler(args.sampler, task=args.task, seed=0, checkpoint=args.checkpoint)
    mixes = _floats(args.uniform_mix) if args.uniform_mix else [stored.uniform_mix]
    growths = (_floats(args.refresh_growth, "--refresh-growth", math.inf, "finite fractions >= 0")
               if args.refresh_growth else [None])
    if args.refresh_growth:                              # refused here, before any row is measured
        load_sampler(args.sampler, task=args.task, seed=0, checkpoint=args.checkpoint, refresh_growth=max(growths))
    envs: dict[int, Any] = {}
    rows: dict[str, dict[str, Any]] = {}
    for name in [r for r in args.references.split(",") if r]:
        rows[name] = measure(envs, name, args.task, args.problems, args.seed, args.repeats, None)
    pairs = {f"K={k} uniform_mix={mix:g}" + ("" if f is None else f" refresh_growth={f:g}"): (int(k), float(mix), f)
             for k, mix, f in itertools.product(args.batches, mixes, growths)}
    for label, (k, mix, f) in pairs.items():
        extra = {} if f is None else {"refresh_growth": f}
        rows[label] = measure(envs, args.sampler, args.task, args.problems, args.seed, args.repeats, args.checkpoint,
                              samples_per_step=k, uniform_mix=mix, **extra)
    floor = rows["uniform"]["success_rate"] if "uniform" in rows else 0.0
    print(f"{args.sampler} on {args.task}, {args.problems} val problems, seed {args.seed}, fastest of {args.repeats} "
          f"(medians; sampler: its share of the wall time, inference included)")
    print(f"| row | K | solved | iterations (median / mean) | collision checks | wall time [ms] | total [s] | sampler |")
    print("|---|---|---|---|---|---|---|---|")
    for label, r in rows.items():
        print(f"| {label} | {r['samples_per_step']} | {r['success_rate']:.0%} | {r['median_iterations']:,.0f} / "
              f"{r['mean_iterations']:,.0f} | {r['median_collision_checks']:,.0f} | {r['median_wall_ms']:.2f} | "
              f"{r['total_wall_s']:.2f} | {r['sampler_share']:.0%} |")
    chosen = choose(rows, pairs, floor)
    k, mix, growth = pairs[chosen]
    setting = {"samples_per_step": k, "uniform_mix": mix, **({} if growth is None else {"refresh_growth": growth})}
    print("chosen: " + " ".join(f"{key}={value:g}" for key, value in setting.items()))
    if args.write:
        store_tuned_setting(args.sampler, args.task, setting, "batch_tuning",
                            {"command": tool_command("tools.tune_batch", argv), "val_problems": args.problems,
                             "rule": "lowest median wall time (fastest of the repeats per problem) among the pairs "
                                     "with success no lower than uniform's; within 5%: smaller K, then more uniform"
                                     + ("" if growth is None else ", then the smaller refresh_growth"),
                             "rows": rows})
    for env in envs.values():
        env.close()
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
