"""Convert MotionBenchMaker's Panda, UR5 or Fetch problems (as VAMP ships them) into the package's
compact JSON, and write the UR5's and the Fetch's collision models.

Run once per robot, from the repository root, with a clone (or bare mirror) of
https://github.com/KavrakiLab/vamp::

    python -m tools.mbm_convert --vamp /path/to/vamp/.git                 # the Panda
    python -m tools.mbm_convert --vamp /path/to/vamp/.git --robot ur5     # or fetch
    python -m tools.mbm_convert --vamp /path/to/vamp/.git --robot ur5 --robot-files   # its URDF and meshes

It reads, at the pinned commit :data:`VAMP_COMMIT` (``git show``, so a bare mirror works), for
``ROBOT`` in ``panda``, ``ur5``, ``fetch``:

* ``resources/ROBOT/problems.tar.bz2``: per scene ``sceneNNNN.yaml`` (a MoveIt planning scene:
  collision objects, each one primitive with a pose, and the allowed-collision matrix) and
  ``requestNNNN.yaml`` (a MoveIt motion-plan request: start joint state, goal joint constraints);
* ``resources/ROBOT/ROBOT.urdf``: the joint limits of the robot MotionBenchMaker plans for.

and writes ``gnn_mp_envs/tasks/mbm/dataset/ROBOT_problems.json`` (see that directory's README for the
layout). With ``--robot-files`` (UR5, Fetch) it writes instead ``gnn_mp_envs/robots/models/ROBOT/``:
VAMP's ``ROBOT.urdf`` without its visual elements (see :func:`collision_urdf`) and, byte for byte,
the collision meshes that URDF references (see that folder's README). The output depends only on
the input bytes: running it again gives the same files byte for byte (``--check`` compares instead
of writing). Needs PyYAML (installed with the ``ray`` extra).
Anything the files hold beyond what the layout records (another group, goal tolerances, frames,
scenes whose objects or allowed-collision matrices differ, ...) is refused, not converted approximately.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

VAMP_REPOSITORY = "https://github.com/KavrakiLab/vamp"
VAMP_COMMIT = "f6de6a72e0725ba08e0829f0a34261a3f465aed7"
PROBLEMS_PATH = "resources/panda/problems.tar.bz2"
URDF_PATH = "resources/panda/panda.urdf"
DATASET = Path(__file__).resolve().parents[1] / "gnn_mp_envs" / "tasks" / "mbm" / "dataset"
OUTPUT = DATASET / "panda_problems.json"
#: Where ``--robot-files`` writes a robot's collision model (``<robot>/<robot>.urdf`` and its meshes).
ROBOT_FILES = DATASET.parents[2] / "robots" / "models"
#: The seven scenes, in MotionBenchMaker's order (the tarball's folders are ``<scene>_<robot>``); the
#: same seven for the Panda, the UR5 and the Fetch.
SCENES = ("table_pick", "table_under_pick", "box", "bookshelf_small", "bookshelf_tall", "bookshelf_thin", "cage")
ARM_JOINTS = tuple(f"panda_joint{k}" for k in range(1, 8))
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
PRIMITIVES = ("box", "cylinder", "sphere")
FORMAT = "gnn-mp-envs MotionBenchMaker problems, version 1"
IDENTITY = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


@dataclass(frozen=True)
class RobotSpec:
    """What the files of one robot must say: the scenes' ``robot_model_name``, the requests'
    ``group_name`` and its joints (the planned joints, in the order the dataset stores them: the
    SRDF group's), the frame of the poses (for the JSON's ``units``) and the start/goal units."""

    name: str
    model_name: str
    group: str
    joints: tuple[str, ...]
    pose_frame: str
    joint_units: str

    @property
    def problems_path(self) -> str:
        return f"resources/{self.name}/problems.tar.bz2"

    @property
    def urdf_path(self) -> str:
        return f"resources/{self.name}/{self.name}.urdf"

    @property
    def output(self) -> Path:
        return DATASET / f"{self.name}_problems.json"

    @property
    def regenerate(self) -> str:
        extra = "" if self.name == "panda" else f" --robot {self.name}"
        return f"python -m tools.mbm_convert --vamp PATH_TO_VAMP_GIT_DIR{extra}"


UR5_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
              "wrist_3_joint")
FETCH_JOINTS = ("torso_lift_joint", "shoulder_pan_joint", "shoulder_lift_joint", "upperarm_roll_joint",
                "elbow_flex_joint", "forearm_roll_joint", "wrist_flex_joint", "wrist_roll_joint")
ROBOTS = {
    "panda": RobotSpec("panda", "panda", "panda_arm", ARM_JOINTS, "the robot base frame", "panda_joint1..7 (rad)"),
    "ur5": RobotSpec("ur5", "ur5_robotiq85", "manipulator", UR5_JOINTS,
                     "the frame of the URDF's root link offset_link (the UR5's base_link stands 0.9144 m above "
                     "it, turned 1.57 rad about z)",
                     "robot.joints in that order (rad)"),
    "fetch": RobotSpec("fetch", "fetch", "arm_with_torso", FETCH_JOINTS, "the frame of base_link (the URDF's root)",
                       "robot.joints in that order: torso_lift_joint (m), then the seven arm joints (rad)"),
}


def git_show(git_dir: Path, path: str, commit: str = VAMP_COMMIT) -> bytes:
    """The bytes of ``path`` at ``commit`` in the repository ``git_dir`` (a .git directory or a bare mirror)."""
    try:
        return subprocess.run(["git", f"--git-dir={git_dir}", "show", f"{commit}:{path}"], check=True,
                              capture_output=True).stdout
    except subprocess.CalledProcessError as exc:
        raise SystemExit(f"cannot read {path} at {commit[:12]} from {git_dir}: "
                         f"{exc.stderr.decode().strip().splitlines()[-1]}") from None


def urdf_limits(urdf: bytes) -> dict[str, tuple[float, float]]:
    """Joint name -> (lower, upper) of the URDF's revolute and prismatic joints."""
    limits = {}
    for joint in ET.fromstring(urdf).iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") in ("revolute", "prismatic") and limit is not None:
            limits[joint.get("name")] = (float(limit.get("lower")), float(limit.get("upper")))
    return limits


