"""Clearance of the arm task's starts and goals (the xArm6), what its sphere model's padding and
overshoot must stay under so that the problems stay valid for the spheres. Per problem, at the start
and at the goal:

* per link, the pybullet distance (hulls less pybullet's 1 mm margin) to the obstacles and the table
  (the base links, which stand on it, exempt): what the problem generator held above the robot's
  padding;
* per link, the same distance to the obstacles as they are ("sharp"): pybullet rounds the edges and
  corners of its boxes and cylinders by its margin (a point 1 mm from an edge in pybullet is 0.59 mm
  from the box, 0.27 mm from a corner), the sphere checker tests the shapes as they are. Measured
  in pybullet with each obstacle as a convex mesh (a box's 8 corners, a cylinder as a 256-sided prism
  around it), whose own 1 mm margin is added back;
* per self-checked link pair, the pybullet distance.

Run from the repository root::

    python -m tools.arm_clearance --problems 1000 --out /tmp/arm_clearance.npz

A link whose spheres reach ``padding + overshoot`` beyond pybullet's margin makes a start or goal
invalid where its sharp clearance is below that; a self pair where the pair's clearance is below
``2 * padding`` plus the two self overshoots. Splits (default): ``train`` (scene ``train``), ``val``
(the validation scene ``pillars``), ``test`` (the held-out ``test`` family, the benchmark's).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

#: (split, scene) pairs measured by default: what training, validation and the benchmark plan.
SPLITS = (("train", "train"), ("val", "pillars"), ("test", "test"))
#: Clearances beyond this (m) are not resolved (reported as this).
FAR = 0.02
#: pybullet's margin of a convex mesh (m), added back to its distance to a mesh obstacle.
MESH_MARGIN = 0.001


def link_names(world) -> dict[int, str]:
    p, cid, r = world.p, world.client, world.robot
    names = {-1: p.getBodyInfo(r, physicsClientId=cid)[0].decode()}
    names.update({j: p.getJointInfo(r, j, physicsClientId=cid)[12].decode()
                  for j in range(p.getNumJoints(r, physicsClientId=cid))})
    return names


def checked_pairs(world) -> list[tuple[int, int]]:
    """The self pairs pybullet checks: links with collision geometry, not parent and child, not allowed."""
    p, cid, r = world.p, world.client, world.robot
    names = link_names(world)
    links = [j for j in names if p.getCollisionShapeData(r, j, physicsClientId=cid)]
    parent = {j: p.getJointInfo(r, j, physicsClientId=cid)[16] for j in links if j >= 0}
    allowed = {frozenset(pair) for pair in world.robot_model.allowed_collisions}
    return [(a, b) for k, a in enumerate(links) for b in links[k + 1:]
            if parent.get(b) != a and parent.get(a) != b and frozenset((names[a], names[b])) not in allowed]


def sharp_body(world, ob) -> int:
    """Obstacle ``ob`` as a convex mesh body (sharp edges; pybullet grows it by its margin)."""
    p, cid = world.p, world.client
    if ob.kind == "box":
        v = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * np.array(ob.size)
    elif ob.kind == "cylinder":
        radius, half = ob.size[0], ob.size[1] / 2
        a = np.arange(256) * 2 * np.pi / 256
        ring = np.c_[np.cos(a), np.sin(a)] * radius / np.cos(np.pi / 256)
        v = np.concatenate([np.c_[ring, np.full(256, z)] for z in (-half, half)])
    else:
        raise ValueError(f"no sharp form of a {ob.kind}")
    shape = p.createCollisionShape(p.GEOM_MESH, vertices=v.tolist(), physicsClientId=cid)
    return p.createMultiBody(0, shape, basePosition=list(ob.position), baseOrientation=list(ob.quaternion()),
                             physicsClientId=cid)


def clearances(world, q, pairs, sharp: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At ``q``: per link (in link order -1..n-1), the least pybullet distance to the obstacles and the
    table (the table skipped for the base links) and the least to the ``sharp`` bodies (and the table,
    whose top face pybullet does not round); per pair, the least distance between the two links."""
    p, cid, r = world.p, world.client, world.robot
    world.set_config(q)
    p.performCollisionDetection(physicsClientId=cid)
    n = p.getNumJoints(r, physicsClientId=cid)
    rounded, exact = np.full(n + 1, FAR), np.full(n + 1, FAR)
    for body, out, extra in [(b, rounded, 0.0) for b in world.obstacle_bodies + [world.table]] + \
                            [(b, exact, MESH_MARGIN) for b in sharp] + [(world.table, exact, 0.0)]:
        for cp in p.getClosestPoints(r, body, FAR, physicsClientId=cid):
            if body == world.table and cp[3] in world.robot_model.base_links:
                continue
            out[cp[3] + 1] = min(out[cp[3] + 1], cp[8] + extra)
    per_pair = np.full(len(pairs), FAR)
    for k, (a, b) in enumerate(pairs):
        for cp in p.getClosestPoints(r, r, FAR, linkIndexA=a, linkIndexB=b, physicsClientId=cid):
            per_pair[k] = min(per_pair[k], cp[8])
    return rounded, exact, per_pair


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", type=int, default=300, help="problems per split")
    ap.add_argument("--out", type=Path, default=Path("arm_clearance.npz"))
    ap.add_argument("--splits", nargs="+", default=[f"{split}:{scene}" for split, scene in SPLITS],
                    help="split:scene pairs (default: %(default)s; the OOD suite's: test:tall-clutter test:shelves "
                         "test:bins)")
    args = ap.parse_args(argv)
    from gnn_mp_envs.tasks.arm.task import ArmTask
    out = {}
    for split, scene in (item.split(":") for item in args.splits):
        task = ArmTask(scene)
        world = task.world
        names = link_names(world)
        pairs = checked_pairs(world)
        rows = []
        start = time.time()
        for i in range(args.problems):
            problem = task.problem(split, i)
            world.load(problem.scene)            # first: it may start a new client (dropping other bodies)
            sharp = [sharp_body(world, ob) for ob in problem.obstacles]
            rows.append([clearances(world, q, pairs, sharp) for q in (problem.start, problem.goal)])
            for body in sharp:
                world.p.removeBody(body, physicsClientId=world.client)
        # (problems, 2 [start, goal], links / pairs)
        rounded, exact, selfs = (np.array([[r[k] for r in row] for row in rows]) for k in range(3))
        key = f"{split}:{scene}"
        out[f"{key}:pybullet"], out[f"{key}:sharp"], out[f"{key}:pairs"] = rounded, exact, selfs
        print(f"{key} ({args.problems} problems, {time.time() - start:.0f} s): least clearance per link to the "
              f"obstacles and the table (mm), pybullet's / sharp, start / goal:")
        for j in range(rounded.shape[2]):
            if (exact[:, :, j] < FAR).any():
                print(f"  {names[j - 1]:>12}: {rounded[:, 0, j].min() * 1e3:6.2f} / {exact[:, 0, j].min() * 1e3:6.2f}"
                      f"   {rounded[:, 1, j].min() * 1e3:6.2f} / {exact[:, 1, j].min() * 1e3:6.2f}")
        least = exact.min(axis=(1, 2))
        print("  problems with a start or goal closer (sharp) than 0.4 / 0.5 / 0.6 / 0.7 / 0.8 / 0.9 / 1.0 mm: "
              + " / ".join(str(int((least <= t * 1e-3).sum())) for t in (0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)))
        print("  self pairs within reach (mm), start / goal:")
        for k, (a, b) in enumerate(pairs):
            if (selfs[:, :, k] < FAR).any():
                print(f"  {names[a]:>12}-{names[b]:<12}: {selfs[:, 0, k].min() * 1e3:6.2f} / "
                      f"{selfs[:, 1, k].min() * 1e3:6.2f}")
        task.close()
    out["link_names"] = np.array([names[j] for j in sorted(names)])
    out["pairs"] = np.array([(names[a], names[b]) for a, b in pairs])
    np.savez(args.out, **out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
