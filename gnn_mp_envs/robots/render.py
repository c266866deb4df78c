"""``rgb_array`` images of a robot's joint-space problems with pybullet's TinyRenderer (no screen needed)."""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.robots.problem import JointSpaceProblem
from gnn_mp_envs.robots.world import RobotWorld

#: Camera of :func:`render_robot`: eye, target, up (behind and above the robot's right).
CAMERA = ((-0.75, -1.05, 1.15), (0.3, 0.0, 0.1), (0.0, 0.0, 1.0))
#: Colours (matplotlib's tab10): the start tree blue, the goal tree orange, the path green, the start
#: marker red and the goal marker purple.
_TREE_RGB = (np.array([31, 119, 180]), np.array([255, 127, 14]))
_PATH_RGB = np.array([44, 160, 44])
_START_RGB, _GOAL_RGB = np.array([214, 39, 40]), np.array([148, 103, 189])
#: The image size every size below is given for; larger images scale them (:func:`drawing_scale`).
BASE_SIZE = (480, 360)


def drawing_scale(width: int, height: int) -> float:
    """How much larger than at :data:`BASE_SIZE` dots, lines and the legend are drawn (at least 1)."""
    return max(1.0, min(width / BASE_SIZE[0], height / BASE_SIZE[1]))


def _project(points: np.ndarray, view: np.ndarray, proj: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (N, 2) (column, row) of world points (N, 3); NaN behind the camera."""
    h = np.hstack([points, np.ones((len(points), 1))]) @ (proj @ view).T
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = h[:, :3] / h[:, 3:4]
    px = np.column_stack([(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height])
    px[h[:, 3] <= 0] = np.nan
    return px


def _dots(img: np.ndarray, px: np.ndarray, color: np.ndarray, radius: int = 1) -> None:
    """Draw filled dots of radius ``radius`` (0: one pixel) at pixel positions (in place)."""
    px = px[np.isfinite(px).all(axis=1)]
    if not len(px):
        return
    c = np.rint(px).astype(int)
    for dx in range(-radius, radius + 1):
        for dy in range(-radius, radius + 1):
            if dx * dx + dy * dy > radius * radius + radius:     # a round dot
                continue
            x, y = c[:, 0] + dx, c[:, 1] + dy
            ok = (x >= 0) & (x < img.shape[1]) & (y >= 0) & (y < img.shape[0])
            img[y[ok], x[ok]] = color


def check_camera(camera: Any) -> tuple[tuple[float, float, float], ...]:
    """``camera`` as (eye, target, up), three finite 3-vectors in world coordinates (m) with eye != target
    and up not along the line of sight; else a one-line ValueError."""
    try:
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in camera)
        ok = all(v.shape == (3,) and np.all(np.isfinite(v)) for v in (eye, target, up))
    except (TypeError, ValueError):
        ok = False
    if ok:
        sight = target - eye
        ok = np.linalg.norm(sight) > 1e-9 and np.linalg.norm(np.cross(sight, up)) > 1e-9 * np.linalg.norm(sight)
    if not ok:
        raise ValueError(f"camera must be (eye, target, up): three finite 3-vectors, eye != target, up not along "
                         f"the line of sight; got {camera!r}")
    return tuple(tuple(float(x) for x in v) for v in (eye, target, up))


def _lines(img: np.ndarray, a: np.ndarray, b: np.ndarray, color: np.ndarray, radius: int = 0) -> None:
    """Draw straight segments from pixels ``a`` to pixels ``b`` (``(k, 2)`` each), in place."""
    keep = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    a, b = a[keep], b[keep]
    if not len(a):
        return
    steps = int(min(256, max(2, np.ceil(np.abs(b - a).max()) + 1)))
    t = np.linspace(0.0, 1.0, steps)[None, :, None]
    _dots(img, (a[:, None, :] + (b - a)[:, None, :] * t).reshape(-1, 2), color, radius)


def render_robot(world: RobotWorld, problem: JointSpaceProblem, tree: Any, path: np.ndarray | None,
                 width: int = 320, height: int = 240, max_tree_nodes: int = 2000,
                 camera: tuple = CAMERA) -> np.ndarray:
    """RGB (height, width, 3) uint8 image of a robot problem (the tasks' ``render_rgb``): the robot at
    the start and, faded, at the goal; each tree's edges and nodes as the flange moves (straight lines
    between the flange positions of a node and its parent; the start tree blue, the goal tree orange;
    at most ``max_tree_nodes`` nodes); the returned path's flange trace in green; a legend. Dots, lines
    and the legend grow with the image (:func:`drawing_scale`).

    TinyRenderer does not draw debug lines, so tree nodes and the path are projected with
    the camera's view/projection matrices and painted onto the image with numpy. ``camera``:
    eye, target and up vector (world coordinates, m).
    """
    scale = drawing_scale(width, height)
    node_radius, line_radius = int(round(scale)), int(round(scale - 1))
    p, cid = world.p, world.client
    world.load(problem.scene)
    eye, target, up = camera
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
        parent = np.asarray(tree.parent[idx])
        # every drawn node and its parent, projected once
        drawn = np.unique(np.concatenate([idx, parent[parent >= 0]]))
        px = dict(zip(drawn.tolist(), _project(world.flange_positions(tree.states[drawn]), view, proj, width, height)))
        for t in range(getattr(tree, "num_trees", 1)):
            sel = tree.tree_id[idx] == t
            child = idx[sel & (parent >= 0)]
            if len(child):
                _lines(img, np.array([px[int(c)] for c in tree.parent[child]]), np.array([px[int(c)] for c in child]),
                       0.55 * _TREE_RGB[t % 2] + 0.45 * 255, line_radius)
        for t in range(getattr(tree, "num_trees", 1)):
            sel = idx[tree.tree_id[idx] == t]
            if len(sel):
                _dots(img, np.array([px[int(c)] for c in sel]), _TREE_RGB[t % 2], radius=node_radius)
    if path is not None and len(path) > 1:
        dense = [path[0]]
        for a, b in zip(path[:-1], path[1:]):
            k = max(1, int(np.ceil(np.linalg.norm(b - a) / problem.resolution)))
            dense.extend(a + (b - a) * (np.arange(1, k + 1) / k)[:, None])
        px = _project(world.flange_positions(np.array(dense)), view, proj, width, height)
        _lines(img, px[:-1], px[1:], _PATH_RGB, radius=int(round(scale)))      # a continuous trace
    for q, color in ((problem.start, _START_RGB), (problem.goal, _GOAL_RGB)):
        _dots(img, _project(world.flange_positions(q), view, proj, width, height), color, radius=int(round(4 * scale)))
    return with_legend(img, num_trees=getattr(tree, "num_trees", 1) if tree is not None else 1)


def with_legend(img: np.ndarray, num_trees: int = 2) -> np.ndarray:
    """``img`` with a legend of its colours in the top-left corner, at the same size: the dots
    painted by :func:`render_robot` carry no meaning without it."""
    from matplotlib.lines import Line2D

    from gnn_mp_envs.utils.render import to_rgb
    height, width = img.shape[:2]
    fig = _pixel_figure(width, height)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.imshow(img, interpolation="none")
    ax.axis("off")
    scale = drawing_scale(width, height)
    trees = ["start tree", "goal tree"][:max(1, min(2, num_trees))]
    entries = [(f"{name} (flange)", _TREE_RGB[t], "o", 4) for t, name in enumerate(trees)]
    entries += [("path (flange)", _PATH_RGB, "-", 0), ("start", _START_RGB, "o", 6),
                ("goal (faded robot)", _GOAL_RGB, "o", 6)]
    handles = [Line2D([], [], color=rgb / 255.0, marker=None if marker == "-" else marker,
                      linestyle="-" if marker == "-" else "none", markersize=size * scale, linewidth=2 * scale)
               for _, rgb, marker, size in entries]
    ax.legend(handles, [label for label, *_ in entries], loc="upper left", fontsize=8 * scale, framealpha=0.8,
              handlelength=1.4, borderpad=0.4, labelspacing=0.3)
    out = to_rgb(fig)
    return out if out.shape[:2] == (height, width) else img


def _pixel_figure(width: int, height: int):
    from matplotlib.figure import Figure
    return Figure(figsize=(width / 100.0, height / 100.0), dpi=100)
