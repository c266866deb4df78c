"""A robot's kinematic tree and collision geometry, read from its URDF: what the compiled sphere
checker (:mod:`gnn_mp_envs.robots.spheres`) needs for forward kinematics, and what the sphere
builder (:mod:`gnn_mp_envs.robots.spheres.build`) covers.

Only what the checkers use is read: links, their ``<collision>`` elements (mesh, box, cylinder,
sphere; origin and mesh scale) and joints (fixed, revolute, continuous, prismatic; origin, axis,
limits). Mesh files are OBJ or STL. pybullet collides the convex hull of each mesh, and of each
object (``o``/``g`` group) of an OBJ separately (a V-HACD decomposition is a compound of hulls):
:func:`mesh_parts` returns the point sets whose hulls pybullet collides.
"""

from __future__ import annotations

import math
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

#: Joint kinds of the kinematic tree, as the compiled forward kinematics numbers them.
FIXED, REVOLUTE, PRISMATIC = 0, 1, 2
_JOINT_KINDS = {"fixed": FIXED, "revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC}


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's fixed-axis roll-pitch-yaw: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@dataclass(frozen=True)
class Collision:
    """One ``<collision>`` element in its link's frame: ``kind`` ``"mesh"`` (``mesh``: the file,
    ``size``: its scale), ``"box"`` (full lengths), ``"cylinder"`` (radius, length along z) or
    ``"sphere"`` (radius); ``rotation`` and ``translation`` place it in the link frame."""

    kind: str
    size: tuple[float, ...]
    rotation: np.ndarray = field(compare=False)
    translation: np.ndarray = field(compare=False)
    mesh: Path | None = None
    #: ``concave="yes"``: pybullet collides the mesh's triangles, not their convex hull.
    concave: bool = False


@dataclass(frozen=True)
class Joint:
    """A joint of the tree: ``child``'s frame is ``parent``'s times the origin, then the motion
    about (revolute) or along (prismatic) ``axis``."""

    name: str
    kind: int
    parent: str
    child: str
    rotation: np.ndarray = field(compare=False)
    translation: np.ndarray = field(compare=False)
    axis: np.ndarray = field(compare=False)
    lower: float = 0.0
    upper: float = 0.0


@dataclass(frozen=True)
class URDFRobot:
    """Links (in an order where every parent comes before its children, the root first), the
    joint that places each non-root link, and each link's collision elements."""

    name: str
    links: tuple[str, ...]
    joints: dict[str, Joint] = field(compare=False)          # child link -> its joint
    collisions: dict[str, tuple[Collision, ...]] = field(compare=False)

    def joint(self, name: str) -> Joint:
        for j in self.joints.values():
            if j.name == name:
                return j
        raise KeyError(f"robot {self.name!r} has no joint {name!r}")

    def parent_child_pairs(self) -> set[frozenset[str]]:
        """Link pairs joined by one joint (Bullet never checks them against each other)."""
        return {frozenset((j.parent, j.child)) for j in self.joints.values()}


def _origin(element: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    if element is None:
        return np.eye(3), np.zeros(3)
    xyz = [float(v) for v in element.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in element.get("rpy", "0 0 0").split()]
    return rpy_matrix(*rpy), np.array(xyz, dtype=np.float64)


def _mesh_path(filename: str, urdf: Path) -> Path:
    """A mesh reference resolved as pybullet does: ``package://`` stripped, relative to the URDF."""
    for prefix in ("package://", "file://"):
        if filename.startswith(prefix):
            filename = filename[len(prefix):]
    path = Path(filename)
    return path if path.is_absolute() else urdf.parent / path


@lru_cache(maxsize=16)
def read_urdf(path: str | Path) -> URDFRobot:
    """The kinematic tree and collision elements of the URDF at ``path``."""
    path = Path(path)
    root = ET.parse(path).getroot()
    collisions: dict[str, tuple[Collision, ...]] = {}
    # the robot's own elements only: a <transmission> names its joints in <joint> elements too
    for link in root.findall("link"):
        items = []
        for col in link.findall("collision"):
            rot, trans = _origin(col.find("origin"))
            geom = col.find("geometry")
            shape = geom[0] if geom is not None and len(geom) else None
            if shape is None:
                continue
            if shape.tag == "mesh":
                scale = tuple(float(v) for v in shape.get("scale", "1 1 1").split())
                items.append(Collision("mesh", scale, rot, trans, _mesh_path(shape.get("filename"), path),
                                       concave=col.get("concave", "no").lower() in ("yes", "true", "1")))
            elif shape.tag == "box":
                items.append(Collision("box", tuple(float(v) for v in shape.get("size").split()), rot, trans))
            elif shape.tag == "cylinder":
                items.append(Collision("cylinder", (float(shape.get("radius")), float(shape.get("length"))),
                                       rot, trans))
            elif shape.tag == "sphere":
                items.append(Collision("sphere", (float(shape.get("radius")),), rot, trans))
            else:
                raise ValueError(f"{path.name}: link {link.get('name')!r} has an unsupported collision "
                                 f"geometry <{shape.tag}>")
        collisions[link.get("name")] = tuple(items)
    joints: dict[str, Joint] = {}
    for j in root.findall("joint"):
        kind = j.get("type")
        if kind not in _JOINT_KINDS:
            raise ValueError(f"{path.name}: joint {j.get('name')!r} has unsupported type {kind!r}")
        rot, trans = _origin(j.find("origin"))
        axis_el = j.find("axis")
        axis = np.array([float(v) for v in (axis_el.get("xyz") if axis_el is not None else "1 0 0").split()])
        limit = j.find("limit")
        lower = float(limit.get("lower", 0.0)) if limit is not None else 0.0
        upper = float(limit.get("upper", 0.0)) if limit is not None else 0.0
        child = j.find("child").get("link")
        norm = float(np.linalg.norm(axis))
        if norm == 0.0 and _JOINT_KINDS[kind] != FIXED:
            raise ValueError(f"{path.name}: joint {j.get('name')!r} has a zero axis")
        joints[child] = Joint(j.get("name"), _JOINT_KINDS[kind], j.find("parent").get("link"), child, rot, trans,
                              axis / norm if norm else np.array([1.0, 0.0, 0.0]), lower, upper)
    roots = [name for name in collisions if name not in joints]
    if len(roots) != 1:
        raise ValueError(f"{path.name}: expected one root link, found {roots}")
    order, frontier = [], [roots[0]]
    children: dict[str, list[str]] = {}
    for j in joints.values():
        children.setdefault(j.parent, []).append(j.child)
    while frontier:
        link = frontier.pop(0)
        order.append(link)
        frontier.extend(children.get(link, []))
    return URDFRobot(root.get("name", path.stem), tuple(order), joints, collisions)


def _read_obj(path: Path) -> list[np.ndarray]:
    """Vertices of each object (``o``) or group (``g``) of an OBJ file: those listed in its block
    and those its faces use (OBJ indices are global); vertices before the first such line form
    their own part. Parts without vertices are dropped."""
    vertices: list[list[float]] = []
    blocks: list[tuple[list[int], set[int]]] = [([], set())]     # (listed vertex ids, face vertex ids)
    for line in path.read_text(errors="replace").splitlines():
        if line.startswith(("o ", "g ")) and (blocks[-1][0] or blocks[-1][1]):
            blocks.append(([], set()))
        elif line.startswith("v "):
            blocks[-1][0].append(len(vertices))
            vertices.append([float(v) for v in line.split()[1:4]])
        elif line.startswith("f "):
            for item in line.split()[1:]:
                k = int(item.split("/")[0])
                blocks[-1][1].add(k - 1 if k > 0 else len(vertices) + k)
    points = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    return [points[sorted(set(listed) | used)] for listed, used in blocks if listed or used]


def _read_stl(path: Path) -> np.ndarray:
    """Vertices of an STL file (binary or ASCII), three per triangle."""
    data = path.read_bytes()
    if len(data) >= 84:
        count = struct.unpack("<I", data[80:84])[0]
        if 84 + 50 * count == len(data):
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=count, offset=84)
            return rec["v"].reshape(-1, 3).astype(np.float64)
    verts = [[float(v) for v in line.split()[1:4]] for line in data.decode(errors="replace").splitlines()
             if line.strip().startswith("vertex")]
    return np.array(verts, dtype=np.float64)


def mesh_triangles(collision: Collision) -> np.ndarray:
    """The triangles ``(k, 3, 3)`` of an STL collision mesh, in the link frame (for concave meshes)."""
    if collision.kind != "mesh" or collision.mesh.suffix.lower() != ".stl":
        raise ValueError("only STL meshes give their triangles here")
    tri = _read_stl(collision.mesh).reshape(-1, 3) * np.asarray(collision.size, dtype=np.float64)
    return (tri @ collision.rotation.T + collision.translation).reshape(-1, 3, 3)


def mesh_parts(collision: Collision) -> list[np.ndarray]:
    """The point sets, in the link frame, whose convex hulls pybullet collides for one collision
    element (a mesh: one per OBJ object or group, one for an STL; a box: its 8 corners). Cylinders
    and spheres are exact shapes: ValueError."""
    if collision.kind == "mesh":
        suffix = collision.mesh.suffix.lower()
        if suffix == ".obj":
            parts = _read_obj(collision.mesh)
        elif suffix == ".stl":
            parts = [_read_stl(collision.mesh)]
        else:
            raise ValueError(f"unsupported collision mesh {collision.mesh.name} (OBJ or STL)")
        scale = np.asarray(collision.size, dtype=np.float64)
        local = [p * scale for p in parts]
    elif collision.kind == "box":
        half = np.asarray(collision.size) / 2
        local = [np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half]
    else:
        raise ValueError(f"a {collision.kind} is not a point set")
    return [p @ collision.rotation.T + collision.translation for p in local]
