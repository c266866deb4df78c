"""Shared pieces of ``rgb_array`` drawings with matplotlib (Agg, no screen needed).

Task-specific drawings live with their task (``Maze2DTask.render_rgb``,
``PendulumTask.render_rgb``, the arm's pybullet renderer); they use the figure, tree and
RGB helpers here. This module imports no task.
"""

from __future__ import annotations

import numpy as np

from gnn_mp_envs.core.tree import TreeStore

TREE_COLORS = ("tab:blue", "tab:orange")


def figure(size: float = 4.0):
    import matplotlib
    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    fig = Figure(figsize=(size, size), dpi=100)
    return fig, fig.add_subplot(1, 1, 1)


def to_rgb(fig) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def _tree_segments(tree: TreeStore, wrap_period: float | None = None) -> list[tuple[int, np.ndarray]]:
    """(tree id, (k, 2, 2) segments) per tree; segments that wrap an angle are dropped."""
    n = len(tree)
    child = np.flatnonzero(tree.parent[:n] >= 0)
    seg = np.stack([tree.states[tree.parent[child], :2], tree.states[child, :2]], axis=1)
    keep = np.ones(len(child), dtype=bool)
    if wrap_period is not None:
        keep = np.abs(seg[:, 0, 0] - seg[:, 1, 0]) < wrap_period / 2
    ids = tree.tree_id[child]
    return [(t, seg[keep & (ids == t)]) for t in range(tree.num_trees)]


def draw_tree(ax, tree: TreeStore, wrap_period: float | None = None) -> None:
    from matplotlib.collections import LineCollection
    for t, seg in _tree_segments(tree, wrap_period):
        ax.add_collection(LineCollection(seg, colors=TREE_COLORS[t], linewidths=0.6, alpha=0.8))
    n = len(tree)
    ax.scatter(tree.states[:n, 0], tree.states[:n, 1], s=1.5, c="k", alpha=0.5)
