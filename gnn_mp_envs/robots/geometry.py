"""Geometry every robot task shares: obstacles (boxes, cylinders, spheres), end-effector targets,
scenes, and the quaternion arithmetic that places them.

A scene is a tuple of :class:`Obstacle` or a :class:`Scene` (a family's draw: obstacles, the goal's
end-effector target and where starts are drawn). Quaternions are ``(x, y, z, w)``, as pybullet's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import InvalidProblemError


def _floats(name: str, value: Any) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InvalidProblemError(f"obstacle {name} must be a sequence of numbers, got {value!r}") from None


@dataclass(frozen=True)
class Obstacle:
    """A static collision shape: ``box`` (``size`` = half extents x, y, z), ``cylinder``
    (``size`` = radius, height; axis along its z) or ``sphere`` (``size`` = radius), centred at
    ``position`` and rotated by ``yaw`` about z, or by ``orientation``, a unit quaternion
    (x, y, z, w), for shapes that are not upright (then ``yaw`` stays 0)."""

    kind: str
    size: tuple[float, ...]
    position: tuple[float, float, float]
    yaw: float = 0.0
    orientation: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        """Refuse shapes pybullet would silently accept or misreport (one message naming the field)."""
        widths = {"box": 3, "cylinder": 2, "sphere": 1}
        if self.kind not in widths:
            raise InvalidProblemError(f"obstacle kind must be 'box', 'cylinder' or 'sphere', got {self.kind!r}")
        size = _floats("size", self.size)
        if len(size) != widths[self.kind]:
            what = {"box": "half extents (x, y, z)", "cylinder": "(radius, height)", "sphere": "(radius,)"}[self.kind]
            raise InvalidProblemError(f"a {self.kind} obstacle's size is {what}: {widths[self.kind]} numbers, "
                                      f"got {len(size)}")
        if not all(math.isfinite(v) and v > 0 for v in size):
            raise InvalidProblemError(f"obstacle size must be finite and > 0, got {list(size)}")
        position = _floats("position", self.position)
        if len(position) != 3 or not all(math.isfinite(v) for v in position):
            raise InvalidProblemError(f"obstacle position must be 3 finite numbers, got {list(position)}")
        if not math.isfinite(float(self.yaw)):
            raise InvalidProblemError(f"obstacle yaw must be finite, got {self.yaw}")
        if self.orientation is not None:
            q = _floats("orientation", self.orientation)
            if len(q) != 4 or not all(math.isfinite(v) for v in q) or abs(math.hypot(*q) - 1.0) > 1e-6:
                raise InvalidProblemError(f"obstacle orientation must be a unit quaternion (x, y, z, w), got {list(q)}")
            if float(self.yaw) != 0.0:
                raise InvalidProblemError("give an obstacle's rotation as yaw or as orientation, not both")
            object.__setattr__(self, "orientation", q)
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "yaw", float(self.yaw))

    def quaternion(self) -> tuple[float, float, float, float]:
        """The rotation as a quaternion (x, y, z, w)."""
        if self.orientation is not None:
            return self.orientation
        return (0.0, 0.0, float(np.sin(self.yaw / 2)), float(np.cos(self.yaw / 2)))

    def key(self) -> tuple:
        """Shape identity: bodies with the same key can be moved instead of rebuilt."""
        return (self.kind,) + tuple(round(float(s), 4) for s in self.size)


@dataclass(frozen=True)
class EndEffectorTarget:
    """Where a configuration puts the tool: flange position, tool axis (unit vector) and
    the range of roll about that axis that inverse kinematics may use."""

    position: tuple[float, float, float]
    axis: tuple[float, float, float]
    roll: tuple[float, float] = (-np.pi, np.pi)


@dataclass(frozen=True)
class Scene:
    """One concrete scene: its family, obstacles and the goal tool target.

    ``azimuth`` is the direction of the goal structure and ``start_side`` (+1/-1/0) the
    side of it where start targets are drawn (0: either side, per draw).
    """

    family: str
    obstacles: tuple[Obstacle, ...]
    goal: EndEffectorTarget
    azimuth: float
    start_side: float = 0.0
    meta: dict = field(default_factory=dict, compare=False)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (x, y, z, w) quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def yaw_quaternion(angle: float) -> np.ndarray:
    """The rotation by ``angle`` about z."""
    return np.array([0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)])


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation by ``angle`` about ``axis`` (any length)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    return np.append(np.sin(angle / 2) * axis, np.cos(angle / 2))


def tool_quaternion(axis: tuple[float, float, float], roll: float) -> np.ndarray:
    """Flange orientation whose z axis (the tool axis) is ``axis``, rolled by ``roll``."""
    z = np.array([0.0, 0.0, 1.0])
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    cross = np.cross(z, a)
    if np.linalg.norm(cross) < 1e-9:
        align = np.array([0.0, 0.0, 0.0, 1.0]) if a[2] > 0 else axis_angle([1.0, 0.0, 0.0], np.pi)
    else:
        align = axis_angle(cross, float(np.arccos(np.clip(z @ a, -1.0, 1.0))))
    return quat_mul(align, axis_angle(z, roll))
