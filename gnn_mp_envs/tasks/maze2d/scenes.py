"""Maze2D scene families: map kinds beyond the walls-with-gaps generator, as seeded generators.

:class:`Maze2DScenesTask` is the registered ``maze2d`` task: ``scene="walls"`` (the default,
every split) is :class:`~gnn_mp_envs.tasks.maze2d.task.Maze2DTask`'s generator, bit for bit; the
other families are named in :data:`SCENE_FAMILIES` by their role:

* ``mixed`` (training, domain randomisation): per problem one of the walls generator, walls
  with blobs, a grid of rooms with doors, scattered bars, in one of the square's eight
  symmetries. ``mixed-angled`` (training): the same plus walls and bars at an angle (oriented
  boxes: each wall tilted on its own, bars at any orientation), so a model sees walls that are
  not axis-aligned without seeing the ``rotated`` test maps.
* validation kinds (held out from training, for decisions): ``pockets`` (walls plus dead-end
  bays), ``slits`` (a thick wall crossed by one long narrow channel), ``slanted`` (a thick wall
  tilted 15-75 degrees crossed by one channel, plus bays turned at any angle).
* out-of-distribution test kinds (never trained or tuned on): ``trap`` (a U facing the start,
  the goal behind its base), ``goal-trap`` (the goal inside a U that opens away from the
  start), ``corridor`` (one long zig-zag corridor), ``spiral`` (the goal at the centre of a
  square spiral), ``forest`` (30-45 small discs and turned boxes), ``rotated`` (the walls
  generator's maps turned by 20-70 degrees: oriented boxes).

A generator draws everything from the ``rng`` it is given (the split's problem stream), so
problem ``i`` of a family is the same on every machine. ``gym.make("GNNMP/Maze2DRRT-v0",
scene="spiral", split="test")`` plans them; pictures: ``docs/img/ood_maze2d.png``.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from gnn_mp_envs.core.problem import InvalidProblemError
from gnn_mp_envs.tasks.maze2d.task import (
    ENDPOINT_MARGIN,
    STEP_SIZE,
    Maze2DProblem,
    Maze2DTask,
    MazeMap,
    random_maze,
    sample_endpoints,
)

#: A generator: ``rng -> (map, start, goal)``.
Generator = Callable[[np.random.Generator], tuple[MazeMap, np.ndarray, np.ndarray]]
#: Draws of a generator before it gives up (clutter that blocks every path, endpoints that do not fit).
MAX_TRIES = 200
#: Half width of the passage a free path must keep in the connectivity check (a point robot
#: needs none, but an RRT with 0.05 steps does not find slots much narrower than the walls' gaps).
PASSAGE_CLEARANCE = 0.012


# ---------------------------------------------------------------------------- geometry helpers
def square_symmetry(maze: MazeMap, points: list[np.ndarray], k: int) -> tuple[MazeMap, list[np.ndarray]]:
    """The map and points under symmetry ``k`` (0..7) of the unit square: ``k % 4`` quarter turns
    about the centre, then a mirror in x when ``k >= 4``. Walls stay axis-aligned walls."""
    def f(xy: np.ndarray) -> np.ndarray:
        x, y = xy[..., 0] - 0.5, xy[..., 1] - 0.5
        for _ in range(k % 4):
            x, y = -y, x
        if k >= 4:
            x = -x
        return np.stack([x + 0.5, y + 0.5], -1)

    w = maze.walls
    a, b = f(w[:, :2]), f(w[:, 2:])
    walls = np.concatenate([np.minimum(a, b), np.maximum(a, b)], 1) if len(w) else w
    blobs = np.column_stack([f(maze.blobs[:, :2]), maze.blobs[:, 2]]) if len(maze.blobs) else maze.blobs
    boxes = maze.boxes
    if len(boxes):
        angle = boxes[:, 4] + (k % 4) * math.pi / 2
        if k >= 4:
            angle = math.pi - angle
        boxes = np.column_stack([f(boxes[:, :2]), boxes[:, 2:4], angle])
    return MazeMap(walls, blobs, boxes), [f(np.asarray(p, np.float64)) for p in points]


def walls_as_boxes(walls: np.ndarray) -> np.ndarray:
    """Axis-aligned walls ``[xmin, ymin, xmax, ymax]`` as oriented boxes (angle 0)."""
    w = np.asarray(walls, dtype=np.float64).reshape(-1, 4)
    return np.column_stack([(w[:, 0] + w[:, 2]) / 2, (w[:, 1] + w[:, 3]) / 2, (w[:, 2] - w[:, 0]) / 2,
                            (w[:, 3] - w[:, 1]) / 2, np.zeros(len(w))])


def turned(boxes: np.ndarray, angle: float, centre=(0.5, 0.5)) -> np.ndarray:
    """Oriented boxes turned by ``angle`` about ``centre``."""
    c, s = math.cos(angle), math.sin(angle)
    dx, dy = boxes[:, 0] - centre[0], boxes[:, 1] - centre[1]
    return np.column_stack([centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy, boxes[:, 2:4],
                            boxes[:, 4] + angle])


def clear(maze: MazeMap, x: np.ndarray, margin: float = ENDPOINT_MARGIN) -> bool:
    """``x`` and its four neighbours ``margin`` away are free (a start or goal with room around it)."""
    probe = np.asarray(x, np.float64) + margin * np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]])
    return bool(maze.is_free(probe).all())


def connected(maze: MazeMap, a: np.ndarray, b: np.ndarray, cells: int = 100,
              clearance: float = PASSAGE_CLEARANCE) -> bool:
    """Whether ``a`` and ``b`` are joined through cells of a ``cells`` x ``cells`` grid whose centre
    and four points ``clearance`` away are free (4-connected flood fill)."""
    c = (np.arange(cells) + 0.5) / cells
    xx, yy = np.meshgrid(c, c, indexing="ij")
    pts = np.stack([xx.ravel(), yy.ravel()], 1)
    ok = np.ones(len(pts), dtype=bool)
    for off in ((0, 0), (clearance, 0), (-clearance, 0), (0, clearance), (0, -clearance)):
        ok &= maze.is_free(pts + np.asarray(off))
    ok = ok.reshape(cells, cells)
    ia = tuple(np.clip((np.asarray(a) * cells).astype(int), 0, cells - 1))
    ib = tuple(np.clip((np.asarray(b) * cells).astype(int), 0, cells - 1))
    if not (ok[ia] and ok[ib]):
        return False
    seen = np.zeros_like(ok)
    seen[ia] = True
    frontier = [ia]
    while frontier:
        nxt = []
        for i, j in frontier:
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                u, v = i + di, j + dj
                if 0 <= u < cells and 0 <= v < cells and ok[u, v] and not seen[u, v]:
                    seen[u, v] = True
                    nxt.append((u, v))
        frontier = nxt
    return bool(seen[ib])


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _symmetric(rng: np.random.Generator, maze: MazeMap, start, goal):
    """The map and endpoints under a random one of the eight symmetries of the square."""
    maze, (start, goal) = square_symmetry(maze, [start, goal], int(rng.integers(8)))
    return maze, start, goal


def _u_walls(x0: float, y0: float, depth: float, height: float, t: float, open_left: bool) -> list[list[float]]:
    """A U of three walls (thickness ``t``) in the box ``[x0, x0 + depth] x [y0, y0 + height]``:
    the base on the right (opening to the left) or on the left (``open_left=False``)."""
    x1, y1 = x0 + depth, y0 + height
    base = [x1 - t, y0, x1, y1] if open_left else [x0, y0, x0 + t, y1]
    return [base, [x0, y0, x1, y0 + t], [x0, y1 - t, x1, y1]]


# ---------------------------------------------------------------------------- training: mixed
def walls_scene(rng: np.random.Generator):
    """The task's own generator (1-3 walls with gaps)."""
    maze, axis = random_maze(rng)
    start, goal = sample_endpoints(rng, maze, axis)
    return maze, start, goal


