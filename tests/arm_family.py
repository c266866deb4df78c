"""Arm scene families defined outside the package, as a user would (``--import tests.arm_family``):
a shipped layout with other ranges, and a layout of its own."""

from __future__ import annotations

import numpy as np

from gnn_mp_envs.robots.geometry import EndEffectorTarget, Obstacle
from gnn_mp_envs.tasks.arm import SCENE_FAMILIES, register_scene_family


def lone_wall_layout(rng: np.random.Generator, params: dict):
    """One wall between the robot and a goal behind it (tool down)."""
    azimuth = float(rng.uniform(*params["azimuth"]))
    c, s = np.cos(azimuth), np.sin(azimuth)
    height = float(rng.uniform(*params["wall_height"]))
    wall = Obstacle("box", (0.02, 0.2, height / 2), (0.38 * c, 0.38 * s, height / 2), azimuth)
    goal = EndEffectorTarget((0.52 * c, 0.52 * s, 0.12), (0.0, 0.0, -1.0))
    return [wall], goal, azimuth, 0.0, {}


register_scene_family("narrow-crevice", {**SCENE_FAMILIES["train-a"], "gap": (0.14, 0.16)}, replace=True)
register_scene_family("lone-wall", {"azimuth": (-0.6, 0.6), "wall_height": (0.25, 0.35)}, lone_wall_layout,
                      replace=True)
