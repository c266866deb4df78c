"""``rgb_array`` images of arm problems with pybullet's TinyRenderer (no screen needed)."""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.tasks.arm.problem import ArmProblem
from gnn_mp_envs.tasks.arm.world import ArmWorld

#: Camera of :func:`render_arm`: eye, target, up (behind and above the robot's right).
CAMERA = ((-0.75, -1.05, 1.15), (0.3, 0.0, 0.1), (0.0, 0.0, 1.0))
_TREE_RGB = (np.array([40, 110, 220]), np.array([240, 140, 30]))
_PATH_RGB = np.array([20, 190, 60])
_START_RGB, _GOAL_RGB = np.array([220, 30, 30]), np.array([30, 160, 30])


def _project(points: np.ndarray, view: np.ndarray, proj: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (N, 2) (column, row) of world points (N, 3); NaN behind the camera."""
    h = np.hstack([points, np.ones((len(points), 1))]) @ (proj @ view).T
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = h[:, :3] / h[:, 3:4]
    px = np.column_stack([(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height])
    px[h[:, 3] <= 0] = np.nan
    return px


def _dots(img: np.ndarray, px: np.ndarray, color: np.ndarray, radius: int = 1) -> None:
    """Draw filled squares of side ``2 radius + 1`` at pixel positions (in place)."""
    px = px[np.isfinite(px).all(axis=1)]
    if not len(px):
        return
    c = np.rint(px).astype(int)
    for dx in range(-radius, radius + 1):
        for dy in range(-radius, radius + 1):
            x, y = c[:, 0] + dx, c[:, 1] + dy
            ok = (x >= 0) & (x < img.shape[1]) & (y >= 0) & (y < img.shape[0])
            img[y[ok], x[ok]] = color


def render_arm(world: ArmWorld, problem: ArmProblem, tree: Any, path: np.ndarray | None,
               width: int = 320, height: int = 240, max_tree_nodes: int = 2000) -> np.ndarray:
    """RGB (height, width, 3) uint8 image of an arm problem (see :meth:`ArmTask.render_rgb`).

    TinyRenderer does not draw debug lines, so tree nodes and the path are projected with
    the camera's view/projection matrices and painted onto the image with numpy.
    """
    p, cid = world.p, world.client
    world.load(problem.scene)
    eye, target, up = CAMERA
    view_l = p.computeViewMatrix(eye, target, up, physicsClientId=cid)
    proj_l = p.computeProjectionMatrixFOV(55.0, width / height, 0.05, 6.0, physicsClientId=cid)
    view = np.array(view_l).reshape(4, 4).T
    proj = np.array(proj_l).reshape(4, 4).T

    def shot(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        world.set_config(q)
        _, _, rgba, _, seg = p.getCameraImage(width, height, view_l, proj_l, renderer=p.ER_TINY_RENDERER,
                                              physicsClientId=cid)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        return rgba[..., :3].copy(), np.asarray(seg).reshape(height, width)

    img, seg_start = shot(problem.start)
    goal_img, seg_goal = shot(problem.goal)
    ghost = (seg_goal & 0xFFFFFF) == world.robot  # pixels of the robot in the goal pose
    ghost &= (seg_goal >= 0)
    img[ghost] = (0.45 * img[ghost] + 0.55 * goal_img[ghost]).astype(np.uint8)
    if tree is not None and len(tree):
        n = len(tree)
        idx = np.arange(n) if n <= max_tree_nodes else np.linspace(0, n - 1, max_tree_nodes).astype(int)
        pts = world.flange_positions(tree.states[idx])
        for t in range(getattr(tree, "num_trees", 1)):
            sel = tree.tree_id[idx] == t
            _dots(img, _project(pts[sel], view, proj, width, height), _TREE_RGB[t % 2], radius=0)
    if path is not None and len(path) > 1:
        dense = [path[0]]
        for a, b in zip(path[:-1], path[1:]):
            k = max(1, int(np.ceil(np.linalg.norm(b - a) / problem.resolution)))
            dense.extend(a + (b - a) * (np.arange(1, k + 1) / k)[:, None])
        px = _project(world.flange_positions(np.array(dense)), view, proj, width, height)
        # Join consecutive points so the trace is a continuous line.
        segs = [px[i] + (px[i + 1] - px[i]) * s for i in range(len(px) - 1) for s in np.linspace(0, 1, 6)]
        _dots(img, np.array(segs), _PATH_RGB, radius=1)
    for q, color in ((problem.start, _START_RGB), (problem.goal, _GOAL_RGB)):
        _dots(img, _project(world.flange_positions(q), view, proj, width, height), color, radius=3)
    return with_legend(img, num_trees=getattr(tree, "num_trees", 1) if tree is not None else 1)


def with_legend(img: np.ndarray, num_trees: int = 2) -> np.ndarray:
    """``img`` with a legend of its colours in the top-left corner, at the same size: the dots
    painted by :func:`render_arm` carry no meaning without it."""
    from matplotlib.lines import Line2D

    from gnn_mp_envs.utils.render import to_rgb
    height, width = img.shape[:2]
    fig = _pixel_figure(width, height)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.imshow(img, interpolation="none")
    ax.axis("off")
    trees = ["start tree", "goal tree"][:max(1, min(2, num_trees))]
    entries = [(f"{name} (flange)", _TREE_RGB[t], "s", 4) for t, name in enumerate(trees)]
    entries += [("path (flange)", _PATH_RGB, "-", 0), ("start", _START_RGB, "o", 5), ("goal (faded arm)", _GOAL_RGB, "o", 5)]
    handles = [Line2D([], [], color=rgb / 255.0, marker=None if marker == "-" else marker,
                      linestyle="-" if marker == "-" else "none", markersize=size, linewidth=2)
               for _, rgb, marker, size in entries]
    ax.legend(handles, [label for label, *_ in entries], loc="upper left", fontsize=6, framealpha=0.8,
              handlelength=1.2, borderpad=0.3, labelspacing=0.2)
    out = to_rgb(fig)
    return out if out.shape[:2] == (height, width) else img


def _pixel_figure(width: int, height: int):
    from matplotlib.figure import Figure
    return Figure(figsize=(width / 100.0, height / 100.0), dpi=100)
