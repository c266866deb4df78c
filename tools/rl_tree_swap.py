"""Does an RL sampler use the tree? Show it another problem's tree and measure what changes.

For each of problems ``0..N-1`` of split ``val`` (``i``), a *shadow* environment plans, in
lockstep with the real one, problem ``j`` (the next problem whose obstacles admit ``i``'s start
and goal) with ``i``'s start and goal, so the shadow tree is a tree of the same query among other
obstacles; every sample the sampler proposes is sent to both environments. A task without
obstacles (the pendulum) has no such problem, and the same samples would grow the same tree
whatever the goal (the dynamics do not depend on it), so there the shadow plans problem ``i``
itself from uniform samples of its own stream: another tree of the same query. Two figures:

* **the action distribution**: at every step the policy scores the same candidate states twice,
  with their features relative to the real tree and relative to the shadow tree; reported are the
  mean KL divergence ``KL(p_real || p_shadow)`` and total variation between the two categoricals,
  next to ``KL(p_real || uniform)`` (how far the policy is from a blind pick at all). A continuous
  policy: the KL of its two Gaussians and the shift of their means over the real one's scale;
* **performance**: the real problem planned while the sampler sees the shadow tree (the samples
  still go to the real planner), against the same problem planned with its own tree (the
  benchmark's seeding rule, ``plan_problem``): median nodes, collision checks, success.

    .venv/bin/python -m tools.rl_tree_swap --task maze2d --problems 20 --json swap.json --plot swap.png
"""

from __future__ import annotations

import copy
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.registry import load_sampler
from gnn_mp_envs.evaluation import evaluation_env, plan_problem, problem_seed
from gnn_mp_envs.utils.io import atomic_write_text
from train.args import OneLineParser, add_dataclass_arguments, arg, from_namespace, positive_int, seed_int


@dataclass
class Args:
    """Flags of ``python -m tools.rl_tree_swap``."""

    task: str = arg("maze2d", "task")
    sampler: str = arg("rl-ppo", "RL sampler (rl-ppo, rl-ppo-torchrl, ...)")
    checkpoint: Path | None = arg(None, "policy checkpoint (default: the shipped weights)")
    problems: int = arg(20, "validation problems 0..N-1", parse=positive_int)
    seed: int = arg(0, "root seed of the problems' sampler seeds", parse=seed_int)
    max_steps: int = arg(4000, "planner iterations per problem (then a failure)", parse=positive_int)
    json: Path | None = arg(None, "write the figures (and per-problem rows) here")
    plot: Path | None = arg(None, "write a figure: per-problem nodes, own tree vs shadow tree")


def shadow_problem(task: Any, real: Any, index: int, count: int, split: str = "val") -> tuple[Any, int, bool]:
    """``(problem, j, resampled)``: problem ``j != index`` with ``real``'s start and goal among its own
    obstacles (the first ``j`` after ``index`` whose obstacles admit them), or, for a task without
    obstacles, ``real`` itself (``resampled``: its shadow grows from uniform samples of its own)."""
    if not len(task.obstacle_rows(real)):
        return real, index, True
    for step in range(1, 200):
        j = index + step
        other = copy.copy(task.problem(split, j))
        other.start, other.goal = np.array(real.start, copy=True), np.array(real.goal, copy=True)
        try:
            other.validate()
        except ValueError:
            continue
        if bool(np.all(other.is_state_valid(np.stack([other.start, other.goal])))):
            return other, j, False
    raise RuntimeError(f"no validation problem admits problem {index}'s start and goal")


def categorical(logits: np.ndarray) -> np.ndarray:
    p = np.exp(logits - logits.max())
    return p / p.sum()


def kl(p: np.ndarray, q: np.ndarray) -> float:
    return float(np.sum(p * (np.log(np.maximum(p, 1e-12)) - np.log(np.maximum(q, 1e-12)))))


def gaussian_kl(m1: np.ndarray, s1: np.ndarray, m2: np.ndarray, s2: np.ndarray) -> float:
    """KL of two diagonal Gaussians, ``KL(N(m1, s1) || N(m2, s2))``."""
    return float(np.sum(np.log(s2 / s1) + (s1 ** 2 + (m1 - m2) ** 2) / (2 * s2 ** 2) - 0.5))