def blobs_scene(rng: np.random.Generator):
    """Walls with gaps plus 2-5 circular blobs (the robustness variant)."""
    for _ in range(MAX_TRIES):
        maze, axis = random_maze(rng, num_blobs=int(rng.integers(2, 6)))
        try:
            start, goal = sample_endpoints(rng, maze, axis)
        except RuntimeError:
            continue
        if connected(maze, start, goal):
            return maze, start, goal
    raise RuntimeError("blobs: no connected map")


def _wall_with_doors(rng, axis: int, at: float, lo: float, hi: float, t: float, doors: int) -> list[list[float]]:
    """Wall pieces across ``[lo, hi]`` at ``at`` (axis 0: fixed x) leaving ``doors`` gaps 0.04-0.07 wide."""
    span = (hi - lo) / doors
    edges = [lo]
    for k in range(doors):
        width = _u(rng, 0.04, 0.07)
        centre = lo + span * (k + _u(rng, 0.25, 0.75))
        edges += [centre - width / 2, centre + width / 2]
    edges.append(hi)
    out = []
    for a, b in zip(edges[0::2], edges[1::2]):
        if b - a > 1e-6:
            out.append([at - t / 2, a, at + t / 2, b] if axis == 0 else [a, at - t / 2, b, at + t / 2])
    return out


