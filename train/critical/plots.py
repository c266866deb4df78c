"""The paper-style prediction figure (one row per problem, one column per model)."""

from __future__ import annotations

from pathlib import Path

from agents.critical_data import label_positions
from gnn_mp_envs.critical.dataset import CriticalProblems
from gnn_mp_envs.critical.halton import HaltonGraph
from gnn_mp_envs.utils.io import atomic_path


def plot_predictions(sets: dict[str, CriticalProblems], preds: dict[str, dict[str, tuple]],
                     graph: HaltonGraph, path: str | Path, per_set: int = 2) -> None:
    """Walls, blobs, labels (crosses), point predictions (stars) and CVAE samples (dots).

    ``sets``: set name -> problems; ``preds``: set name -> model name -> (points, samples).
    The first ``per_set`` problems of each set are drawn.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    names = list(next(iter(preds.values())).keys())
    rows = [(key, i) for key in sets for i in range(min(per_set, len(sets[key])))]
    fig, axes = plt.subplots(len(rows), max(len(names), 1), figsize=(2.4 * max(len(names), 1), 2.4 * len(rows)),
                             squeeze=False)
    for r, (key, i) in enumerate(rows):
        probs = sets[key]
        lab = label_positions(probs, graph, i)
        for c, name in enumerate(names):
            ax = axes[r][c]
            for w in probs.walls[i]:
                ax.add_patch(Rectangle(w[:2], w[2] - w[0], w[3] - w[1], color="0.25"))
            for b in probs.blobs[i]:
                ax.add_patch(Circle(b[:2], b[2], color="0.45"))
            point, samples = preds[key][name]
            if samples is not None:
                ax.scatter(samples[i, :, 0], samples[i, :, 1], s=6, c="tab:blue", alpha=0.5, label="samples")
            ax.scatter(lab[:, 0], lab[:, 1], s=14, marker="x", c="k", label="bottleneck")
            ax.scatter(*point[i], s=50, marker="*", c="tab:orange", label="prediction")
            ax.scatter(*probs.start[i], s=25, c="tab:green")
            ax.scatter(*probs.goal[i], s=25, c="tab:red")
            ax.set(xlim=(0, 1), ylim=(0, 1), xticks=[], yticks=[], aspect="equal")
            if r == 0:
                ax.set_title(name)
            if c == 0:
                ax.set_ylabel("in-dist" if key == "test" else "blob maps")
    axes[0][0].legend(loc="lower left", fontsize=5)
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120)
    finally:
        plt.close(fig)
