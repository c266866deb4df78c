"""The sphere model of a robot and its file format (``models/<robot>/<robot>.npz``, numpy arrays, no
pickle): per link, two trees of spheres in the link's frame whose leaves cover the link's collision
geometry (:mod:`gnn_mp_envs.robots.spheres.build` makes them).

Arrays: ``nodes`` ``(n, 4)`` float64, centre and radius of every tree node; ``first_child`` and
``child_count`` ``(n,)`` integers, each node's children (consecutive rows, after it; 0 children: a
leaf); ``root_names`` (link names), ``root_rows`` and ``self_root_rows`` (each link's two roots);
``meta``, a JSON string with ``format`` (:data:`MODEL_FORMAT`), the margin, each link's overshoot,
the sha256 of every mesh file it was made from and the command that made it.
:func:`load_sphere_model` refuses a file that breaks any of this, in one line naming the file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from gnn_mp_envs.utils.npz import DAMAGED

#: Format tag of the sphere model files.
MODEL_FORMAT = "gnn-mp-envs sphere model, version 1"
#: The arrays of a model file.
ARRAYS = ("nodes", "first_child", "child_count", "root_names", "root_rows", "self_root_rows", "meta")


class SphereModelError(ValueError):
    """A sphere model file that cannot be used; the message is one line naming the file."""


def leaf_rows(root: int, first_child: np.ndarray, child_count: np.ndarray) -> np.ndarray:
    """The rows of the leaves of the sphere tree at ``root``, in increasing order, found one level of the
    tree at a time with numpy (a link's tree can hold tens of thousands of leaves)."""
    found, level = [], np.array([int(root)], dtype=np.int64)
    while len(level):
        counts = child_count[level]
        found.append(level[counts == 0])
        inner, kids = level[counts > 0], counts[counts > 0].astype(np.int64)
        # the children of each inner node are the consecutive rows from its first child
        level = (np.repeat(first_child[inner].astype(np.int64), kids) + np.arange(kids.sum())
                 - np.repeat(np.cumsum(kids) - kids, kids))
    return np.sort(np.concatenate(found))


@dataclass(frozen=True)
class SphereModel:
    """Per-link sphere trees of one robot, in link frames: two per link, one tested against
    obstacles (``roots``: the tightest, where the dataset's starts and goals come closest to
    obstacles) and one against the robot's other links (``self_roots``: looser, so fewer leaves;
    self-clearances are larger).

    ``nodes``: ``(n, 4)`` centre and radius of every tree node; ``first_child`` / ``child_count``:
    each node's children (consecutive rows; 0 children: a leaf, a fine sphere); ``roots`` /
    ``self_roots``: link name -> its tree's root row. ``meta``: margin, overshoot per link, source
    files, the command that made it."""

    nodes: np.ndarray
    first_child: np.ndarray
    child_count: np.ndarray
    roots: dict[str, int]
    self_roots: dict[str, int]
    meta: dict[str, Any]

    @property
    def margin(self) -> float:
        """How far beyond each link's convex hulls the leaves reach at least (m)."""
        return float(self.meta["margin"])

    def leaves(self, link: str, self_collision: bool = False) -> np.ndarray:
        """The fine spheres ``(k, 4)`` of ``link``: the leaves of its obstacle tree (or of its
        self-collision tree)."""
        root = (self.self_roots if self_collision else self.roots)[link]
        return self.nodes[leaf_rows(root, self.first_child, self.child_count)]

    def save(self, path: str | Path) -> None:
        names = sorted(self.roots, key=self.roots.get)
        np.savez_compressed(path, nodes=self.nodes, first_child=self.first_child, child_count=self.child_count,
                            root_names=np.array(names), root_rows=np.array([self.roots[n] for n in names]),
                            self_root_rows=np.array([self.self_roots[n] for n in names]),
                            meta=np.array(json.dumps({"format": MODEL_FORMAT, **self.meta}, sort_keys=True)))


def _check(path: Path, data: dict[str, np.ndarray]) -> str | None:
    """What is wrong with a model file's arrays (None: nothing): types, shapes, finite positive radii,
    children within the rows after their parent, one root of each kind per link, inside the rows."""
    nodes, first, count = data["nodes"], data["first_child"], data["child_count"]
    if nodes.dtype.kind != "f" or nodes.ndim != 2 or nodes.shape[1] != 4 or not len(nodes):
        return f"'nodes' must be a non-empty (n, 4) float array, got {nodes.dtype} {nodes.shape}"
    n = len(nodes)
    for name, arr in (("first_child", first), ("child_count", count), ("root_rows", data["root_rows"]),
                      ("self_root_rows", data["self_root_rows"])):
        if arr.dtype.kind not in "iu" or arr.ndim != 1:
            return f"{name!r} must be a 1-D integer array, got {arr.dtype} {arr.shape}"
    if first.shape != (n,) or count.shape != (n,):
        return f"'first_child' and 'child_count' must have one entry per node ({n}), got {first.shape}, {count.shape}"
    if not np.all(np.isfinite(nodes)):
        return "'nodes' holds non-finite values"
    if not np.all(nodes[:, 3] > 0):
        return "every sphere's radius must be > 0"
    inner = count > 0
    rows = np.arange(n)
    if np.any(count < 0) or np.any(first[inner] <= rows[inner]) or np.any(first[inner] + count[inner] > n):
        return "a node's children must be rows after it, inside the file"
    names = data["root_names"]
    if names.dtype.kind != "U" or names.ndim != 1 or len(set(names.tolist())) != len(names):
        return "'root_names' must be distinct link names"
    for name in ("root_rows", "self_root_rows"):
        if data[name].shape != names.shape or np.any(data[name] < 0) or np.any(data[name] >= n):
            return f"{name!r} must hold one row per link, inside the file"
    return None


@lru_cache(maxsize=8)
def load_sphere_model(path: str | Path) -> SphereModel:
    """A sphere model file (``.npz``, read without pickle); :class:`SphereModelError` for one that is
    damaged, of another format or inconsistent, ``FileNotFoundError`` for a missing one."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"sphere model {path} is missing: reinstall gnn-mp-envs or regenerate it with "
                                "`python -m tools.spherize`")
    try:
        with np.load(path, allow_pickle=False) as npz:
            missing = [name for name in ARRAYS if name not in npz.files]
            if missing:
                raise SphereModelError(f"{path}: not a sphere model (no {', '.join(missing)})")
            data = {name: npz[name] for name in ARRAYS}
        meta = json.loads(str(data["meta"]))
    except SphereModelError:
        raise
    except DAMAGED + (json.JSONDecodeError,) as exc:
        lines = str(exc).strip().splitlines()
        detail = f"{type(exc).__name__}: {lines[0][:100]}" if lines else type(exc).__name__
        raise SphereModelError(f"{path}: unreadable sphere model ({detail})") from None
    if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise SphereModelError(f"{path}: not a sphere model of this version ({found!r})")
    if not isinstance(meta.get("margin"), (int, float)) or not meta["margin"] > 0:
        raise SphereModelError(f"{path}: meta 'margin' must be a number > 0")
    problem = _check(path, data)
    if problem:
        raise SphereModelError(f"{path}: {problem}")
    names = [str(n) for n in data["root_names"]]
    return SphereModel(data["nodes"].astype(np.float64), data["first_child"].astype(np.int64),
                       data["child_count"].astype(np.int64),
                       {n: int(r) for n, r in zip(names, data["root_rows"])},
                       {n: int(r) for n, r in zip(names, data["self_root_rows"])}, meta)
