"""Convert MotionBenchMaker's Panda problems (as VAMP ships them) into the package's compact JSON.

Run once, from the repository root, with a clone (or bare mirror) of https://github.com/KavrakiLab/vamp::

    python -m tools.mbm_convert --vamp /path/to/vamp/.git

It reads, at the pinned commit :data:`VAMP_COMMIT` (``git show``, so a bare mirror works):

* ``resources/panda/problems.tar.bz2``: per scene ``sceneNNNN.yaml`` (a MoveIt planning scene:
  collision objects, each one primitive with a pose, and the allowed-collision matrix) and
  ``requestNNNN.yaml`` (a MoveIt motion-plan request: start joint state, goal joint constraints);
* ``resources/panda/panda.urdf``: the joint limits of the Panda MotionBenchMaker plans for.

and writes ``gnn_mp_envs/tasks/mbm/dataset/panda_problems.json`` (see that directory's README for the
layout). The output depends only on the input bytes: running it again gives the same file byte for
byte (``--check`` compares instead of writing). Needs PyYAML (installed with the ``ray`` extra).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import re
import subprocess
import sys
import tarfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

VAMP_REPOSITORY = "https://github.com/KavrakiLab/vamp"
VAMP_COMMIT = "f6de6a72e0725ba08e0829f0a34261a3f465aed7"
PROBLEMS_PATH = "resources/panda/problems.tar.bz2"
URDF_PATH = "resources/panda/panda.urdf"
OUTPUT = Path(__file__).resolve().parents[1] / "gnn_mp_envs" / "tasks" / "mbm" / "dataset" / "panda_problems.json"
#: The seven Panda scenes, in MotionBenchMaker's order (the tarball's folders are ``<scene>_panda``).
SCENES = ("table_pick", "table_under_pick", "box", "bookshelf_small", "bookshelf_tall", "bookshelf_thin", "cage")
ARM_JOINTS = tuple(f"panda_joint{k}" for k in range(1, 8))
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
PRIMITIVES = ("box", "cylinder", "sphere")
FORMAT = "gnn-mp-envs MotionBenchMaker problems, version 1"


def git_show(git_dir: Path, path: str, commit: str = VAMP_COMMIT) -> bytes:
    """The bytes of ``path`` at ``commit`` in the repository ``git_dir`` (a .git directory or a bare mirror)."""
    try:
        return subprocess.run(["git", f"--git-dir={git_dir}", "show", f"{commit}:{path}"], check=True,
                              capture_output=True).stdout
    except subprocess.CalledProcessError as exc:
        raise SystemExit(f"cannot read {path} at {commit[:12]} from {git_dir}: "
                         f"{exc.stderr.decode().strip().splitlines()[-1]}") from None


def urdf_limits(urdf: bytes) -> dict[str, tuple[float, float]]:
    """Joint name -> (lower, upper) of the URDF's revolute joints."""
    limits = {}
    for joint in ET.fromstring(urdf).iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") == "revolute" and limit is not None:
            limits[joint.get("name")] = (float(limit.get("lower")), float(limit.get("upper")))
    return limits