def swap_run(sampler: Any, env: Any, shadow_env: Any, index: int, args: Args) -> dict[str, Any]:
    """Plan problem ``index`` while the sampler sees the shadow tree; per-step distribution changes."""
    from gnn_mp_envs.envs.candidates import CandidateSet
    from gnn_mp_envs.envs.wrappers import tree_view
    task = env.task
    real = task.problem("val", index)
    other, j, resampled = shadow_problem(shadow_env.task, real, index, args.problems)
    s = problem_seed(args.seed, index)
    shadow_rng = np.random.default_rng([s, 0x5AD0])      # the resampled shadow's own uniform samples
    sampler.reset(s)
    obs, info = env.reset(seed=s, options={"index": index})
    shadow, _ = shadow_env.reset(seed=s, options={"problem": other})
    low, high = sampler.low, sampler.high
    pick = hasattr(sampler, "candidate_set")
    probe = CandidateSet(low, high, prior=sampler.new_prior(), **sampler.candidate_set.config()) if pick else None
    kls, tvs, blind, shifts = [], [], [], []
    captured: dict[str, Any] = {}
    if pick:
        propose = sampler.candidate_set.propose

        def capturing(o, rng):
            captured["cands"], captured["feats"] = propose(o, rng)
            return captured["cands"], captured["feats"]
        sampler.candidate_set.propose = capturing
    shadow_done = False
    try:
        for _ in range(args.max_steps):
            seen = shadow
            captured.clear()
            x = sampler.act(seen)
            if pick and "cands" in captured:           # the model was consulted this step
                n = probe._ingest(obs)
                active = int(obs["active_tree"][0])
                target = probe._start if active == 1 else probe._goal
                own = probe.features(captured["cands"].astype(np.float64), n, active, target)
                p_real = categorical(sampler.logits(obs, own).astype(np.float64))
                p_shadow = categorical(sampler.logits(seen, captured["feats"]).astype(np.float64))
                kls.append(kl(p_real, p_shadow))
                tvs.append(0.5 * float(np.abs(p_real - p_shadow).sum()))
                blind.append(kl(p_real, np.full(len(p_real), 1.0 / len(p_real))))
            elif not pick:
                m1, s1 = sampler.params(obs)
                m2, s2 = sampler.params(seen)
                kls.append(gaussian_kl(m1.astype(np.float64), s1.astype(np.float64), m2.astype(np.float64),
                                       s2.astype(np.float64)))
                shifts.append(float(np.mean(np.abs(m1 - m2) / s1)))
            if pick:
                probe.record(obs, x)
            obs, _, terminated, truncated, info = env.step(x)
            if not shadow_done:
                shadow_x = (low + (high - low) * shadow_rng.random(len(low))).astype(np.float32) if resampled else x
                shadow, _, shadow_term, shadow_trunc, _ = shadow_env.step(shadow_x)
                shadow_done = bool(shadow_term or shadow_trunc)    # then the shadow tree stays as it is
            if terminated or truncated:
                break
    finally:
        if pick:
            sampler.candidate_set.propose = propose
    del tree_view
    out = {"problem": index, "shadow_problem": j, "resampled": resampled, "success": bool(info["is_success"]),
           "nodes": int(info["nodes_expanded"]), "collision_checks": int(info["collision_checks"]),
           "steps_scored": len(kls), "mean_kl": float(np.mean(kls)) if kls else None,
           "mean_tv": float(np.mean(tvs)) if tvs else None,
           "mean_kl_to_uniform": float(np.mean(blind)) if blind else None}
    if shifts:
        out["mean_shift_over_scale"] = float(np.mean(shifts))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m tools.rl_tree_swap", description=__doc__.splitlines()[0])
    add_dataclass_arguments(parser, Args)
    args = from_namespace(Args, parser.parse_args(argv))
    sampler = load_sampler(args.sampler, task=args.task, seed=0, checkpoint=args.checkpoint)
    env = evaluation_env(args.task, "val")
    shadow_env = evaluation_env(args.task, "val")
    rows = []
    for i in range(args.problems):
        own = plan_problem(env, sampler, i, args.seed, max_steps=args.max_steps)
        swapped = swap_run(sampler, env, shadow_env, i, args)
        rows.append({**swapped, "own_success": own.success, "own_nodes": own.nodes_expanded,
                     "own_collision_checks": own.collision_checks})
        print(f"problem {i:>3} (shadow {swapped['shadow_problem']:>3}): nodes {own.nodes_expanded:>5} own tree, "
              f"{swapped['nodes']:>5} shadow tree; mean KL {swapped['mean_kl'] or 0:.3f}", flush=True)

    def med(key: str) -> float:
        return float(np.median([r[key] for r in rows]))

    weights = np.array([r["steps_scored"] for r in rows], float)
    summary = {
        "task": args.task, "sampler": args.sampler, "problems": args.problems, "seed": args.seed,
        "own_tree": {"success_rate": float(np.mean([r["own_success"] for r in rows])),
                     "median_nodes": med("own_nodes"), "median_collision_checks": med("own_collision_checks")},
        "shadow_tree": {"success_rate": float(np.mean([r["success"] for r in rows])),
                        "median_nodes": med("nodes"), "median_collision_checks": med("collision_checks")},
        "mean_kl": float(np.average([r["mean_kl"] or 0.0 for r in rows], weights=weights)),
    }
    if rows[0].get("mean_tv") is not None:
        summary["mean_tv"] = float(np.average([r["mean_tv"] for r in rows], weights=weights))
        summary["mean_kl_to_uniform"] = float(np.average([r["mean_kl_to_uniform"] for r in rows], weights=weights))
    if "mean_shift_over_scale" in rows[0]:
        summary["mean_shift_over_scale"] = float(np.average([r["mean_shift_over_scale"] for r in rows],
                                                            weights=weights))
    print(json.dumps(summary, indent=2))
    if args.json is not None:
        atomic_write_text(args.json, json.dumps({"summary": summary, "rows": rows}, indent=2) + "\n")
    if args.plot is not None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6, 3.2))
        idx = np.arange(len(rows))
        ax.bar(idx - 0.2, [r["own_nodes"] for r in rows], 0.4, label="own tree")
        ax.bar(idx + 0.2, [r["nodes"] for r in rows], 0.4, label="another problem's tree")
        ax.set_xlabel("val problem")
        ax.set_ylabel("nodes expanded")
        ax.set_yscale("log")
        ax.set_title(f"{args.sampler} on {args.task}: mean KL {summary['mean_kl']:.2f}")
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
    env.close()
    shadow_env.close()
    return 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
