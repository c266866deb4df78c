"""Maze2D: the unit square with random walls that leave narrow passages.

This is the map family of the paper's critical-sample section; :mod:`gnn_mp_envs.critical`
reuses :class:`MazeMap` and :func:`random_maze` for its Halton-graph problems.

A map is data: axis-aligned wall rectangles, optional circular blobs (the robustness
variant) and optional oriented boxes (rectangles turned by an angle: rotated maps). Each
wall of the generator here spans the square and has one or two gaps (the narrow passages).
Start and goal lie on opposite sides of all walls, so every path threads at least one gap.
Collision checks are exact: a point test or a segment test each counts as one check. Other
map kinds (traps, corridors, spirals, forests, rotated maps) are the scene families of
:mod:`gnn_mp_envs.tasks.maze2d.scenes`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gnn_mp_envs.core.loop import CompiledKernel
from gnn_mp_envs.core.problem import ZERO_LENGTH, Edge, InvalidProblemError, Problem
from gnn_mp_envs.tasks.base import Task, check_keys
from gnn_mp_envs.utils.compiled import jit
from gnn_mp_envs.utils.render import draw_tree, figure, to_rgb

#: Extension length of RRT/BiRRT in the unit square.
STEP_SIZE = 0.05
#: Clearance of start and goal from any wall.
ENDPOINT_MARGIN = 0.04


def _rows(name: str, value: Any, width: int) -> np.ndarray:
    """``value`` as a finite (k, width) float array; InvalidProblemError naming ``name`` otherwise."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidProblemError(f"{name} must be numbers, got {value!r}") from None
    if a.size % width or (a.ndim > 1 and a.shape[-1] != width):
        raise InvalidProblemError(f"{name} must have rows of {width} numbers, got shape {a.shape}")
    a = a.reshape(-1, width)
    bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
    if bad.size:
        raise InvalidProblemError(f"{name}[{bad[0]}] = {a[bad[0]].tolist()} is not finite")
    return a