def urdf_root(urdf: bytes) -> str:
    """The URDF's root link (the one link that is no joint's child): the frame MoveIt plans in."""
    tree = ET.fromstring(urdf)
    children = {j.find("child").get("link") for j in tree.iter("joint")}
    roots = [link.get("name") for link in tree.iter("link") if link.get("name") not in children]
    if len(roots) != 1:
        raise SystemExit(f"expected one root link in the URDF, found {roots}")
    return roots[0]


def _rotate(q: list[float], v: list[float]) -> list[float]:
    """``v`` rotated by the unit quaternion ``q`` = (x, y, z, w): v + 2 w (u x v) + 2 u x (u x v)."""
    x, y, z, w = q
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)]


def compose(a: list[float], b: list[float]) -> list[float]:
    """The pose ``a * b`` (``b`` given in ``a``'s frame), both ``[x, y, z, qx, qy, qz, qw]``; plain
    Python floats, so the result does not depend on the platform's BLAS."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a[3:], b[3:]
    t = _rotate(a[3:], b[:3])
    return [a[0] + t[0], a[1] + t[1], a[2] + t[2],
            aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def check_header(owner: str, message: dict, frame: str) -> None:
    """Refuse a ``header`` naming a frame other than the planning frame (the URDF's root)."""
    header = message.get("header")
    if header is not None and (set(header) - {"frame_id"} or header.get("frame_id", frame) not in ("", frame)):
        raise SystemExit(f"{owner}: header {header} (expected frame {frame!r})")


def read_yaml(data: bytes) -> Any:
    import yaml
    return yaml.load(data, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def _pose(message: dict) -> list[float]:
    return [float(v) for v in message["position"]] + [float(v) for v in message["orientation"]]


def scene_objects(scene: dict, frame: str = "") -> tuple[list[tuple[str, str, list[float], list[float]]], bool]:
    """(id, primitive type, MoveIt dimensions, pose [x, y, z, qx, qy, qz, qw]) of each collision object,
    and whether any object had an object-level pose.

    Every object of these files is one primitive with one pose. Where the object has a pose as well
    (MoveIt >= Noetic: the primitive's pose is relative to it; the UR5's ``table_pick``), the stored
    pose is their composition, as MoveIt and VAMP's loader compute it. A header may only name the
    planning frame ``frame``. Anything else is refused rather than converted approximately."""
    out, composed = [], False
    if set(scene["world"]) != {"collision_objects"}:
        raise SystemExit(f"unexpected world entries {sorted(scene['world'])}")
    for co in scene["world"]["collision_objects"]:
        if set(co) - {"id", "header", "pose", "primitives", "primitive_poses"}:
            raise SystemExit(f"object {co['id']!r}: unexpected entries {sorted(set(co) - {'id', 'primitives'})}")
        if len(co["primitives"]) != 1 or len(co["primitive_poses"]) != 1:
            raise SystemExit(f"object {co['id']!r}: expected one primitive with one pose")
        check_header(f"object {co['id']!r}", co, frame)
        kind = co["primitives"][0]["type"]
        if kind not in PRIMITIVES:
            raise SystemExit(f"object {co['id']!r}: unknown primitive {kind!r}")
        pose = _pose(co["primitive_poses"][0])
        if "pose" in co:
            pose, composed = compose(_pose(co["pose"]), pose), True
        out.append((co["id"], kind, [float(v) for v in co["primitives"][0]["dimensions"]], pose))
    return out, composed


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


def convert(tarball: bytes, urdf: bytes, robot: str = "panda") -> dict[str, Any]:
    """The JSON document of ``robot``'s problems in ``tarball`` with the joint limits of ``urdf``."""
    spec = ROBOTS[robot]
    joints = spec.joints
    frame = urdf_root(urdf)
    files: dict[tuple[str, str, int], dict] = {}
    with tarfile.open(fileobj=io.BytesIO(tarball), mode="r:bz2") as tar:
        for member in tar.getmembers():
            if not member.isfile():
                continue
            match = re.fullmatch(rf"problems/(\w+)_{robot}/(scene|request)(\d{{4}})\.yaml", member.name)
            if match is None:
                raise SystemExit(f"unexpected file {member.name!r} in the tarball")
            folder, kind, number = match.groups()
            files[folder, kind, int(number)] = read_yaml(tar.extractfile(member).read())
    if sorted({f for f, _, _ in files}) != sorted(SCENES):
        raise SystemExit(f"expected the scenes {SCENES}, found {sorted({f for f, _, _ in files})}")

    acm, held, composed_any = None, None, False
    scenes: dict[str, Any] = {}
    for name in SCENES:
        numbers = sorted(n for f, k, n in files if f == name and k == "scene")
        if numbers != sorted(n for f, k, n in files if f == name and k == "request"):
            raise SystemExit(f"{name}: scene and request files do not pair up")
        layout, problems = None, []
        for number in numbers:
            where = f"{name} problem {number}"
            scene, request = files[name, "scene", number], files[name, "request", number]
            if scene.get("robot_model_name") != spec.model_name:
                raise SystemExit(f"{where}: robot {scene.get('robot_model_name')!r}, expected {spec.model_name!r}")
            if request.get("group_name") != spec.group:
                raise SystemExit(f"{where}: planning group {request.get('group_name')!r}, expected {spec.group!r}")
            for tf in scene.get("fixed_frame_transforms") or []:
                if [float(v) for v in tf["transform"]["translation"] + tf["transform"]["rotation"]] != IDENTITY:
                    raise SystemExit(f"{where}: fixed frame {tf.get('child_frame_id')!r} is not the identity")
            objects, composed = scene_objects(scene, frame)
            composed_any |= composed
            this_layout = [[oid, kind, dims] for oid, kind, dims, _ in objects]
            if layout is None:
                layout = this_layout
            elif this_layout != layout:   # same objects, kinds and sizes in every problem of a scene
                raise SystemExit(f"{where}: objects differ from the scene's first problem")
            pairs = allowed_pairs(scene)
            if acm is None:
                acm = pairs
            elif pairs != acm:
                raise SystemExit(f"{where}: a different allowed-collision matrix")
            if set(request["start_state"]) - {"joint_state", "multi_dof_joint_state"}:
                raise SystemExit(f"{where}: unexpected start-state entries {sorted(request['start_state'])}")
            js = request["start_state"]["joint_state"]
            check_header(f"{where} start state", js, frame)
            if len(set(js["name"])) != len(js["name"]) or not set(joints) <= set(js["name"]):
                raise SystemExit(f"{where}: start state names {js['name']}, expected each of {joints} once")
            others = tuple(j for j in js["name"] if j not in joints)
            this_held = dict(zip(others, joint_values(js["name"], js["position"], others)))
            if held is None:
                held = this_held
            elif this_held != held:   # the same names in the same order and the same values
                raise SystemExit(f"{where}: held joints at {this_held}, elsewhere {held}")
            goals = request["goal_constraints"]
            if len(goals) != 1:
                raise SystemExit(f"{where}: {len(goals)} goal constraints, expected 1")
            if set(goals[0]) != {"joint_constraints"}:
                raise SystemExit(f"{where}: goal constraints {sorted(goals[0])}, expected joint constraints only")
            constraints = goals[0]["joint_constraints"]
            if any(set(c) != {"joint_name", "position"} for c in constraints):
                raise SystemExit(f"{where}: a goal joint constraint with tolerances or weights")
            goal = {c["joint_name"]: float(c["position"]) for c in constraints}
            if len(goal) != len(constraints) or set(goal) != set(joints):
                raise SystemExit(f"{where}: goal joints {[c['joint_name'] for c in constraints]}, expected {joints}")
            problems.append({"file": number,
                             "start": joint_values(js["name"], js["position"], joints),
                             "goal": [goal[j] for j in joints],
                             "poses": [pose for *_, pose in objects]})
        scenes[name] = {"objects": layout, "problems": problems}

    limits = urdf_limits(urdf)
    missing = [j for j in joints if j not in limits]
    if missing:
        raise SystemExit(f"the URDF has no limited revolute or prismatic joint {missing}")
    poses = f"one per object, in the objects' order: [x, y, z, qx, qy, qz, qw] in {spec.pose_frame} (m)"
    if composed_any:
        poses += ("; where the YAML gives an object pose as well as the primitive's, their composition "
                  "(object pose * primitive pose, as MoveIt and VAMP's loader compute it)")
    return {
        "format": FORMAT,
        "source": {"repository": VAMP_REPOSITORY, "commit": VAMP_COMMIT,
                   "sha256": {spec.problems_path: hashlib.sha256(tarball).hexdigest(),
                              spec.urdf_path: hashlib.sha256(urdf).hexdigest()},
                   "regenerate": spec.regenerate},
        "robot": {"name": robot, "joints": list(joints),
                  "lower": [limits[j][0] for j in joints], "upper": [limits[j][1] for j in joints],
                  "held_joints": held,
                  "allowed_collisions": acm},
        "units": {"objects": "[id, primitive, MoveIt dimensions: box [x, y, z] full lengths (m), "
                             "cylinder [height, radius], sphere [radius]]",
                  "poses": poses,
                  "start, goal": spec.joint_units},
        "scenes": scenes,
    }


# ---------------------------------------------------------------------- the robot's collision model

#: What pybullet assumes for a link without ``<inertial>`` (it says so on stdout at every load):
#: written into such links so that loading is silent and behaves the same.
DEFAULT_INERTIAL = ('<inertial><mass value="1"/>'
                    '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>')
#: Links whose collision mesh pybullet must take as it is (``<collision concave="yes">``: a
#: triangle mesh) rather than as its convex hull. The UR5's forearm mesh fills 64 % of its hull,
#: and the hull reaches into the wrist: 101 of MotionBenchMaker's starts and goals put wrist_2_link
#: or wrist_3_link inside it (up to 2 cm deep), none touches the mesh itself (MoveIt checks the
#: meshes). Only links whose every collision partner is convex may be concave (Bullet collides no
#: triangle mesh with another).
CONCAVE_LINKS = {"ur5": ("forearm_link",), "fetch": ()}


def _collisions(urdf: str) -> dict[str, list[bytes]]:
    """Link name -> its collision elements, serialised without a ``concave`` flag (to compare
    before and after an edit)."""
    out = {}
    for link in ET.fromstring(urdf).iter("link"):
        elements = []
        for c in link.findall("collision"):
            c.attrib.pop("concave", None)
            elements.append(ET.tostring(c))
        out[link.get("name")] = elements
    return out


def collision_urdf(urdf: str, robot: str) -> str:
    """``urdf`` with every ``<visual>`` element removed (pybullet then draws the collision shapes),
    pybullet's default inertial written into the links that have none, and the collision elements
    of :data:`CONCAVE_LINKS` flagged ``concave="yes"``; everything else, every collision element's
    geometry, origin, scale and mesh path included, byte for byte as it was. A comment after the
    XML declaration says so."""
    text = re.sub(r"[ \t]*<visual>.*?</visual>[ \t]*\n", "", urdf, flags=re.S)
    bare = [link.get("name") for link in ET.fromstring(text).iter("link") if link.find("inertial") is None]
    for name in bare:
        closed = re.compile(rf'<link name="{re.escape(name)}"\s*/>')
        opened = re.compile(rf'<link name="{re.escape(name)}"\s*>')
        text, n = closed.subn(f'<link name="{name}">{DEFAULT_INERTIAL}</link>', text, count=1)
        if n == 0:
            text, n = opened.subn(f'<link name="{name}">{DEFAULT_INERTIAL}', text, count=1)
        if n != 1:
            raise SystemExit(f"cannot find link {name!r} in the URDF text")
    concave = CONCAVE_LINKS[robot]
    for name in concave:
        flagged = re.compile(rf'(<link name="{re.escape(name)}"\s*>(?:(?!</link>).)*?<collision)>', re.S)
        text, n = flagged.subn(r'\1 concave="yes">', text, count=1)
        if n != 1:
            raise SystemExit(f"cannot find the collision element of link {name!r}")
    note = (f"<!-- gnn-mp-envs: VAMP's resources/{robot}/{robot}.urdf at {VAMP_COMMIT[:12]} "
            f"({VAMP_REPOSITORY}), for collision checking in pybullet: every <visual> removed; "
            f"pybullet's default inertial (mass 1, unit inertia) written into the links without one "
            f"({', '.join(bare) or 'none'})"
            + (f"; the collision mesh of {', '.join(concave)} flagged concave=\"yes\" (pybullet collides "
               f"the triangle mesh, not its convex hull)" if concave else "")
            + "; everything else unchanged. See README.md. -->\n")
    if text.startswith("<?xml"):
        head, _, rest = text.partition("\n")
        text = head + "\n" + note + rest
    else:
        text = note + text
    tree = ET.fromstring(text)
    if next(tree.iter("visual"), None) is not None:
        raise SystemExit("a <visual> element survived")
    if sorted(link.get("name") for link in tree.iter("link") if link.find("collision[@concave]") is not None) \
            != sorted(concave):
        raise AssertionError("the concave flags are not where they should be")
    if _collisions(text) != _collisions(urdf):
        raise AssertionError("the edit changed a collision element")
    return text


def mesh_paths(urdf: str) -> list[str]:
    """The meshes the URDF's elements reference (comments do not count), as paths relative to its
    folder: pybullet drops a ``package://`` prefix and looks next to the URDF."""
    names = {m.get("filename") for m in ET.fromstring(urdf).iter("mesh")}
    return sorted(n.removeprefix("package://") for n in names)


def robot_files(git_dir: Path, robot: str) -> dict[str, bytes]:
    """Relative path -> bytes of the files that load ``robot`` in pybullet: the edited URDF and the
    collision meshes it references, unchanged."""
    source = f"resources/{robot}/{robot}.urdf"
    urdf = collision_urdf(git_show(git_dir, source).decode(), robot)
    files = {f"{robot}.urdf": urdf.encode()}
    for rel in mesh_paths(urdf):
        if ".." in Path(rel).parts or Path(rel).is_absolute():
            raise SystemExit(f"mesh path {rel!r} leaves the robot's folder")
        files[rel] = git_show(git_dir, f"resources/{robot}/{rel}")
    return files


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
    ap.add_argument("--robot", choices=sorted(ROBOTS), default="panda", help="whose problems (default: panda)")
    ap.add_argument("--out", type=Path, default=None, help="output file (default: the package's ROBOT_problems.json)")
    ap.add_argument("--check", action="store_true", help="compare with --out instead of writing it (exit 1 if it differs)")
    ap.add_argument("--robot-files", action="store_true",
                    help="write (or --check) the robot's URDF and collision meshes under "
                         "gnn_mp_envs/robots/models/ROBOT/ instead of the problems (ur5 and fetch; the "
                         "Panda is pybullet_data's)")
    args = ap.parse_args(argv)
    spec = ROBOTS[args.robot]
    if args.robot_files:
        if args.robot == "panda":
            raise SystemExit("the Panda's model is pybullet_data's franka_panda/panda.urdf; nothing to write")
        folder = ROBOT_FILES / args.robot
        files = robot_files(args.vamp, args.robot)
        if args.check:
            differ = [rel for rel, data in files.items()
                      if not (folder / rel).exists() or (folder / rel).read_bytes() != data]
            differ += [f"{path.relative_to(folder)} (not referenced)" for path in sorted(folder.rglob("*"))
                       if path.is_file() and path.parent != folder and str(path.relative_to(folder)) not in files]
            print(f"{folder}: {len(files)} files, " + (f"DIFFER: {differ}" if differ else "identical"))
            return 1 if differ else 0
        for rel, data in files.items():
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            (folder / rel).write_bytes(data)
        print(f"wrote {len(files)} files under {folder} ({sum(map(len, files.values())) / 1e6:.2f} MB)")
        return 0
    if args.out is None:
        args.out = spec.output
    text = dumps(convert(git_show(args.vamp, spec.problems_path), git_show(args.vamp, spec.urdf_path), args.robot))
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
    from tools import run_script
    sys.exit(run_script(main))
