"""Compare a learned sampler's settings or checkpoints with uniform on validation kinds (split ``val``):
the in-distribution problems and the task's held-out validation scenes, never the OOD test suites.

    python -m tools.compare_on_kinds --task maze2d --checkpoint runs/tree/.../model.pt \\
        --configs '{"fixed": {}, "adaptive": {"adaptive": true}}' --problems 40

Per kind and configuration it prints ``median ratio / paired ratio (success, model share)``: the
sampler's median headline figure (``TaskSpec.headline_metric``) over uniform's, and the geometric
mean over problems of the per-problem ratio (the same problem and seed for both samplers: less
noisy than a ratio of medians); the model share is the fraction of samples the adaptive mixture
drew from the model. The last column is the paired geometric mean over the validation kinds.
This is how the training ablations in docs/journal/2026-12-05-tree-sampler-training.md were compared.
"""

from __future__ import annotations

import argparse
import json
import math
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def run(job: tuple) -> tuple:
    """Plan problems ``indices`` of one kind with one sampler (a worker process)."""
    task, split, scene, name, settings, checkpoint, indices, seed = job
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    env = evaluation_env(task, split, scene=scene)
    kwargs = dict(settings)
    if checkpoint and name != "uniform":
        kwargs["checkpoint"] = checkpoint
    sampler = load_sampler(name, task=task, seed=0, **kwargs)
    out = []
    for i in indices:
        r = plan_problem(env, sampler, i, seed)
        adaptive = getattr(sampler, "adaptive", None)
        out.append({"i": i, "success": r.success, "nodes_expanded": r.nodes_expanded,
                    "collision_checks": r.collision_checks,
                    **({"drawn": adaptive.drawn.tolist()} if adaptive is not None else {})})
    env.close()
    return job[:5], out


def main(argv: list[str] | None = None) -> int:
    from train.args import positive_int, seed_int, worker_count
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="maze2d")
    p.add_argument("--sampler", default="gnn")
    p.add_argument("--configs", default='{"fixed": {}}', help="JSON: name -> sampler settings")
    p.add_argument("--kinds", default=None, help="comma-separated scenes ('-' = in-distribution; default: "
                   "in-distribution and the task's validation scenes)")
    p.add_argument("--split", default="val", choices=("train", "val"))
    p.add_argument("--problems", type=positive_int, default=40)
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--seed", type=seed_int, default=0)
    p.add_argument("--workers", type=worker_count, default=2)
    p.add_argument("--chunk", type=positive_int, default=5, help="problems per job")
    p.add_argument("--json", default=None, help="write every run's counters here")
    args = p.parse_args(argv)
    from gnn_mp_envs.registration import task_spec
    spec = task_spec(args.task)
    kinds = args.kinds.split(",") if args.kinds else ["-", *spec.validation_scenes]
    try:
        configs = json.loads(args.configs)
    except json.JSONDecodeError as exc:
        p.error(f"--configs: not JSON ({exc})")
    if not isinstance(configs, dict) or not configs or not all(isinstance(v, dict) for v in configs.values()):
        p.error(f"--configs: expected a JSON object of name -> settings objects, got {args.configs!r}")
    metric = spec.headline_metric
    jobs = []
    for kind in kinds:
        scene = None if kind == "-" else kind
        for lo in range(0, args.problems, args.chunk):
            idx = list(range(lo, min(args.problems, lo + args.chunk)))
            jobs.append((args.task, args.split, scene, "uniform", {}, None, idx, args.seed))
            jobs += [(args.task, args.split, scene, args.sampler, settings, args.checkpoint, idx, args.seed)
                     for settings in configs.values()]
    results: dict = {}
    with ProcessPoolExecutor(args.workers) as ex:
        for (task, split, scene, name, settings), out in ex.map(run, jobs):
            key = (scene or "-", "uniform" if name == "uniform" else json.dumps(settings, sort_keys=True))
            results.setdefault(key, []).extend(out)
    print(f"{args.sampler} on {args.task} ({args.checkpoint or 'shipped weights'}), split {args.split}: "
          f"{metric} median ratio / paired ratio to uniform (success, model share)")
    for cname, settings in configs.items():
        cells, logs = [], []
        for kind in kinds:
            uniform = results[(kind, "uniform")]
            runs = results[(kind, json.dumps(settings, sort_keys=True))]
            base = {r["i"]: r[metric] for r in uniform}
            ratio = np.median([r[metric] for r in runs]) / np.median(list(base.values()))
            paired = math.exp(np.mean([math.log(r[metric] / base[r["i"]]) for r in runs]))
            share = ""
            if "drawn" in runs[0]:
                drawn = np.array([r["drawn"] for r in runs]).sum(0)
                share = f", m{drawn[1] / max(drawn.sum(), 1):.2f}"
            cells.append(f"{kind}: {ratio:.2f}/{paired:.2f}p ({np.mean([r['success'] for r in runs]):.0%}{share})")
            if kind != "-":
                logs.append(math.log(paired))
        geo = math.exp(sum(logs) / len(logs)) if logs else float("nan")
        print(f"  {cname:>12}: " + "  ".join(cells) + f"  | kinds, paired: {geo:.2f}")
    print("  uniform medians: " + "  ".join(
        f"{k}: {np.median([r[metric] for r in results[(k, 'uniform')]]):.0f}" for k in kinds))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({f"{k[0]}|{k[1]}": v for k, v in results.items()}, f)
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
