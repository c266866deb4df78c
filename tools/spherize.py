"""Make the shipped sphere models: spheres that cover each link's collision geometry (the convex
hulls pybullet collides, grown by its collision margin and the robot's padding), grouped into a
tree per link. Run from the repository root::

    python -m tools.spherize --robot panda            # writes gnn_mp_envs/robots/models/panda/panda.npz
    python -m tools.spherize --robot panda --check    # coverage and overshoot of the shipped file

Method and guarantees: :mod:`gnn_mp_envs.robots.spheres.build`. The margin is pybullet's collision
margin plus the robot model's padding, so a configuration the pybullet checker calls a collision
(with or without the padding) is one for the spheres too; the overshoot (how much farther the
spheres may reach) is chosen per link below, from the clearance of the dataset's starts and goals
(``--clearance`` prints it): below it, so that every start and goal stays valid.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from gnn_mp_envs.robots.catalog import robot_model
from gnn_mp_envs.robots.model import sphere_model_path, urdf_file
from gnn_mp_envs.robots.spheres.build import BULLET_MARGIN, build_tree, coverage_gaps, max_overshoot, spherize_link
from gnn_mp_envs.robots.spheres.model import SphereModel, load_sphere_model
from gnn_mp_envs.robots.urdf import read_urdf

#: Robot (a name of :data:`gnn_mp_envs.robots.catalog.ROBOTS`) -> how its model is made: ``overshoot`` (m)
#: per link, ``"*"`` for the others. The tightest links are the ones whose
#: start/goal clearance is smallest (``--clearance``).
SETTINGS: dict[str, dict[str, Any]] = {
    "panda": {"overshoot": {"*": 0.005, "panda_link5": 0.0007, "panda_hand": 0.0012, "panda_link6": 0.002,
                            "panda_leftfinger": 0.002, "panda_rightfinger": 0.002},
              "self_overshoot": {"*": 0.006}},
    # The UR5's and the Fetch's starts and goals come within 1.1 mm (pybullet distance) of obstacles
    # and of their own links: a quarter millimetre of padding, half a millimetre of overshoot on the
    # links that come that close, 0.3 mm on the self pairs that do.
    "ur5": {"padding": 0.00025,
            "overshoot": {"*": 0.002, "robotiq_85_left_finger_tip_link": 0.0005,
                          "robotiq_85_right_finger_tip_link": 0.0005, "robotiq_85_left_finger_link": 0.001,
                          "robotiq_85_right_finger_link": 0.001},
            "self_overshoot": {"*": 0.004, "forearm_link": 0.0003, "wrist_2_link": 0.0003, "wrist_3_link": 0.0003,
                               "fts_robotside": 0.001}},
    "fetch": {"padding": 0.00025,
              "overshoot": {"*": 0.002, "forearm_roll_link": 0.0005, "wrist_flex_link": 0.0005,
                            "r_gripper_finger_link": 0.0005, "l_gripper_finger_link": 0.0005,
                            "upperarm_roll_link": 0.0005, "gripper_link": 0.0005},
              "self_overshoot": {"*": 0.003, "base_link": 0.001, "wrist_flex_link": 0.0003,
                                 "upperarm_roll_link": 0.0003, "forearm_roll_link": 0.0005,
                                 "shoulder_lift_link": 0.0005}},
    # The xArm6 of the arm task (pybullet_data's V-HACD meshes: 21 convex parts over 7 links) stands on the
    # table (its base link is exempt from the table). Its problem generator accepts a start or goal when pybullet
    # puts every link more than the robot's 1 mm padding from the obstacles; but pybullet rounds the boxes' and
    # cylinders' edges by its 1 mm margin (a link 1 mm from an edge in pybullet is 0.59 mm from the box, 0.27 mm
    # from a corner) and the spheres test the shapes as they are: on the sharp shapes, 3,000 starts and goals
    # (train, val, test; python -m tools.arm_clearance) come within 0.39 mm (one train goal), 0.63 to 0.9 mm
    # (link2 to link5, 30 problems) and 2.05 mm (link6). A quarter millimetre of padding and 0.4 mm of overshoot
    # on link2 to link5 (0.65 mm in all) keep every val and test start and goal valid, 1 mm on link6; link_base
    # and link1 never came within 10 mm of an obstacle (2 mm), nor any self pair within 13.8 mm (3 mm). Eight
    # polishing samples close the self trees' last dips under the cover's tolerance.
    "xarm6": {"padding": 0.00025, "overshoot": {"*": 0.0004, "link_base": 0.002, "link1": 0.002, "link6": 0.001},
              "self_overshoot": {"*": 0.003}, "polish_seeds": 8},
}
#: Boundary sample spacing of the cover (m).
SPACING = 0.001


def overshoot_of(robot: str, link: str, key: str = "overshoot") -> float:
    table = SETTINGS[robot][key]
    return float(table.get(link, table["*"]))


def make(robot: str, out: Path, seed: int = 0) -> SphereModel:
    model = robot_model(robot)
    urdf = urdf_file(model.urdf)
    r = read_urdf(str(urdf))
    # the model's padding: the robot model's (the pybullet checker's) unless the settings name a smaller one
    padding = float(SETTINGS[robot].get("padding", model.padding))
    margin = BULLET_MARGIN + padding
    nodes, first, count, roots, self_roots, meshes, per_link = [], [], [], {}, {}, {}, {}
    offset = 0

    def add(leaves: np.ndarray) -> int:
        nonlocal offset
        n, f, c = build_tree(leaves, seed=seed)
        nodes.append(n)
        first.append(np.where(c > 0, f + offset, 0))
        count.append(c)
        offset += len(n)
        return offset - len(n)

    for link in r.links:
        if not r.collisions.get(link):
            continue
        start = time.time()
        leaves = spherize_link(r, link, margin, overshoot_of(robot, link), SPACING, seed=seed)
        self_overshoot = overshoot_of(robot, link, "self_overshoot")
        self_leaves = spherize_link(r, link, margin, self_overshoot, 2 * SPACING, seed=seed)
        roots[link] = add(leaves)
        self_roots[link] = add(self_leaves)
        per_link[link] = {"leaves": int(len(leaves)), "overshoot": overshoot_of(robot, link),
                          "self_leaves": int(len(self_leaves)), "self_overshoot": self_overshoot}
        for col in r.collisions[link]:
            if col.mesh is not None:
                meshes[col.mesh.name] = hashlib.sha256(col.mesh.read_bytes()).hexdigest()
        print(f"{link}: {len(leaves)} spheres against obstacles, {len(self_leaves)} against the robot "
              f"({time.time() - start:.0f} s)", flush=True)
    result = SphereModel(np.concatenate(nodes), np.concatenate(first), np.concatenate(count), roots, self_roots,
                         {"robot": robot, "urdf": urdf.name, "margin": margin, "bullet_margin": BULLET_MARGIN,
                          "padding": padding, "links": per_link, "spacing": SPACING, "seed": seed,
                          "mesh_sha256": meshes, "command": f"python -m tools.spherize --robot {robot}"})
    out.parent.mkdir(parents=True, exist_ok=True)
    result.save(out)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB, "
          f"{sum(v['leaves'] + v['self_leaves'] for v in per_link.values())} spheres)")
    return result


def polish(robot: str, path: Path, spacing: float = 0.001, seeds: int = 2,
           edge_spacings: tuple[float, ...] = (0.0015, 0.0012, 0.001, 0.0008, 0.0006, 0.0005)) -> None:
    """Close the cover's remaining dips: every leaf set is checked on fresh boundary samples grown
    by the margin less half the cover's tolerance (the faces at random, ``seeds`` samples ``spacing``
    apart; the strips over edges and the caps over vertices, where narrow dips hide, at each of
    ``edge_spacings``), a sphere added over each point still out (radius: the link's union depth there
    plus the margin and the overshoot, as every sphere), and the trees rebuilt."""
    from gnn_mp_envs.robots.spheres.build import (
        COVER_TOLERANCE,
        boundary_samples,
        inside_union,
        link_geometry,
        union_depth,
    )
    model = robot_model(robot)
    r = read_urdf(str(urdf_file(model.urdf)))
    spheres = load_sphere_model(path)
    margin = spheres.margin
    nodes, first, count, roots, self_roots = [], [], [], {}, {}
    offset = 0

    def add(leaves: np.ndarray) -> int:
        nonlocal offset
        n, f, c = build_tree(leaves, seed=int(spheres.meta.get("seed", 0)))
        nodes.append(n)
        first.append(np.where(c > 0, f + offset, 0))
        count.append(c)
        offset += len(n)
        return offset - len(n)

    for link in sorted(spheres.roots, key=spheres.roots.get):
        hulls, _ = link_geometry(r, link)
        for self_collision, key in ((False, "overshoot"), (True, "self_overshoot")):
            leaves = spheres.leaves(link, self_collision)
            overshoot = spheres.meta["links"][link][key]
            added = 0
            for hull in hulls:
                samples = [boundary_samples(hull, margin - COVER_TOLERANCE / 2, spacing, np.random.default_rng([7919, k]))
                           for k in range(seeds)]
                samples += [boundary_samples(hull, margin - COVER_TOLERANCE / 2, s, None, faces=False)
                            for s in edge_spacings]
                for pts, base, _ in samples:
                    out = ~inside_union(pts, leaves)
                    if out.any():
                        extra = np.unique(base[out], axis=0)
                        extra = np.c_[extra, np.maximum(union_depth(hulls, extra), 0.0) + margin + overshoot]
                        leaves = np.concatenate([leaves, extra])
                        added += len(extra)
            if added:
                print(f"{link} ({'self' if self_collision else 'obstacles'}): {added} spheres added", flush=True)
                spheres.meta["links"][link]["self_leaves" if self_collision else "leaves"] = int(len(leaves))
            (self_roots if self_collision else roots)[link] = add(leaves)
    SphereModel(np.concatenate(nodes), np.concatenate(first), np.concatenate(count), roots, self_roots,
                spheres.meta).save(path)
    load_sphere_model.cache_clear()


def check(robot: str, path: Path) -> int:
    """Coverage (hull vertices and a fresh boundary sample grown by the margin) and overshoot per link."""
    model = robot_model(robot)
    r = read_urdf(str(urdf_file(model.urdf)))
    spheres = load_sphere_model(path)
    bad = 0
    for link in spheres.roots:
        for self_collision in (False, True):
            leaves = spheres.leaves(link, self_collision)
            gaps = coverage_gaps(r, link, leaves, spheres.margin, SPACING)
            reach = max_overshoot(r, link, leaves, spheres.margin)
            bad += gaps["vertices"] + gaps["surface"]
            print(f"{link} ({'self' if self_collision else 'obstacles'}): {len(leaves)} spheres, {gaps['checked']} "
                  f"points checked, {gaps['vertices']} vertex and {gaps['surface']} surface points out; overshoot "
                  f"{reach * 1e3:.2f} mm")
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    from train.args import seed_int
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", choices=sorted(SETTINGS), required=True)
    ap.add_argument("--out", type=Path, default=None, help="output file (default: the package's)")
    ap.add_argument("--check", action="store_true", help="check the file's coverage instead of writing it")
    ap.add_argument("--polish", action="store_true", help="close remaining dips of the existing file (also the last "
                    "step of writing one)")
    ap.add_argument("--seed", type=seed_int, default=0)
    args = ap.parse_args(argv)
    out = args.out or sphere_model_path(args.robot)
    if args.check:
        return check(args.robot, out)
    if not args.polish:
        make(args.robot, out, args.seed)
    polish(args.robot, out, seeds=int(SETTINGS[args.robot].get("polish_seeds", 2)))
    return 0


if __name__ == "__main__":
    from tools import run_script
    sys.exit(run_script(main))
