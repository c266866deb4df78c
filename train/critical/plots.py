"""The prediction figure (one row per problem, one column per model)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agents.critical.data import label_positions
from gnn_mp_envs.critical.dataset import CriticalProblems
from gnn_mp_envs.critical.halton import HaltonGraph
from gnn_mp_envs.utils.io import atomic_path

#: The heat map shows node log-probabilities from the top node's down to HEAT_RANGE below it.
HEAT_RANGE = 6.0


def plot_predictions(sets: dict[str, CriticalProblems], preds: dict[str, dict[str, tuple]],
                     graph: HaltonGraph, path: str | Path, per_set: int = 2,
                     chosen: dict[str, dict[str, dict]] | None = None, k: int = 10) -> None:
    """Walls, blobs, labels (crosses), point predictions (stars), the node distribution (heat
    map over the graph's nodes, log scale), decoded CVAE samples (dots) and the k chosen samples (circles).

    ``sets``: set name -> problems; ``preds``: set name -> model name -> (points, samples)
    or (points, samples, log node scores); ``chosen``: set name -> model name -> k -> per
    problem (k', 2) states. The first ``per_set`` problems of each set are drawn.
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
            entry = preds[key][name]
            point, samples = entry[0], entry[1]
            scores = entry[2] if len(entry) > 2 else None
            if scores is not None:
                # log-probability relative to the top node, clipped at e^-HEAT_RANGE
                rel = np.clip(scores[i] - scores[i].max() + HEAT_RANGE, 0, HEAT_RANGE) / HEAT_RANGE
                ax.scatter(graph.nodes[:, 0], graph.nodes[:, 1], s=4, c=rel, cmap="Blues", vmin=0, vmax=1,
                           linewidths=0, zorder=1)
            for w in probs.walls[i]:
                ax.add_patch(Rectangle(w[:2], w[2] - w[0], w[3] - w[1], color="0.25", zorder=2))
            for b in probs.blobs[i]:
                ax.add_patch(Circle(b[:2], b[2], color="0.45", zorder=2))
            if samples is not None and scores is None:
                ax.scatter(samples[i, :16, 0], samples[i, :16, 1], s=6, c="tab:blue", alpha=0.5,
                           label="samples", zorder=3)
            if chosen is not None and name in chosen.get(key, {}):
                sel = np.reshape(chosen[key][name][k][i], (-1, 2))
                ax.scatter(sel[:, 0], sel[:, 1], s=28, facecolors="none", edgecolors="tab:purple",
                           linewidths=0.9, label=f"top {k}", zorder=4)
            ax.scatter(lab[:, 0], lab[:, 1], s=14, marker="x", c="k", label="bottleneck", zorder=5)
            ax.scatter(*point[i], s=50, marker="*", c="tab:orange", label="point", zorder=5)
            ax.scatter(*probs.start[i], s=25, c="tab:green", zorder=5)
            ax.scatter(*probs.goal[i], s=25, c="tab:red", zorder=5)
            ax.set(xlim=(0, 1), ylim=(0, 1), xticks=[], yticks=[], aspect="equal")
            if r == 0:
                ax.set_title(name)
            if c == 0:
                ax.set_ylabel({"test": "in-dist", "blob": "blob maps"}.get(key, key))
    axes[0][0].legend(loc="lower left", fontsize=5)
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120)
    finally:
        plt.close(fig)
