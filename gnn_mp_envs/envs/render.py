"""``rgb_array`` drawings of trees with matplotlib (Agg, no screen needed)."""

from __future__ import annotations

import numpy as np

from gnn_mp_envs.core.problem import Problem
from gnn_mp_envs.core.tree import TreeStore

TREE_COLORS = ("tab:blue", "tab:orange")


def _figure(size: float = 4.0):
    import matplotlib
    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    fig = Figure(figsize=(size, size), dpi=100)
    return fig, fig.add_subplot(1, 1, 1)


def _to_rgb(fig) -> np.ndarray:
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


def render_maze2d(problem: Problem, tree: TreeStore, path: np.ndarray | None) -> np.ndarray:
    """Walls (grey), blobs, the tree(s), start (green), goal (red) and the path (magenta)."""
    from matplotlib.patches import Circle, Rectangle
    fig, ax = _figure()
    maze = problem.maze
    for x0, y0, x1, y1 in maze.walls:
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color="0.35"))
    for cx, cy, r in maze.blobs:
        ax.add_patch(Circle((cx, cy), r, color="0.5"))
    draw_tree(ax, tree)
    if path is not None:
        ax.plot(path[:, 0], path[:, 1], color="m", linewidth=2.0)
    ax.plot(*problem.start, "o", color="tab:green", markersize=8)
    ax.plot(*problem.goal, "*", color="tab:red", markersize=12)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    fig.tight_layout()
    return _to_rgb(fig)


def render_pendulum(problem: Problem, tree: TreeStore, path: np.ndarray | None) -> np.ndarray:
    """The tree in phase space (theta, omega), the goal box and the path."""
    from matplotlib.patches import Rectangle
    from gnn_mp_envs.tasks import pendulum as pd
    fig, ax = _figure()
    draw_tree(ax, tree, wrap_period=2 * np.pi)
    g = problem.goal
    ax.add_patch(Rectangle((g[0] - pd.GOAL_ANGLE_TOLERANCE, g[1] - pd.GOAL_SPEED_TOLERANCE),
                           2 * pd.GOAL_ANGLE_TOLERANCE, 2 * pd.GOAL_SPEED_TOLERANCE,
                           color="tab:red", alpha=0.3))
    if path is not None:
        jumps = np.flatnonzero(np.abs(np.diff(path[:, 0])) > np.pi) + 1
        for piece in np.split(path, jumps):
            ax.plot(piece[:, 0], piece[:, 1], color="m", linewidth=2.0)
    ax.plot(*problem.start, "o", color="tab:green", markersize=8)
    ax.plot(*g, "*", color="tab:red", markersize=12)
    ax.set_xlim(-np.pi, np.pi)
    ax.set_ylim(-pd.MAX_SPEED, pd.MAX_SPEED)
    ax.set_xlabel("theta [rad]")
    ax.set_ylabel("omega [rad/s]")
    fig.tight_layout()
    return _to_rgb(fig)
