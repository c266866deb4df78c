"""What the simulator and the checkers need to know about a robot (:class:`RobotModel`), and where a
robot's files live: ``models/<robot>/`` holds its URDF and collision meshes (where they are not
pybullet_data's), its facts (``robot.json``), its sphere model (``<robot>.npz``) and its licences."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from gnn_mp_envs.robots.geometry import Obstacle

#: The robots' folders.
MODELS_DIR = Path(__file__).resolve().parent / "models"


@dataclass(frozen=True)
class RobotModel:
    """A robot as the planner sees it: its URDF (a ``pybullet_data`` path or an absolute one), the
    pybullet joint indices planned (in state order) and their limits, the flange link, joints held
    at a fixed position (the Panda's fingers), link-name pairs whose contact is not a collision,
    a safety margin of the planner's checks, and the box it stands on (whose contact with
    ``base_links`` is then ignored)."""

    urdf: str
    joints: tuple[int, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    ee_link: int
    held_joints: tuple[tuple[int, float], ...] = ()
    allowed_collisions: tuple[tuple[str, str], ...] = ()
    #: Safety margin of the planner's checks (m): a contact closer than this is a collision (the
    #: independent re-check of returned paths, ``RobotWorld.collides(q, CONTACT_DISTANCE)``, uses none).
    padding: float = 0.0
    #: The table the robot stands on (None: it stands on nothing the scene holds).
    table: Obstacle | None = None
    base_links: tuple[int, ...] = (-1, 0)
    #: Name of the robot's shipped sphere model (``models/<name>/<name>.npz``, made by
    #: ``python -m tools.spherize``), for the compiled checker; None: pybullet only.
    spheres: str | None = None


def model_dir(name: str) -> Path:
    """The folder of robot ``name``'s files."""
    return MODELS_DIR / name


def sphere_model_path(name: str) -> Path:
    """The shipped sphere model file of robot ``name``."""
    return model_dir(name) / f"{name}.npz"


def urdf_file(urdf: str) -> Path:
    """A RobotModel's URDF as a file: absolute paths as they are, others inside ``pybullet_data``."""
    path = Path(urdf)
    if path.is_absolute():
        return path
    import pybullet_data
    return Path(pybullet_data.getDataPath()) / path