def read_yaml(data: bytes) -> Any:
    import yaml
    return yaml.load(data, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def scene_objects(scene: dict) -> list[tuple[str, str, list[float], list[float]]]:
    """(id, primitive type, MoveIt dimensions, pose [x, y, z, qx, qy, qz, qw]) of each collision object.

    Every object of these files is one primitive with one pose and no object-level pose; anything
    else is refused rather than converted approximately."""
    out = []
    for co in scene["world"]["collision_objects"]:
        if len(co["primitives"]) != 1 or len(co["primitive_poses"]) != 1 or "pose" in co:
            raise SystemExit(f"object {co['id']!r}: expected one primitive with one pose and no object pose")
        kind = co["primitives"][0]["type"]
        if kind not in PRIMITIVES:
            raise SystemExit(f"object {co['id']!r}: unknown primitive {kind!r}")
        pose = co["primitive_poses"][0]
        out.append((co["id"], kind, [float(v) for v in co["primitives"][0]["dimensions"]],
                    [float(v) for v in pose["position"]] + [float(v) for v in pose["orientation"]]))
    return out


def allowed_pairs(scene: dict) -> list[list[str]]:
    """The link pairs the scene's allowed-collision matrix allows to touch (sorted; symmetric matrix)."""
    acm = scene["allowed_collision_matrix"]
    names, values = acm["entry_names"], acm["entry_values"]
    pairs = set()
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            if values[i][j] != values[j][i]:
                raise SystemExit(f"asymmetric allowed-collision matrix entry {a} / {b}")
            if i < j and values[i][j]:
                pairs.add(tuple(sorted((a, b))))
    return [list(p) for p in sorted(pairs)]


def joint_values(names: list[str], positions: list[float], wanted: tuple[str, ...]) -> list[float]:
    return [float(positions[names.index(j)]) for j in wanted]


def convert(tarball: bytes, urdf: bytes) -> dict[str, Any]:
    """The JSON document of the problems in ``tarball`` with the joint limits of ``urdf``."""
    files: dict[tuple[str, str, int], dict] = {}
    with tarfile.open(fileobj=io.BytesIO(tarball), mode="r:bz2") as tar:
        for member in tar.getmembers():
            if not member.isfile():
                continue
            match = re.fullmatch(r"problems/(\w+)_panda/(scene|request)(\d{4})\.yaml", member.name)
            if match is None:
                raise SystemExit(f"unexpected file {member.name!r} in the tarball")
            folder, kind, number = match.groups()
            files[folder, kind, int(number)] = read_yaml(tar.extractfile(member).read())
    if sorted({f for f, _, _ in files}) != sorted(SCENES):
        raise SystemExit(f"expected the scenes {SCENES}, found {sorted({f for f, _, _ in files})}")

    acm, fingers = None, None
    scenes: dict[str, Any] = {}
    for name in SCENES:
        numbers = sorted(n for f, k, n in files if f == name and k == "scene")
        if numbers != sorted(n for f, k, n in files if f == name and k == "request"):
            raise SystemExit(f"{name}: scene and request files do not pair up")
        layout, problems = None, []
        for number in numbers:
            scene, request = files[name, "scene", number], files[name, "request", number]
            objects = scene_objects(scene)
            this_layout = [[oid, kind, dims] for oid, kind, dims, _ in objects]
            if layout is None:
                layout = this_layout
            elif this_layout != layout:   # same objects, kinds and sizes in every problem of a scene
                raise SystemExit(f"{name} problem {number}: objects differ from the scene's first problem")
            pairs = allowed_pairs(scene)
            if acm is None:
                acm = pairs
            elif pairs != acm:
                raise SystemExit(f"{name} problem {number}: a different allowed-collision matrix")
            js = request["start_state"]["joint_state"]
            finger = joint_values(js["name"], js["position"], FINGER_JOINTS)
            if fingers is None:
                fingers = finger
            elif finger != fingers:
                raise SystemExit(f"{name} problem {number}: fingers at {finger}, elsewhere {fingers}")
            goals = request["goal_constraints"]
            if len(goals) != 1:
                raise SystemExit(f"{name} problem {number}: {len(goals)} goal constraints, expected 1")
            goal = {c["joint_name"]: float(c["position"]) for c in goals[0]["joint_constraints"]}
            problems.append({"file": number,
                             "start": joint_values(js["name"], js["position"], ARM_JOINTS),
                             "goal": [goal[j] for j in ARM_JOINTS],
                             "poses": [pose for *_, pose in objects]})
        scenes[name] = {"objects": layout, "problems": problems}

    limits = urdf_limits(urdf)
    return {
        "format": FORMAT,
        "source": {"repository": VAMP_REPOSITORY, "commit": VAMP_COMMIT,
                   "sha256": {PROBLEMS_PATH: hashlib.sha256(tarball).hexdigest(),
                              URDF_PATH: hashlib.sha256(urdf).hexdigest()},
                   "regenerate": "python -m tools.mbm_convert --vamp PATH_TO_VAMP_GIT_DIR"},
        "robot": {"name": "panda", "joints": list(ARM_JOINTS),
                  "lower": [limits[j][0] for j in ARM_JOINTS], "upper": [limits[j][1] for j in ARM_JOINTS],
                  "held_joints": dict(zip(FINGER_JOINTS, fingers)),
                  "allowed_collisions": acm},
        "units": {"objects": "[id, primitive, MoveIt dimensions: box [x, y, z] full lengths (m), "
                             "cylinder [height, radius], sphere [radius]]",
                  "poses": "one per object, in the objects' order: [x, y, z, qx, qy, qz, qw] in the robot "
                           "base frame (m)",
                  "start, goal": "panda_joint1..7 (rad)"},
        "scenes": scenes,
    }


def dumps(doc: dict[str, Any]) -> str:
    """Deterministic JSON: one line per header entry, per scene layout and per problem
    (floats as Python's shortest round-trip repr, so every value is the YAML's exactly)."""
    compact = {"separators": (",", ":")}
    head = {k: v for k, v in doc.items() if k != "scenes"}
    lines = ["{"] + [f" {json.dumps(k)}: {json.dumps(v, **compact)}," for k, v in head.items()] + [' "scenes": {']
    for s, (name, scene) in enumerate(doc["scenes"].items()):
        lines.append(f"  {json.dumps(name)}: {{")
        lines.append(f'   "objects": {json.dumps(scene["objects"], **compact)},')
        lines.append('   "problems": [')
        rows = [f"    {json.dumps(p, **compact)}" for p in scene["problems"]]
        lines.append(",\n".join(rows))
        lines.append("   ]")
        lines.append("  }" + ("," if s < len(doc["scenes"]) - 1 else ""))
    lines += [" }", "}", ""]
    text = "\n".join(lines)
    if json.loads(text) != doc:   # the hand-made layout must be the document
        raise AssertionError("layout changed the document")
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vamp", type=Path, required=True, help="VAMP's git directory (a clone's .git or a bare mirror)")
    ap.add_argument("--out", type=Path, default=OUTPUT, help="output file (default: the package's)")
    ap.add_argument("--check", action="store_true", help="compare with --out instead of writing it (exit 1 if it differs)")
    args = ap.parse_args(argv)
    text = dumps(convert(git_show(args.vamp, PROBLEMS_PATH), git_show(args.vamp, URDF_PATH)))
    if args.check:
        same = args.out.exists() and args.out.read_text() == text
        print(f"{args.out}: {'identical' if same else 'DIFFERS'}")
        return 0 if same else 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    count = sum(len(s["problems"]) for s in json.loads(text)["scenes"].values())
    print(f"wrote {args.out} ({len(text.encode()) / 1e6:.2f} MB, {count} problems)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
