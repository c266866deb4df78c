"""Tabletop scene families of the arm task, as data plus one small generator per layout.

A scene is a list of :class:`~gnn_mp_envs.robots.geometry.Obstacle` (boxes and cylinders standing on or
above the table) and two end-effector targets: where the goal configuration reaches (inside a
crevice, under a shelf, into a cubby) and where the start configuration is (elsewhere
around the robot). :data:`SCENE_FAMILIES` holds the parameter ranges of each family; a
family's ``layout`` names the generator in :data:`LAYOUTS` that turns the ranges and an
``rng`` into a concrete :class:`Scene`. The robot base sits at the origin on the table top
(``z = 0``), facing ``+x``.

``train-a`` and ``train-b`` are the training families; ``test`` is held out: different
obstacle types (cylinders, a thin wall, a closed cubby) and counts. Beyond them:
``pillars`` is a validation kind held out from training (for decisions), and ``tall-clutter``,
``shelves`` and ``bins`` are out-of-distribution test kinds, layouts no generator above makes
(never trained or tuned on).
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from gnn_mp_envs.robots.geometry import EndEffectorTarget, Obstacle, Scene

#: Obstacles keep this distance from the robot's base axis (the base link is ~0.1 wide).
BASE_CLEARANCE = 0.22


#: Family name -> layout and parameter ranges ``(low, high)`` (lengths in m, angles in rad).
SCENE_FAMILIES: dict[str, dict[str, Any]] = {
    # Table with box clutter and a crevice between two blocks; the goal points the tool
    # down into the crevice.
    "train-a": {
        "layout": "crevice",
        "distance": (0.40, 0.50),       # radial distance of the crevice centre
        "azimuth": (-0.9, 0.9),         # direction of the crevice centre
        "gap": (0.16, 0.20),            # free width between the blocks
        "block_half_depth": (0.05, 0.08),
        "block_half_width": (0.04, 0.07),
        "block_height": (0.32, 0.40),
        "goal_height": (0.04, 0.08),    # tool flange height inside the crevice
        "clutter": (2, 4),              # number of extra boxes
        "clutter_half_size": (0.03, 0.07),
        "clutter_height": (0.06, 0.25),
    },
    # A shelf whose top board overhangs its open front; the goal reaches in under it.
    "train-b": {
        "layout": "shelf",
        "distance": (0.50, 0.58),       # radial distance of the shelf centre
        "azimuth": (-0.9, 0.9),
        "inner_width": (0.34, 0.42),
        "depth": (0.22, 0.30),
        "height": (0.40, 0.46),         # height of the underside of the top board
        "overhang": (0.04, 0.08),       # board overhang beyond the side panels' front
        "thickness": 0.04,
        "goal_height": (0.15, 0.22),
        "goal_inset": (0.06, 0.14),     # tool flange behind the side panels' front edge
        "clutter": (0, 2),
        "clutter_half_size": (0.03, 0.06),
        "clutter_height": (0.06, 0.20),
    },
    # Held out: a closed box-cubby (roof, back, sides), cylindrical posts and a thin wall.
    "test": {
        "layout": "cubby",
        "distance": (0.50, 0.58),
        "azimuth": (-0.8, 0.8),
        "inner_width": (0.30, 0.36),
        "depth": (0.22, 0.28),
        "height": (0.26, 0.32),
        "thickness": 0.04,
        "goal_height": (0.10, 0.15),
        "goal_inset": (0.06, 0.12),
        "posts": (2, 4),
        "post_radius": (0.02, 0.035),
        "post_height": (0.25, 0.45),
        "wall_length": (0.25, 0.35),
        "wall_height": (0.20, 0.30),
        "wall_offset": (0.95, 1.25),    # wall azimuth relative to the cubby (either side)
    },
    # Validation kind: cylinders standing around a goal reached with the tool down to the table.
    "pillars": {
        "layout": "pillars",
        "distance": (0.38, 0.5),
        "azimuth": (-0.9, 0.9),
        "goal_height": (0.06, 0.12),
        "ring": (3, 4),                  # pillars around the goal
        "ring_radius": (0.15, 0.19),     # their distance from the goal
        "others": (2, 4),
        "post_radius": (0.025, 0.04),
        "post_height": (0.3, 0.5),
    },
    # OOD: tall boxes packed around the goal and over the table; the tool reaches down between them.
    "tall-clutter": {
        "layout": "tall-clutter",
        "distance": (0.4, 0.5),
        "azimuth": (-0.9, 0.9),
        "goal_height": (0.08, 0.14),
        "ring": (3, 5),
        "ring_radius": (0.17, 0.21),
        "others": (4, 6),
        "half_size": (0.03, 0.05),
        "height": (0.4, 0.6),
    },
    # OOD: a bookshelf of two or three levels; the goal reaches into a lower level.
    "shelves": {
        "layout": "shelves",
        "distance": (0.52, 0.6),
        "azimuth": (-0.9, 0.9),
        "inner_width": (0.36, 0.44),
        "depth": (0.22, 0.28),
        "levels": (2, 3),
        "level_height": (0.18, 0.24),
        "thickness": 0.03,
        "goal_inset": (0.05, 0.1),
    },
    # OOD: an open-top bin (four walls) on the table, the tool down into it; a second bin nearby.
    "bins": {
        "layout": "bins",
        "distance": (0.42, 0.52),
        "azimuth": (-0.9, 0.9),
        "inner": (0.16, 0.22),           # inner width of the bin (square)
        "wall_height": (0.16, 0.24),
        "thickness": 0.02,
        "goal_depth": (0.04, 0.08),      # flange height above the bin floor
    },
}

#: Start targets, shared by every family: tool down, on the far side of the robot.
START_RANGES: dict[str, tuple[float, float]] = {
    "offset": (1.6, 2.8),      # |azimuth of start - azimuth of goal structure|
    "distance": (0.30, 0.45),
    "height": (0.25, 0.45),
}

DOWN = (0.0, 0.0, -1.0)


def _u(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return float(rng.uniform(r[0], r[1]))


def _polar(radius: float, azimuth: float, z: float) -> tuple[float, float, float]:
    return (radius * float(np.cos(azimuth)), radius * float(np.sin(azimuth)), z)


def _frame(centre_r: float, azimuth: float):
    """Position in a frame whose x axis points radially out at ``azimuth`` (u = radial,
    v = tangential), used to lay out structures facing the robot."""
    c, s = float(np.cos(azimuth)), float(np.sin(azimuth))

    def at(u: float, v: float, z: float) -> tuple[float, float, float]:
        x, y = centre_r + u, v
        return (c * x - s * y, s * x + c * y, z)

    return at


def _box(half: tuple[float, float, float], pos: tuple[float, float, float], yaw: float) -> Obstacle:
    return Obstacle("box", tuple(float(h) for h in half), tuple(float(p) for p in pos), float(yaw))


def _clutter(rng: np.random.Generator, spec: dict, avoid: list[tuple[float, float, float]],
             n: int) -> list[Obstacle]:
    """``n`` random boxes on the table, away from the base and from ``avoid`` (x, y, radius)."""
    out: list[Obstacle] = []
    for _ in range(n):
        for _ in range(50):
            r, a = _u(rng, (0.30, 0.65)), _u(rng, (-np.pi, np.pi))
            hx, hy = _u(rng, spec["clutter_half_size"]), _u(rng, spec["clutter_half_size"])
            h = _u(rng, spec["clutter_height"])
            x, y, _ = _polar(r, a, 0.0)
            if all(np.hypot(x - ax, y - ay) > ar + max(hx, hy) for ax, ay, ar in avoid):
                out.append(_box((hx, hy, h / 2), (x, y, h / 2), _u(rng, (0, np.pi))))
                avoid.append((x, y, max(hx, hy) * 1.5))
                break
    return out


def start_target(scene: Scene, rng: np.random.Generator) -> EndEffectorTarget:
    """A start tool target (tool down) on the far side of the robot from the goal structure."""
    side = scene.start_side or float(rng.choice([-1.0, 1.0]))
    a = scene.azimuth + side * _u(rng, START_RANGES["offset"])
    return EndEffectorTarget(_polar(_u(rng, START_RANGES["distance"]), a, _u(rng, START_RANGES["height"])),
                             DOWN)


def crevice_layout(rng: np.random.Generator, spec: dict):
    """Two blocks with a crevice between them (tool down into it) and box clutter."""
    r, a = _u(rng, spec["distance"]), _u(rng, spec["azimuth"])
    gap = _u(rng, spec["gap"])
    at = _frame(r, a)
    obstacles = []
    for side in (-1.0, 1.0):
        hd, hw, h = _u(rng, spec["block_half_depth"]), _u(rng, spec["block_half_width"]), _u(rng, spec["block_height"])
        obstacles.append(_box((hd, hw, h / 2), at(0.0, side * (gap / 2 + hw), h / 2), a))
    goal = EndEffectorTarget(at(0.0, 0.0, _u(rng, spec["goal_height"])), DOWN)
    cx, cy, _ = at(0.0, 0.0, 0.0)
    clutter = _clutter(rng, spec, [(cx, cy, gap / 2 + 0.25)], int(rng.integers(spec["clutter"][0], spec["clutter"][1] + 1)))
    return obstacles + clutter, goal, a, 0.0, {"gap": gap}


def _open_box(rng: np.random.Generator, spec: dict, at, a: float, overhang: float,
              closed_back: bool) -> tuple[list[Obstacle], float, float, float]:
    """Side panels, top board (and back wall) of a shelf/cubby whose open front faces the
    robot; returns the obstacles and the interior half width, depth and height."""
    t = spec["thickness"]
    w, d, h = _u(rng, spec["inner_width"]), _u(rng, spec["depth"]), _u(rng, spec["height"])
    obstacles = [_box((d / 2, t / 2, h / 2), at(0.0, s * (w / 2 + t / 2), h / 2), a) for s in (-1.0, 1.0)]
    obstacles.append(_box(((d + overhang) / 2, w / 2 + t, t / 2), at(-overhang / 2, 0.0, h + t / 2), a))
    if closed_back:
        obstacles.append(_box((t / 2, w / 2, h / 2), at(d / 2 + t / 2, 0.0, h / 2), a))
    return obstacles, w / 2, d, h


def shelf_layout(rng: np.random.Generator, spec: dict):
    """A shelf (side panels + overhanging top board); the tool reaches in horizontally."""
    r, a = _u(rng, spec["distance"]), _u(rng, spec["azimuth"])
    at = _frame(r, a)
    overhang = _u(rng, spec["overhang"])
    obstacles, hw, d, h = _open_box(rng, spec, at, a, overhang, closed_back=False)
    goal_u = -d / 2 + _u(rng, spec["goal_inset"])
    goal = EndEffectorTarget(at(goal_u, _u(rng, (-0.3, 0.3)) * hw, min(_u(rng, spec["goal_height"]), h - 0.1)),
                             (float(np.cos(a)), float(np.sin(a)), 0.0))
    cx, cy, _ = at(0.0, 0.0, 0.0)
    clutter = _clutter(rng, spec, [(cx, cy, max(hw, d / 2) + 0.2)],
                       int(rng.integers(spec["clutter"][0], spec["clutter"][1] + 1)))
    return obstacles + clutter, goal, a, 0.0, {"depth": d}


def cubby_layout(rng: np.random.Generator, spec: dict):
    """A closed cubby (held out): roof, sides and back; posts and a thin wall around it."""
    r, a = _u(rng, spec["distance"]), _u(rng, spec["azimuth"])
    at = _frame(r, a)
    obstacles, hw, d, h = _open_box(rng, spec, at, a, 0.0, closed_back=True)
    goal_u = -d / 2 + _u(rng, spec["goal_inset"])
    goal = EndEffectorTarget(at(goal_u, _u(rng, (-0.25, 0.25)) * hw, min(_u(rng, spec["goal_height"]), h - 0.1)),
                             (float(np.cos(a)), float(np.sin(a)), 0.0))
    side = float(rng.choice([-1.0, 1.0]))
    # A thin radial wall on one side of the cubby; the start lies beyond it.
    wa = a + side * _u(rng, spec["wall_offset"])
    length, wh = _u(rng, spec["wall_length"]), _u(rng, spec["wall_height"])
    wall_r = BASE_CLEARANCE + 0.08 + length / 2
    obstacles.append(_box((length / 2, spec["thickness"] / 2, wh / 2), _polar(wall_r, wa, wh / 2), wa))
    cx, cy, _ = at(0.0, 0.0, 0.0)
    avoid = [(cx, cy, max(hw, d / 2) + 0.18)]
    wx, wy, _ = _polar(wall_r, wa, 0.0)
    avoid.append((wx, wy, length / 2 + 0.05))
    for _ in range(int(rng.integers(spec["posts"][0], spec["posts"][1] + 1))):
        for _ in range(50):
            pr, pa = _u(rng, (0.32, 0.7)), _u(rng, (-np.pi, np.pi))
            rad, ph = _u(rng, spec["post_radius"]), _u(rng, spec["post_height"])
            x, y, _ = _polar(pr, pa, 0.0)
            if all(np.hypot(x - ax, y - ay) > ar + rad for ax, ay, ar in avoid):
                obstacles.append(Obstacle("cylinder", (rad, ph), (x, y, ph / 2)))
                avoid.append((x, y, rad + 0.12))
                break
    return obstacles, goal, a, side, {"wall_azimuth": wa}


def _ring_layout(rng: np.random.Generator, spec: dict, make) -> tuple:
    """A goal (tool down) at ``goal_height`` with ``ring`` obstacles around it and ``others``
    elsewhere over the table; ``make(x, y)`` builds one obstacle standing at ``(x, y)`` and
    returns it with its footprint radius."""
    r, a = _u(rng, spec["distance"]), _u(rng, spec["azimuth"])
    gx, gy, _ = _polar(r, a, 0.0)
    obstacles: list[Obstacle] = []
    avoid = []
    n = int(rng.integers(spec["ring"][0], spec["ring"][1] + 1))
    phase = _u(rng, (0.0, 2 * np.pi))
    for k in range(n):
        ang = phase + 2 * np.pi * k / n + _u(rng, (-0.3, 0.3))
        rr = _u(rng, spec["ring_radius"])
        ob, foot = make(gx + rr * np.cos(ang), gy + rr * np.sin(ang))
        obstacles.append(ob)
        avoid.append((ob.position[0], ob.position[1], foot))
    avoid.append((gx, gy, 0.06))
    for _ in range(int(rng.integers(spec["others"][0], spec["others"][1] + 1))):
        for _ in range(50):
            pr, pa = _u(rng, (0.3, 0.7)), _u(rng, (-np.pi, np.pi))
            x, y, _ = _polar(pr, pa, 0.0)
            ob, foot = make(x, y)
            if all(np.hypot(x - ax, y - ay) > ar + foot + 0.04 for ax, ay, ar in avoid):
                obstacles.append(ob)
                avoid.append((x, y, foot))
                break
    goal = EndEffectorTarget((gx, gy, _u(rng, spec["goal_height"])), DOWN)
    return obstacles, goal, a, 0.0, {}


def pillars_layout(rng: np.random.Generator, spec: dict):
    """Cylinders around a low goal (tool down) and elsewhere on the table (validation kind)."""
    def make(x: float, y: float):
        rad, h = _u(rng, spec["post_radius"]), _u(rng, spec["post_height"])
        return Obstacle("cylinder", (rad, h), (x, y, h / 2)), rad
    return _ring_layout(rng, spec, make)


def tall_clutter_layout(rng: np.random.Generator, spec: dict):
    """Tall boxes packed around a low goal (tool down) and over the table (OOD kind)."""
    def make(x: float, y: float):
        hx, hy, h = _u(rng, spec["half_size"]), _u(rng, spec["half_size"]), _u(rng, spec["height"])
        return _box((hx, hy, h / 2), (x, y, h / 2), _u(rng, (0, np.pi))), float(np.hypot(hx, hy))
    return _ring_layout(rng, spec, make)


def shelves_layout(rng: np.random.Generator, spec: dict):
    """A bookshelf (side panels, a board per level, a back wall) facing the robot; the tool reaches
    horizontally into the lowest level or the one above it (OOD kind)."""
    r, a = _u(rng, spec["distance"]), _u(rng, spec["azimuth"])
    at = _frame(r, a)
    t = spec["thickness"]
    w, d = _u(rng, spec["inner_width"]), _u(rng, spec["depth"])
    levels = int(rng.integers(spec["levels"][0], spec["levels"][1] + 1))
    heights = [_u(rng, spec["level_height"]) for _ in range(levels)]
    top = sum(heights) + levels * t
    obstacles = [_box((d / 2, t / 2, top / 2), at(0.0, s * (w / 2 + t / 2), top / 2), a) for s in (-1.0, 1.0)]
    obstacles.append(_box((t / 2, w / 2 + t, top / 2), at(d / 2 + t / 2, 0.0, top / 2), a))
    z = 0.0
    floors = []
    for h in heights:
        floors.append(z)
        z += h
        obstacles.append(_box((d / 2, w / 2, t / 2), at(0.0, 0.0, z + t / 2), a))
        z += t
    level = int(rng.integers(min(2, levels)))
    goal_z = floors[level] + heights[level] * _u(rng, (0.4, 0.6))
    goal = EndEffectorTarget(at(-d / 2 + _u(rng, spec["goal_inset"]), _u(rng, (-0.25, 0.25)) * w / 2, goal_z),
                             (float(np.cos(a)), float(np.sin(a)), 0.0))
    return obstacles, goal, a, 0.0, {"levels": levels}


def bins_layout(rng: np.random.Generator, spec: dict):
    """An open-top bin (four walls) on the table with the tool down into it, and a second bin
    beside it (OOD kind)."""
    r, a = _u(rng, spec["distance"]), _u(rng, spec["azimuth"])
    t = spec["thickness"]
    obstacles = []
    side = float(rng.choice([-1.0, 1.0]))
    centres = [(r, a), (r + _u(rng, (-0.05, 0.05)), a + side * _u(rng, (0.55, 0.7)))]
    inner0 = 0.0
    for k, (rr, aa) in enumerate(centres):
        at = _frame(rr, aa)
        inner, h = _u(rng, spec["inner"]), _u(rng, spec["wall_height"])
        inner0 = inner if k == 0 else inner0
        half = inner / 2 + t / 2
        for s in (-1.0, 1.0):
            obstacles.append(_box((t / 2, half + t / 2, h / 2), at(s * half, 0.0, h / 2), aa))
            obstacles.append(_box((half - t / 2, t / 2, h / 2), at(0.0, s * half, h / 2), aa))
    at = _frame(r, a)
    spread = inner0 / 2 - 0.07
    goal = EndEffectorTarget(at(_u(rng, (-spread, spread)), _u(rng, (-spread, spread)), _u(rng, spec["goal_depth"])),
                             DOWN)
    return obstacles, goal, a, 0.0, {"inner": inner0}


LAYOUTS: dict[str, Callable] = {"crevice": crevice_layout, "shelf": shelf_layout, "cubby": cubby_layout,
                                "pillars": pillars_layout, "tall-clutter": tall_clutter_layout,
                                "shelves": shelves_layout, "bins": bins_layout}


def sample_scene(family: str, rng: np.random.Generator) -> Scene:
    """A random scene of ``family`` (a key of :data:`SCENE_FAMILIES`)."""
    try:
        spec = SCENE_FAMILIES[family]
    except KeyError:
        raise ValueError(f"unknown arm scene {family!r}; known: {sorted(SCENE_FAMILIES)}") from None
    obstacles, goal, azimuth, side, meta = LAYOUTS[spec["layout"]](rng, spec)
    return Scene(family, tuple(obstacles), goal, float(azimuth), float(side), meta)


def register_scene_family(name: str, params: dict[str, Any], layout: str | Callable | None = None, *,
                          replace: bool = False) -> None:
    """Add an arm scene family the whole tool chain plans by name: ``ArmTask(scene=name)``,
    ``gym.make("GNNMP/ArmBiRRT-v0", scene=name)``, ``gnn-mp benchmark --task arm --scene name``
    (with ``--import`` of the module making this call, so that worker processes and the OMPL
    runner register it too).

    ``params``: the parameter ranges the layout reads (like an entry of :data:`SCENE_FAMILIES`).
    ``layout``: the name of a layout in :data:`LAYOUTS` (a shipped layout with other ranges), or
    a function ``(rng, params) -> (obstacles, goal, azimuth, start_side, meta)`` (see
    :func:`crevice_layout`), registered in :data:`LAYOUTS` under its ``__name__``; default:
    ``params["layout"]``. One scene is drawn (seed 0) to check the layout before the family is
    added; a bad family is a one-line ``ValueError``."""
    from gnn_mp_envs.registration import TASK_SPECS, register_scene
    if not isinstance(name, str) or not name or name == "train":
        raise ValueError(f"a scene family needs a name other than 'train' (either training family), got {name!r}")
    if name in SCENE_FAMILIES and not replace:
        raise ValueError(f"arm scene family {name!r} already exists (replace=True to redefine it)")
    if not isinstance(params, dict):
        raise ValueError(f"scene family {name!r}: params must be a dict of parameter ranges, got {type(params).__name__}")
    layout = params.get("layout") if layout is None else layout
    if callable(layout):
        LAYOUTS[layout.__name__] = layout
        layout = layout.__name__
    if layout not in LAYOUTS:
        raise ValueError(f"scene family {name!r}: unknown layout {layout!r}; known: {', '.join(sorted(LAYOUTS))} "
                         "(or pass the layout function)")
    spec = {**params, "layout": layout}
    try:
        obstacles, goal, azimuth, side, meta = LAYOUTS[layout](np.random.default_rng(0), spec)
        if not (all(isinstance(ob, Obstacle) for ob in obstacles) and isinstance(goal, EndEffectorTarget)
                and math.isfinite(float(azimuth)) and float(side) in (-1.0, 0.0, 1.0) and isinstance(meta, dict)):
            raise TypeError("expected (obstacles, goal target, azimuth, start side -1/0/1, meta dict)")
    except Exception as exc:
        raise ValueError(f"scene family {name!r}: layout {layout!r} failed on a first draw "
                         f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    SCENE_FAMILIES[name] = spec
    if "arm" in TASK_SPECS:                             # the environment and the CLI check scenes there
        register_scene("arm", name)