def rooms_scene(rng: np.random.Generator):
    """Four rooms: a wall across x and one across y, each with a door in each half; start and
    goal in opposite rooms."""
    for _ in range(MAX_TRIES):
        cx, cy, t = _u(rng, 0.35, 0.65), _u(rng, 0.35, 0.65), _u(rng, 0.03, 0.05)
        walls = (_wall_with_doors(rng, 0, cx, 0.0, cy - t / 2, t, 1) + _wall_with_doors(rng, 0, cx, cy + t / 2, 1.0, t, 1)
                 + _wall_with_doors(rng, 1, cy, 0.0, cx - t / 2, t, 1)
                 + _wall_with_doors(rng, 1, cy, cx + t / 2, 1.0, t, 1))
        walls.append([cx - t / 2, cy - t / 2, cx + t / 2, cy + t / 2])
        maze = MazeMap(np.array(walls))
        start = np.array([_u(rng, 0.04, cx - 0.06), _u(rng, 0.04, cy - 0.06)])
        goal = np.array([_u(rng, cx + 0.06, 0.96), _u(rng, cy + 0.06, 0.96)])
        if clear(maze, start) and clear(maze, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("rooms: no free endpoints")


def bars_scene(rng: np.random.Generator):
    """5-9 scattered axis-aligned bars 0.15-0.45 long; start and goal on opposite sides."""
    for _ in range(MAX_TRIES):
        walls = []
        for _ in range(int(rng.integers(5, 10))):
            length, t = _u(rng, 0.15, 0.45), _u(rng, 0.03, 0.05)
            x, y = _u(rng, 0.15, 0.85), _u(rng, 0.1, 0.9)
            walls.append([x - t / 2, y - length / 2, x + t / 2, y + length / 2] if rng.random() < 0.5
                         else [x - length / 2, y - t / 2, x + length / 2, y + t / 2])
        maze = MazeMap(np.array(walls))
        start = np.array([_u(rng, 0.03, 0.12), _u(rng, 0.05, 0.95)])
        goal = np.array([_u(rng, 0.88, 0.97), _u(rng, 0.05, 0.95)])
        if clear(maze, start) and clear(maze, goal) and connected(maze, start, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("bars: no connected map")


MIXED_KINDS: dict[str, Generator] = {"walls": walls_scene, "blobs": blobs_scene, "rooms": rooms_scene,
                                     "bars": bars_scene}


def mixed_scene(rng: np.random.Generator):
    """Domain randomisation for training: one of :data:`MIXED_KINDS` per problem."""
    kinds = list(MIXED_KINDS.values())
    return kinds[int(rng.integers(len(kinds)))](rng)


def _chord_wall(rng: np.random.Generator, centre: np.ndarray, angle: float, thick: float,
                gaps: int, gap_width: tuple[float, float] = (0.035, 0.06)) -> list[list[float]]:
    """Oriented boxes ``[cx, cy, half_length, half_width, angle]`` of a wall ``thick`` thick along
    the line through ``centre`` at ``angle``, across the whole square (it overhangs by 0.1), with
    ``gaps`` gaps ``gap_width`` wide at random places of the stretch inside the square."""
    u = np.array([math.cos(angle), math.sin(angle)])
    # The line's parameters t with centre + t u inside the square.
    with np.errstate(divide="ignore"):
        t_lo = np.where(u != 0, (0.0 - centre) / u, -np.inf)
        t_hi = np.where(u != 0, (1.0 - centre) / u, np.inf)
    enter = float(np.max(np.minimum(t_lo, t_hi)))
    leave = float(np.min(np.maximum(t_lo, t_hi)))
    span = leave - enter
    cuts = sorted((enter + span * _u(rng, 0.1, 0.9), _u(rng, *gap_width)) for _ in range(gaps))
    edges = [enter - 0.1]
    for c, w in cuts:
        edges += [c - w / 2, c + w / 2]
    edges.append(leave + 0.1)
    out = []
    for a, b in zip(edges[0::2], edges[1::2]):
        if b - a > 1e-6:
            mid = centre + u * (a + b) / 2
            out.append([mid[0], mid[1], (b - a) / 2, thick / 2, angle])
    return out


def angled_walls_scene(rng: np.random.Generator):
    """1-3 walls with 1-2 gaps each, like the walls generator's, but each wall tilted on its own by
    up to +-55 degrees from upright (oriented boxes, not parallel to each other); start and goal
    near opposite sides, joined through the gaps."""
    for _ in range(MAX_TRIES):
        n = int(rng.integers(1, 4))
        slot = 0.8 / n
        boxes = []
        for k in range(n):
            x = 0.1 + slot * (k + _u(rng, 0.35, 0.65))
            angle = math.pi / 2 + math.radians(_u(rng, -55, 55))
            boxes += _chord_wall(rng, np.array([x, _u(rng, 0.3, 0.7)]), angle, _u(rng, 0.03, 0.06),
                                 int(rng.integers(1, 3)))
        maze = MazeMap(boxes=np.array(boxes))
        start = np.array([_u(rng, 0.02, 0.15), _u(rng, 0.05, 0.95)])
        goal = np.array([_u(rng, 0.85, 0.98), _u(rng, 0.05, 0.95)])
        if clear(maze, start) and clear(maze, goal) and connected(maze, start, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("angled-walls: no connected map")


def angled_bars_scene(rng: np.random.Generator):
    """5-9 scattered bars 0.15-0.45 long at any orientation (the ``bars`` kind, turned); start and
    goal on opposite sides."""
    for _ in range(MAX_TRIES):
        n = int(rng.integers(5, 10))
        boxes = np.column_stack([rng.uniform(0.15, 0.85, n), rng.uniform(0.1, 0.9, n), rng.uniform(0.075, 0.225, n),
                                 rng.uniform(0.015, 0.025, n), rng.uniform(0.0, math.pi, n)])
        maze = MazeMap(boxes=boxes)
        start = np.array([_u(rng, 0.03, 0.12), _u(rng, 0.05, 0.95)])
        goal = np.array([_u(rng, 0.88, 0.97), _u(rng, 0.05, 0.95)])
        if clear(maze, start) and clear(maze, goal) and connected(maze, start, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("angled-bars: no connected map")


#: The angled kinds that ``mixed-angled`` adds to :data:`MIXED_KINDS` (training only).
ANGLED_KINDS: dict[str, Generator] = {"angled-walls": angled_walls_scene, "angled-bars": angled_bars_scene}


def mixed_angled_scene(rng: np.random.Generator):
    """Domain randomisation with walls at an angle: one of :data:`MIXED_KINDS` and
    :data:`ANGLED_KINDS` per problem (a third of the problems angled)."""
    kinds = list(MIXED_KINDS.values()) + list(ANGLED_KINDS.values())
    return kinds[int(rng.integers(len(kinds)))](rng)


# ---------------------------------------------------------------------------- validation kinds
def pockets_scene(rng: np.random.Generator):
    """One or two walls with gaps, plus 2-3 dead-end bays (U shapes 0.12-0.2 across) in the rooms,
    each opening toward one side at random."""
    for _ in range(MAX_TRIES):
        maze, axis = random_maze(rng, (1, 2))
        start, goal = sample_endpoints(rng, maze, axis)
        walls = list(maze.walls)
        for _ in range(int(rng.integers(2, 4))):
            size, t = _u(rng, 0.12, 0.2), _u(rng, 0.025, 0.04)
            x0, y0 = _u(rng, 0.05, 0.95 - size), _u(rng, 0.05, 0.95 - size)
            bay = np.array(_u_walls(x0, y0, size, size, t, bool(rng.random() < 0.5)))
            if rng.random() < 0.5:   # opening up or down instead: mirror the U in its diagonal
                bay = np.column_stack([bay[:, 1] - y0 + x0, bay[:, 0] - x0 + y0, bay[:, 3] - y0 + x0,
                                       bay[:, 2] - x0 + y0])
            walls += list(bay)
        maze = MazeMap(np.array(walls))
        if clear(maze, start) and clear(maze, goal) and connected(maze, start, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("pockets: no connected map")


def slits_scene(rng: np.random.Generator):
    """A wall 0.15-0.3 thick across the square, crossed by one channel 0.04-0.06 wide: a long
    narrow passage; start and goal on opposite sides."""
    thick, width = _u(rng, 0.15, 0.3), _u(rng, 0.04, 0.06)
    x = _u(rng, 0.35, 0.65)
    centre = _u(rng, 0.15, 0.85)
    walls = np.array([[x - thick / 2, 0.0, x + thick / 2, centre - width / 2],
                      [x - thick / 2, centre + width / 2, x + thick / 2, 1.0]])
    maze = MazeMap(walls)
    start, goal = sample_endpoints(rng, maze, 0)
    return _symmetric(rng, maze, start, goal)


def slanted_scene(rng: np.random.Generator):
    """A wall 0.1-0.2 thick across the square, tilted 15-75 degrees from an axis, crossed by one
    channel 0.045-0.065 wide (a slanted ``slits``), plus 1-2 dead-end bays (U shapes 0.12-0.18
    across) turned by any angle; start and goal on opposite sides of the wall."""
    for _ in range(MAX_TRIES):
        thick, width = _u(rng, 0.1, 0.2), _u(rng, 0.045, 0.065)
        angle = math.radians(_u(rng, 15, 75)) * (1 if rng.random() < 0.5 else -1) + math.pi / 2
        centre = np.array([_u(rng, 0.4, 0.6), _u(rng, 0.4, 0.6)])
        boxes = _chord_wall(rng, centre, angle, thick, 1, (width, width))
        for _ in range(int(rng.integers(1, 3))):
            size, t = _u(rng, 0.12, 0.18), _u(rng, 0.025, 0.04)
            x0, y0 = _u(rng, 0.05, 0.95 - size), _u(rng, 0.05, 0.95 - size)
            bay = walls_as_boxes(np.array(_u_walls(x0, y0, size, size, t, True)))
            boxes += turned(bay, _u(rng, -math.pi, math.pi), (x0 + size / 2, y0 + size / 2)).tolist()
        maze = MazeMap(boxes=np.array(boxes))
        normal = np.array([-math.sin(angle), math.cos(angle)])
        out = []
        for side in (-1, 1):
            for _ in range(MAX_TRIES):
                p = rng.uniform(0.03, 0.97, 2)
                if side * float((p - centre) @ normal) > thick / 2 + ENDPOINT_MARGIN and clear(maze, p):
                    out.append(p)
                    break
        if len(out) == 2 and connected(maze, *out):
            start, goal = out if rng.random() < 0.5 else out[::-1]
            return maze, start, goal
    raise RuntimeError("slanted: no connected map")


# ---------------------------------------------------------------------------- out-of-distribution kinds
def trap_scene(rng: np.random.Generator):
    """A U-shaped trap 0.3-0.5 tall whose opening faces the start; the goal lies behind its base,
    so the straight way in ends at the base and the path goes around an arm."""
    for _ in range(MAX_TRIES):
        depth, height, t = _u(rng, 0.2, 0.3), _u(rng, 0.3, 0.5), _u(rng, 0.03, 0.05)
        x0, y0 = _u(rng, 0.3, 0.45), _u(rng, 0.5 - height / 2 - 0.1, 0.5 - height / 2 + 0.1)
        maze = MazeMap(np.array(_u_walls(x0, y0, depth, height, t, open_left=True)))
        yc = y0 + height / 2
        start = np.array([_u(rng, 0.04, x0 - 0.08), yc + _u(rng, -0.25, 0.25) * height])
        goal = np.array([_u(rng, x0 + depth + 0.06, 0.96), yc + _u(rng, -0.3, 0.3) * height])
        if clear(maze, start) and clear(maze, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("trap: no free endpoints")


def goal_trap_scene(rng: np.random.Generator):
    """The goal inside a U 0.3-0.45 tall whose opening faces away from the start: the way in is
    around the trap, through its far side."""
    for _ in range(MAX_TRIES):
        depth, height, t = _u(rng, 0.25, 0.35), _u(rng, 0.3, 0.45), _u(rng, 0.03, 0.05)
        x0, y0 = _u(rng, 0.35, 0.5), _u(rng, 0.5 - height / 2 - 0.1, 0.5 - height / 2 + 0.1)
        maze = MazeMap(np.array(_u_walls(x0, y0, depth, height, t, open_left=False)))
        goal = np.array([x0 + t + _u(rng, 0.05, 0.12), y0 + height / 2 + _u(rng, -0.2, 0.2) * height])
        start = np.array([_u(rng, 0.04, x0 - 0.08), _u(rng, 0.1, 0.9)])
        if clear(maze, start) and clear(maze, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("goal-trap: no free endpoints")


def corridor_scene(rng: np.random.Generator):
    """One zig-zag corridor: 3-4 walls across the square, each leaving a 0.1-0.14 opening at
    alternate ends; start below the first wall, goal above the last."""
    n = int(rng.integers(3, 5))
    t = _u(rng, 0.03, 0.045)
    gap = [_u(rng, 0.1, 0.14) for _ in range(n)]
    ys = np.linspace(0.12, 0.88, n + 2)[1:-1] + rng.uniform(-0.02, 0.02, n)
    first_left = bool(rng.random() < 0.5)
    walls = []
    for k, (y, g) in enumerate(zip(ys, gap)):
        left = (k % 2 == 0) == first_left         # the opening at x = 0 (left) or x = 1
        walls.append([g, y - t / 2, 1.0, y + t / 2] if left else [0.0, y - t / 2, 1.0 - g, y + t / 2])
    maze = MazeMap(np.array(walls))
    start = np.array([_u(rng, 0.1, 0.9), _u(rng, 0.04, ys[0] - t / 2 - 0.05)])
    goal = np.array([_u(rng, 0.1, 0.9), _u(rng, ys[-1] + t / 2 + 0.05, 0.96)])
    return _symmetric(rng, maze, start, goal)


def spiral_scene(rng: np.random.Generator):
    """A square spiral of walls (corridors 0.09-0.12 wide, 5-7 segments) with the goal at its
    centre and the start outside."""
    for _ in range(MAX_TRIES):
        width, t = _u(rng, 0.09, 0.12), _u(rng, 0.025, 0.035)
        segments = int(rng.integers(5, 8))
        c = np.array([_u(rng, 0.45, 0.55), _u(rng, 0.45, 0.55)])
        # Walk outward: each segment turns a quarter and is one corridor width longer.
        pos, heading, length = c + np.array([-width / 2, -width / 2]), 0, width
        walls = []
        dirs = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([-1.0, 0.0]), np.array([0.0, -1.0])]
        for _ in range(segments):
            end = pos + dirs[heading] * length
            lo, hi = np.minimum(pos, end) - t / 2, np.maximum(pos, end) + t / 2
            walls.append([*lo, *hi])
            pos, heading, length = end, (heading + 1) % 4, length + width
        walls = np.clip(np.array(walls), 0.0, 1.0)
        maze = MazeMap(walls[(walls[:, 2] > walls[:, 0]) & (walls[:, 3] > walls[:, 1])])
        goal = c + rng.uniform(-0.01, 0.01, 2)
        corner = np.array([[0.05, 0.05], [0.95, 0.05], [0.05, 0.95], [0.95, 0.95]])[int(rng.integers(4))]
        start = corner + rng.uniform(-0.02, 0.02, 2)
        if clear(maze, start, 0.03) and clear(maze, goal, 0.03) and connected(maze, start, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("spiral: no connected map")


def forest_scene(rng: np.random.Generator):
    """30-45 small obstacles (discs of radius 0.02-0.045 and turned boxes) strewn over the square;
    start and goal near opposite corners, joined through the forest."""
    for _ in range(MAX_TRIES):
        n = int(rng.integers(30, 46))
        kinds = rng.random(n) < 0.5
        centres = rng.uniform(0.08, 0.92, (n, 2))
        blobs = np.column_stack([centres[kinds], rng.uniform(0.02, 0.045, int(kinds.sum()))])
        m = int((~kinds).sum())
        boxes = np.column_stack([centres[~kinds], rng.uniform(0.02, 0.05, m), rng.uniform(0.012, 0.03, m),
                                 rng.uniform(0, math.pi, m)])
        maze = MazeMap(blobs=blobs, boxes=boxes)
        start = np.array([_u(rng, 0.03, 0.12), _u(rng, 0.03, 0.12)])
        goal = np.array([_u(rng, 0.88, 0.97), _u(rng, 0.88, 0.97)])
        if clear(maze, start, 0.03) and clear(maze, goal, 0.03) and connected(maze, start, goal):
            return _symmetric(rng, maze, start, goal)
    raise RuntimeError("forest: no connected map")


def rotated_scene(rng: np.random.Generator):
    """The walls generator's map, its walls lengthened beyond the square so that they still cut
    it, turned by +-20-70 degrees about the centre (oriented boxes); start and goal re-drawn on
    opposite sides of all walls."""
    for _ in range(MAX_TRIES):
        maze, axis = random_maze(rng)
        walls = maze.walls.copy()
        along = 1 - axis        # the walls span this coordinate; stretch their outer pieces
        walls[walls[:, along] <= 1e-9, along] = -0.5
        walls[walls[:, along + 2] >= 1 - 1e-9, along + 2] = 1.5
        angle = math.radians(_u(rng, 20, 70)) * (1 if rng.random() < 0.5 else -1)
        rotated = MazeMap(boxes=turned(walls_as_boxes(walls), angle))
        # Endpoints in the unturned frame: before the first wall / beyond the last along ``axis``.
        first, last = walls[:, axis].min(), walls[:, axis + 2].max()
        out = []
        for lo, hi in ((-0.3, first - ENDPOINT_MARGIN), (last + ENDPOINT_MARGIN, 1.3)):
            for _ in range(MAX_TRIES):
                x = np.empty(2)
                x[axis], x[along] = _u(rng, lo, hi), _u(rng, -0.3, 1.3)
                p = turned(np.array([[*x, 1.0, 1.0, 0.0]]), angle)[0, :2]
                if np.all((p > 0.03) & (p < 0.97)) and clear(rotated, p):
                    out.append(p)
                    break
        if len(out) == 2:
            start, goal = out if rng.random() < 0.5 else out[::-1]
            return rotated, start, goal
    raise RuntimeError("rotated: no free endpoints")


#: Family name -> (role, generator). Roles: ``default`` (the benchmark's and every split's
#: family), ``train`` (domain randomisation), ``val`` (held-out kinds for decisions), ``ood``
#: (out-of-distribution test kinds).
SCENE_FAMILIES: dict[str, tuple[str, Generator]] = {
    "walls": ("default", walls_scene),
    "mixed": ("train", mixed_scene),
    "mixed-angled": ("train", mixed_angled_scene),
    "pockets": ("val", pockets_scene),
    "slits": ("val", slits_scene),
    "slanted": ("val", slanted_scene),
    "trap": ("ood", trap_scene),
    "goal-trap": ("ood", goal_trap_scene),
    "corridor": ("ood", corridor_scene),
    "spiral": ("ood", spiral_scene),
    "forest": ("ood", forest_scene),
    "rotated": ("ood", rotated_scene),
}


def families(role: str) -> tuple[str, ...]:
    """The families of one role, in table order."""
    return tuple(name for name, (r, _) in SCENE_FAMILIES.items() if r == role)


class Maze2DScenesTask(Maze2DTask):
    """Maze2D problems of one scene family (see the module docstring); ``walls`` is
    :class:`Maze2DTask`'s own generator."""

    def __init__(self, scene: str = "walls", **kwargs) -> None:
        if scene not in SCENE_FAMILIES:
            raise ValueError(f"unknown maze2d scene {scene!r}; known: {', '.join(SCENE_FAMILIES)}")
        super().__init__(**kwargs)
        self.scene = scene

    def sample_problem(self, rng: np.random.Generator) -> Maze2DProblem:
        if self.scene == "walls":
            return super().sample_problem(rng)
        maze, start, goal = SCENE_FAMILIES[self.scene][1](rng)
        problem = Maze2DProblem(maze, np.asarray(start, np.float64), np.asarray(goal, np.float64), self.step_size)
        try:
            problem.validate()
        except InvalidProblemError as exc:   # a generator bug, not a user error
            raise RuntimeError(f"maze2d scene {self.scene!r} made an invalid problem: {exc}") from None
        return problem


__all__ = ["ANGLED_KINDS", "MIXED_KINDS", "SCENE_FAMILIES", "STEP_SIZE", "Maze2DScenesTask", "connected", "families",
           "square_symmetry", "turned", "walls_as_boxes"]