@dataclass
class MazeMap:
    """Obstacles of the unit square: ``walls`` (M, 4) as ``[xmin, ymin, xmax, ymax]``,
    ``blobs`` (K, 3) as ``[cx, cy, r]`` and oriented ``boxes`` (B, 5) as ``[cx, cy, half_length,
    half_width, angle]`` (the box's length axis turned ``angle`` radians from +x)."""

    walls: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    blobs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))

    def __post_init__(self) -> None:
        self.walls = _rows("walls", self.walls, 4)
        self.blobs = _rows("blobs", self.blobs, 3)
        self.boxes = _rows("boxes", self.boxes, 5)
        bad = np.flatnonzero((self.boxes[:, 2] <= 0) | (self.boxes[:, 3] <= 0))
        if bad.size:
            raise InvalidProblemError(f"boxes[{bad[0]}] = {self.boxes[bad[0]].tolist()} has a half extent <= 0")
        self._wall_rows = [_wall_row(w) for w in self.walls]     # for the one-segment test
        bad = np.flatnonzero((self.walls[:, 0] > self.walls[:, 2]) | (self.walls[:, 1] > self.walls[:, 3]))
        if bad.size:
            raise InvalidProblemError(f"walls[{bad[0]}] = {self.walls[bad[0]].tolist()} is inverted: "
                                      "expected [xmin, ymin, xmax, ymax] with min <= max")
        bad = np.flatnonzero(self.blobs[:, 2] <= 0)
        if bad.size:
            raise InvalidProblemError(f"blobs[{bad[0]}] has radius {self.blobs[bad[0], 2]}: must be > 0")

    def is_free(self, points: np.ndarray) -> np.ndarray:
        """Free-space test of each row of ``points`` (N, 2); outside the square is not free."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        free = np.all((p >= 0.0) & (p <= 1.0), axis=1)
        if len(self.walls):
            w = self.walls
            inside = ((p[:, None, 0] >= w[None, :, 0]) & (p[:, None, 0] <= w[None, :, 2])
                      & (p[:, None, 1] >= w[None, :, 1]) & (p[:, None, 1] <= w[None, :, 3]))
            free &= ~inside.any(axis=1)
        if len(self.blobs):
            b = self.blobs
            d2 = ((p[:, None, :] - b[None, :, :2]) ** 2).sum(-1)
            free &= ~(d2 <= b[None, :, 2] ** 2).any(axis=1)
        if len(self.boxes):
            u, v = _box_frame(p, self.boxes)
            free &= ~((np.abs(u) <= self.boxes[None, :, 2]) & (np.abs(v) <= self.boxes[None, :, 3])).any(axis=1)
        return free

    def segments_free(self, p: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Exact test of segments ``p[i] -> q[i]`` (N, 2) against every obstacle."""
        p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
        q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
        # Endpoints inside an obstacle are caught by the slab / closest-point tests below,
        # so only the square's bounds need a separate point test.
        free = (np.all((p >= 0.0) & (p <= 1.0), axis=1) & np.all((q >= 0.0) & (q <= 1.0), axis=1))
        d = q - p
        if len(self.walls):
            free &= ~_segments_hit_boxes(p, d, self.walls).any(axis=1)
        if len(self.blobs):
            c = self.blobs[None, :, :2]
            dd = np.maximum((d * d).sum(-1), 1e-300)[:, None]
            t = np.clip(((c - p[:, None, :]) * d[:, None, :]).sum(-1) / dd, 0.0, 1.0)
            closest = p[:, None, :] + t[..., None] * d[:, None, :]
            free &= ~(((closest - c) ** 2).sum(-1) <= self.blobs[None, :, 2] ** 2).any(axis=1)
        if len(self.boxes):
            free &= ~_segments_hit_oriented(p, d, self.boxes).any(axis=1)
        return free

    def segment_free(self, p: np.ndarray, q: np.ndarray) -> bool:
        """:meth:`segments_free` of one segment ``p -> q``, in plain floats: the same operations in
        the same order (so the same answer, bit for bit) at a tenth of the cost of numpy's
        broadcasting for a single row. Maps with blobs or oriented boxes take the vectorised test."""
        if len(self.blobs) or len(self.boxes):
            return bool(self.segments_free(p[None], q[None])[0])
        return self.segment_free_xy(float(p[0]), float(p[1]), float(q[0]), float(q[1]))

    def segment_free_xy(self, px: float, py: float, qx: float, qy: float) -> bool:
        """:meth:`segment_free` of the segment ``(px, py) -> (qx, qy)`` given as floats."""
        if self.blobs.size or self.boxes.size:
            return self.segment_free(np.array([px, py]), np.array([qx, qy]))
        if not (0.0 <= px <= 1.0 and 0.0 <= py <= 1.0 and 0.0 <= qx <= 1.0 and 0.0 <= qy <= 1.0):
            return False
        dx, dy = qx - px, qy - py
        lox, hix = (px, qx) if px <= qx else (qx, px)
        loy, hiy = (py, qy) if py <= qy else (qy, py)
        for x0, y0, x1, y1, left, below, right, above in self._wall_rows:
            # A wall clear of the segment's bounding box by more than rounding can reach is not
            # hit (the slab test would say so too: see _wall_row); most walls end here.
            if hix < left or lox > right or hiy < below or loy > above:
                continue
            if _slab_hit(px, dx, x0, x1, py, dy, y0, y1):
                return False
        return True

    def occupancy(self, size: int = 64) -> np.ndarray:
        """A (size, size) occupancy image (1 = obstacle), row 0 at y = 0, sampled at cell centres."""
        c = (np.arange(size) + 0.5) / size
        xx, yy = np.meshgrid(c, c)
        return (~self.is_free(np.stack([xx.ravel(), yy.ravel()], 1))).reshape(size, size).astype(np.float32)


