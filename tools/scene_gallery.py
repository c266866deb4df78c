"""Pictures of a task's scene families: the first problems of each, planned by the uniform sampler.

    python -m tools.scene_gallery --task maze2d --out docs/img/ood_maze2d.png
    python -m tools.scene_gallery --task arm --roles ood,val --problems 2 --out docs/img/ood_arm.png

One row per family (its role in brackets: default, train, val, ood), ``--problems`` columns; each
picture is the environment's ``render()`` after a uniform-sampler run of split ``--split``
(problems ``0..N-1``, the benchmark's seeding rule), so the tree shows how hard the problem is.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROLE_ORDER = ("default", "train", "val", "ood")


def scene_roles(task: str) -> dict[str, str]:
    """Scene -> role (``default``, ``train``, ``val`` or ``ood``) from the task's spec."""
    from gnn_mp_envs.registration import task_spec
    spec = task_spec(task)
    roles = {}
    for scene in spec.scenes:
        if scene in spec.ood_scenes:
            roles[scene] = "ood"
        elif scene in spec.validation_scenes:
            roles[scene] = "val"
        elif scene == spec.default_scene("test"):
            roles[scene] = "default"
        else:
            roles[scene] = "train"
    return roles


def gallery(task: str, roles: list[str], problems: int, split: str, seed: int, out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    rows = [(scene, role) for scene, role in scene_roles(task).items() if role in roles]
    rows.sort(key=lambda r: ROLE_ORDER.index(r[1]))
    fig, axes = plt.subplots(len(rows), problems, figsize=(2.2 * problems, 2.2 * len(rows)), squeeze=False)
    sampler = load_sampler("uniform", task=task, seed=seed)
    for r, (scene, role) in enumerate(rows):
        env = evaluation_env(task, split, scene=scene, render=True)
        try:
            for c in range(problems):
                record = plan_problem(env, sampler, c, seed)
                ax = axes[r, c]
                ax.imshow(np.asarray(env.render()))
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(f"{record.nodes_expanded} nodes" + ("" if record.success else ", unsolved"), fontsize=7)
                if c == 0:
                    ax.set_ylabel(f"{scene}\n[{role}]", fontsize=8)
        finally:
            env.close()
    fig.suptitle(f"{task} scene families, split {split}, problems 0..{problems - 1}, uniform sampler", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.985))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)
    from PIL import Image        # a palette image: a tenth of the RGB file, the same picture to the eye
    Image.open(out).convert("RGB").quantize(colors=64).save(out, optimize=True)
    return out


def main(argv: list[str] | None = None) -> int:
    from train.args import figure_path, seed_int, size_int
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="maze2d")
    parser.add_argument("--roles", default="default,train,val,ood", help="comma-separated roles to show")
    parser.add_argument("--problems", type=size_int, default=3)
    parser.add_argument("--split", default="test", choices=("train", "val", "test"))
    parser.add_argument("--seed", type=seed_int, default=0)
    parser.add_argument("--out", type=figure_path, required=True)
    args = parser.parse_args(argv)
    roles = [r.strip() for r in args.roles.split(",") if r.strip()]
    unknown = sorted(set(roles) - set(ROLE_ORDER))
    if unknown or not roles:
        parser.error(f"unknown role(s) {unknown or args.roles!r}; known: {', '.join(ROLE_ORDER)}")
    print(gallery(args.task, roles, args.problems, args.split, args.seed, args.out))
    return 0


if __name__ == "__main__":
    from tools import run_script
    raise SystemExit(run_script(main))