def _segments_hit_boxes(p: np.ndarray, d: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(N, M) slab test: does segment i (p + t d, t in [0, 1]) touch box j."""
    lo = boxes[None, :, :2]
    hi = boxes[None, :, 2:]
    p3 = p[:, None, :]
    d3 = d[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - p3) / d3
        t2 = (hi - p3) / d3
    parallel = d3 == 0.0
    inside_slab = (p3 >= lo) & (p3 <= hi)
    tmin = np.where(parallel, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(parallel, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
    t_enter = tmin.max(axis=2)
    t_exit = tmax.min(axis=2)
    return (t_enter <= t_exit) & (t_exit >= 0.0) & (t_enter <= 1.0)


#: Relative margin of the bounding-box rejection in :meth:`MazeMap.segment_free`.
_BOX_MARGIN = 1e-9


def _wall_row(wall: np.ndarray) -> tuple[float, ...]:
    """A wall for the one-segment test: ``(x0, y0, x1, y1)`` and the same box grown by a margin.

    A segment whose bounding box lies beyond the grown box cannot be hit by the slab test either:
    with the segment inside the unit square, the slab parameters then miss ``[0, 1]`` by at least
    ``margin / |d|`` (about 1e-9), while each is computed with a relative error of a few 1e-16. So
    the rejection skips work, never changes an answer (``tests/test_core.py`` grazes walls at
    1e-12 to 1e-8).
    """
    x0, y0, x1, y1 = map(float, wall)
    margin = _BOX_MARGIN * max(1.0, abs(x0), abs(y0), abs(x1), abs(y1))
    return x0, y0, x1, y1, x0 - margin, y0 - margin, x1 + margin, y1 + margin


def _box_frame(p: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, B) coordinates of points ``p`` (N, 2) along each box's length and width axes, from its centre."""
    c, s = np.cos(boxes[:, 4]), np.sin(boxes[:, 4])
    dx = p[:, None, 0] - boxes[None, :, 0]
    dy = p[:, None, 1] - boxes[None, :, 1]
    return dx * c + dy * s, dy * c - dx * s


def _segments_hit_oriented(p: np.ndarray, d: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(N, B): does segment i touch oriented box j. The segment is turned into the box's frame,
    where the box is axis-aligned, and the slab test of :func:`_segments_hit_boxes` runs there."""
    u, v = _box_frame(p, boxes)
    c, s = np.cos(boxes[:, 4]), np.sin(boxes[:, 4])
    du = d[:, None, 0] * c + d[:, None, 1] * s
    dv = d[:, None, 1] * c - d[:, None, 0] * s
    hit = np.ones(u.shape, dtype=bool)
    t_enter = np.full(u.shape, -np.inf)
    t_exit = np.full(u.shape, np.inf)
    for q, dq, half in ((u, du, boxes[None, :, 2]), (v, dv, boxes[None, :, 3])):
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - q) / dq
            t2 = (half - q) / dq
        parallel = dq == 0.0
        hit &= ~(parallel & (np.abs(q) > half))
        t_enter = np.maximum(t_enter, np.where(parallel, -np.inf, np.minimum(t1, t2)))
        t_exit = np.minimum(t_exit, np.where(parallel, np.inf, np.maximum(t1, t2)))
    return hit & (t_enter <= t_exit) & (t_exit >= 0.0) & (t_enter <= 1.0)


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """(B, 4, 2) corners of oriented boxes (counter-clockwise)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    c, s = np.cos(boxes[:, 4]), np.sin(boxes[:, 4])
    signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    u = signs[None, :, 0] * boxes[:, None, 2]
    v = signs[None, :, 1] * boxes[:, None, 3]
    return np.stack([boxes[:, None, 0] + u * c[:, None] - v * s[:, None],
                     boxes[:, None, 1] + u * s[:, None] + v * c[:, None]], axis=-1)


def _slab(p: float, d: float, lo: float, hi: float) -> tuple[float, float]:
    """One axis of :func:`_segments_hit_boxes` for one segment and box: ``(t_min, t_max)``."""
    if d == 0.0:
        inside = p >= lo and p <= hi
        return (-math.inf, math.inf) if inside else (math.inf, -math.inf)
    t1, t2 = (lo - p) / d, (hi - p) / d
    return (t1, t2) if t1 <= t2 else (t2, t1)


def _slab_hit(px: float, dx: float, x0: float, x1: float, py: float, dy: float, y0: float, y1: float) -> bool:
    """Does the segment ``p + t d``, ``t`` in [0, 1], touch the box: the slab test of one pair."""
    tx0, tx1 = _slab(px, dx, x0, x1)
    ty0, ty1 = _slab(py, dy, y0, y1)
    t_enter = tx0 if tx0 >= ty0 else ty0
    t_exit = tx1 if tx1 <= ty1 else ty1
    return t_enter <= t_exit and t_exit >= 0.0 and t_enter <= 1.0


# ---------------------------------------------------------------------- compiled, for the planning loop
@jit(inline=True)
def _slab_compiled(p, d, lo, hi):
    """:func:`_slab`, compiled (the same operations)."""
    if d == 0.0:
        if p >= lo and p <= hi:
            return -math.inf, math.inf
        return math.inf, -math.inf
    t1, t2 = (lo - p) / d, (hi - p) / d
    return (t1, t2) if t1 <= t2 else (t2, t1)


@jit
def segment_free_walls(px, py, qx, qy, rows):
    """:meth:`MazeMap.segment_free_xy` of a map of walls only, compiled: ``rows`` are the walls'
    ``_wall_row`` tuples ``(k, 8)``; the same operations in the same order, so the same answers."""
    if not (0.0 <= px <= 1.0 and 0.0 <= py <= 1.0 and 0.0 <= qx <= 1.0 and 0.0 <= qy <= 1.0):
        return False
    dx, dy = qx - px, qy - py
    lox, hix = (px, qx) if px <= qx else (qx, px)
    loy, hiy = (py, qy) if py <= qy else (qy, py)
    for w in range(rows.shape[0]):
        if hix < rows[w, 4] or lox > rows[w, 6] or hiy < rows[w, 5] or loy > rows[w, 7]:
            continue
        tx0, tx1 = _slab_compiled(px, dx, rows[w, 0], rows[w, 2])
        ty0, ty1 = _slab_compiled(py, dy, rows[w, 1], rows[w, 3])
        t_enter = tx0 if tx0 >= ty0 else ty0
        t_exit = tx1 if tx1 <= ty1 else ty1
        if t_enter <= t_exit and t_exit >= 0.0 and t_enter <= 1.0:
            return False
    return True


@jit
def maze_steer(a, target, step, rows, x_new, distance):
    """:meth:`Maze2DProblem.steer` for the planning loop (:mod:`gnn_mp_envs.core.loop`): 1 or -1 (one
    collision check per edge)."""
    fx, fy, tx, ty = a[0], a[1], target[0], target[1]
    dx, dy = tx - fx, ty - fy
    d = math.sqrt(dx * dx + dy * dy)
    distance[0] = d
    if d < ZERO_LENGTH:
        return 1
    if d <= step:
        nx, ny = tx, ty
    else:
        t = step / d
        nx, ny = fx + t * dx, fy + t * dy
    x_new[0], x_new[1] = nx, ny
    return 1 if segment_free_walls(fx, fy, nx, ny, rows) else -1


@jit
def maze_motion(a, b, rows):
    """:meth:`Maze2DProblem.check_motion` for the planning loop: 1 or -1."""
    return 1 if segment_free_walls(a[0], a[1], b[0], b[1], rows) else -1


@jit
def maze_goal_distance(a, b):
    """:meth:`Maze2DProblem.pair_distance`, compiled."""
    dx, dy = a[0] - b[0], a[1] - b[1]
    return math.sqrt(dx * dx + dy * dy)


def random_maze(rng: np.random.Generator, num_walls: tuple[int, int] = (1, 3),
                num_blobs: int = 0) -> tuple[MazeMap, int]:
    """Random walls with narrow gaps; returns the map and the wall axis (0: walls at fixed x).

    Walls are 0.03-0.06 thick; each has one or two gaps 0.035-0.06 wide. With more than
    one wall, each sits in its own slot of [0.1, 0.9] so the rooms between them stay open.
    """
    n = int(rng.integers(num_walls[0], num_walls[1] + 1))
    axis = int(rng.integers(2))
    # One wall per equal slot of [0.1, 0.9], jittered inside its slot: rooms stay open.
    slot = 0.8 / n
    positions = [0.1 + slot * (k + float(rng.uniform(0.35, 0.65))) for k in range(n)]
    walls = []
    for c in positions:
        thick = float(rng.uniform(0.03, 0.06))
        gaps = sorted((float(rng.uniform(0.1, 0.9)), float(rng.uniform(0.035, 0.06)))
                      for _ in range(int(rng.integers(1, 3))))
        edges = [0.0]
        for centre, width in gaps:
            edges += [centre - width / 2, centre + width / 2]
        edges.append(1.0)
        for a, b in zip(edges[0::2], edges[1::2]):
            if b - a <= 1e-6:
                continue
            if axis == 0:  # wall at fixed x, spanning y
                walls.append([c - thick / 2, a, c + thick / 2, b])
            else:
                walls.append([a, c - thick / 2, b, c + thick / 2])
    blobs = np.zeros((0, 3))
    if num_blobs:
        blobs = np.column_stack([rng.uniform(0.05, 0.95, (num_blobs, 2)),
                                 rng.uniform(0.03, 0.07, num_blobs)])
    return MazeMap(np.array(walls), blobs), axis


def sample_endpoints(rng: np.random.Generator, maze: MazeMap, axis: int,
                     max_tries: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Start before the first wall and goal beyond the last one, both in free space."""
    along = 0 if axis == 0 else 1
    if len(maze.walls):
        first = maze.walls[:, along].min()
        last = maze.walls[:, along + 2].max()
    else:
        first, last = 0.5, 0.5
    out = []
    for lo, hi in ((0.02, first - ENDPOINT_MARGIN), (last + ENDPOINT_MARGIN, 0.98)):
        for _ in range(max_tries):
            x = np.empty(2)
            x[along] = rng.uniform(lo, hi)
            x[1 - along] = rng.uniform(0.02, 0.98)
            probe = x + ENDPOINT_MARGIN * np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]])
            if maze.is_free(probe).all():
                out.append(x)
                break
        else:
            raise RuntimeError("could not place a free start/goal; the map is too cluttered")
    if rng.random() < 0.5:
        out.reverse()
    return out[0], out[1]


class Maze2DProblem(Problem):
    """A point robot in the unit square among the walls of a :class:`MazeMap`."""

    task = "maze2d"

    def __init__(self, maze: MazeMap, start: np.ndarray, goal: np.ndarray,
                 step_size: float = STEP_SIZE) -> None:
        super().__init__(start, goal, low=np.zeros(2), high=np.ones(2),
                         step_size=step_size, resolution=step_size)
        self.maze = maze
        # distance's metric (plain Euclidean: the scan's floats are distance's), for the exact k-d index
        self.nearest_metric = (np.ones(2), np.zeros(2, dtype=np.bool_))
        self._kernel: CompiledKernel | None = None

    def compiled_kernel(self) -> CompiledKernel | None:
        """The planning loop's kernel of a map of walls only (blobs and oriented boxes: None, the Python
        planner)."""
        if self._kernel is None and not (len(self.maze.blobs) or len(self.maze.boxes)):
            rows = np.array(self.maze._wall_rows, dtype=np.float64).reshape(-1, 8)
            self._kernel = CompiledKernel("maze2d-walls", maze_steer, maze_motion, maze_goal_distance, rows)
        return self._kernel

    def __getstate__(self) -> dict:
        """Pickled without the compiled kernel (rebuilt on first use)."""
        return {**self.__dict__, "_kernel": None}

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        return self.maze.is_free(states)

    def check_motion(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Exact segment test; counts as one collision check."""
        return self.check_segment(float(a[0]), float(a[1]), float(b[0]), float(b[1]))

    def check_segment(self, ax: float, ay: float, bx: float, by: float) -> bool:
        """:meth:`check_motion` of ``(ax, ay) -> (bx, by)`` given as floats (counted the same)."""
        self.edges_checked += 1
        self.collision_checks += 1
        return self.maze.segment_free_xy(ax, ay, bx, by)

    # The planner's distances without numpy's wrappers: rows as ``sqrt(dx*dx + dy*dy)`` in three
    # ufuncs, a pair in plain floats; both are bit for bit what the base class's ``einsum`` gives
    # for two coordinates (tests/test_core.py compares them).
    def distance(self, states: np.ndarray, x: np.ndarray) -> np.ndarray:
        d = states - x     # the base class's difference, without its call
        d *= d             # the einsum's two products and their sum, without its wrapper
        s = d[..., 0] + d[..., 1]
        return np.sqrt(s)

    @staticmethod
    def pair_distance(a: np.ndarray, b: np.ndarray) -> float:
        dx, dy = float(a[0]) - float(b[0]), float(a[1]) - float(b[1])
        return math.sqrt(dx * dx + dy * dy)

    def steer(self, x_from: np.ndarray, x_to: np.ndarray) -> Edge | None:
        """:meth:`Problem.steer` in plain floats (the same states and costs)."""
        fx, fy = x_from.tolist()
        tx, ty = x_to.tolist()
        dx, dy = tx - fx, ty - fy
        d = math.sqrt(dx * dx + dy * dy)        # pair_distance(x_to, x_from)
        if d < ZERO_LENGTH:
            return None
        if d <= self.step_size:
            nx, ny = tx, ty
            x_new = np.asarray(x_to, dtype=np.float64)
        else:
            t = self.step_size / d
            nx, ny = fx + t * dx, fy + t * dy
            x_new = np.array([nx, ny])
        if not self.check_segment(fx, fy, nx, ny):
            return None
        return Edge(x_new, min(d, self.step_size))

    def in_goal(self, x: np.ndarray) -> bool:
        return self.pair_distance(x, self.goal) <= self.goal_tolerance

    def goal_connection(self, x: np.ndarray) -> Edge | None:
        d = self.pair_distance(self.goal, x)
        if d > self.step_size or not self.check_motion(x, self.goal):
            return None
        return Edge(self.goal.copy(), d)


class Maze2DTask(Task):
    """Seeded Maze2D problems: 1-3 walls with narrow gaps, start and goal across them."""

    name = "maze2d"
    #: ``[cx, cy, half_x, half_y, cos, sin, is_blob]``: the centre, the half extents along the
    #: obstacle's own axes and its turn (walls: ``cos = 1, sin = 0``; blobs: ``half_x = half_y = r``).
    obstacle_width = 7
    #: Room for the densest scene family (forests); the observation pads to it.
    max_obstacles = 64

    def __init__(self, num_walls: tuple[int, int] = (1, 3), num_blobs: int = 0,
                 step_size: float = STEP_SIZE) -> None:
        self.num_walls = tuple(num_walls)
        self.num_blobs = int(num_blobs)
        self.step_size = float(step_size)

    def sample_problem(self, rng: np.random.Generator) -> Maze2DProblem:
        maze, axis = random_maze(rng, self.num_walls, self.num_blobs)
        start, goal = sample_endpoints(rng, maze, axis)
        return Maze2DProblem(maze, start, goal, self.step_size)

    def make_problem(self, spec: Any) -> Problem:
        if isinstance(spec, dict):
            check_keys(spec, ("start", "goal", "walls", "blobs", "boxes"), "a maze2d problem dict")
            try:
                maze = MazeMap(spec.get("walls", np.zeros((0, 4))), spec.get("blobs", np.zeros((0, 3))),
                               spec.get("boxes", np.zeros((0, 5))))
                spec = Maze2DProblem(maze, spec["start"], spec["goal"], self.step_size)
            except KeyError as e:
                raise InvalidProblemError(f"a maze2d problem dict needs 'start' and 'goal' (missing {e})") from None
        return super().make_problem(spec)

    def obstacle_rows(self, problem: Problem) -> np.ndarray:
        return maze_rows(problem.maze, self.max_obstacles)

    def render_rgb(self, problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
        return render_maze2d(problem, tree, path)


def maze_rows(maze: MazeMap, max_rows: int) -> np.ndarray:
    """The map's obstacles as observation rows (see ``Maze2DTask.obstacle_width``): walls, blobs,
    oriented boxes in that order; InvalidProblemError beyond ``max_rows``."""
    w, b, o = maze.walls, maze.blobs, maze.boxes
    n = len(w) + len(b) + len(o)
    if n > max_rows:
        raise InvalidProblemError(f"a maze2d problem has at most {max_rows} walls, blobs and boxes, got {n}")
    rows = np.zeros((n, 7))
    k = len(w)
    rows[:k, :2] = (w[:, :2] + w[:, 2:]) / 2
    rows[:k, 2:4] = (w[:, 2:] - w[:, :2]) / 2
    rows[:k, 4] = 1.0
    rows[k:k + len(b), :2] = b[:, :2]
    rows[k:k + len(b), 2] = rows[k:k + len(b), 3] = b[:, 2]
    rows[k:k + len(b), 4] = rows[k:k + len(b), 6] = 1.0
    k += len(b)
    rows[k:, :4] = o[:, :4]
    rows[k:, 4], rows[k:, 5] = np.cos(o[:, 4]), np.sin(o[:, 4])
    return rows


def render_maze2d(problem: Maze2DProblem, tree: Any, path: np.ndarray | None) -> np.ndarray:
    """Walls and boxes (grey), blobs, the tree(s), start (green), goal (red) and the path (magenta)."""
    from matplotlib.patches import Circle, Polygon, Rectangle
    fig, ax = figure()
    maze = problem.maze
    for x0, y0, x1, y1 in maze.walls:
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color="0.35"))
    for cx, cy, r in maze.blobs:
        ax.add_patch(Circle((cx, cy), r, color="0.5"))
    for corners in box_corners(maze.boxes):
        ax.add_patch(Polygon(corners, closed=True, color="0.35"))
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
    return to_rgb(fig)
