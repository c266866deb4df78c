"""The sphere checker against its oracles: pybullet's link frames (forward kinematics), the mesh
files (coverage of every link's hulls grown by the margin), pybullet's contacts (never less
conservative), brute-force sphere tests (the tree walk) and a state-by-state loop (the edge
check's order and count)."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from gnn_mp_envs.robots.checkers import bisection_order
from gnn_mp_envs.robots.geometry import Obstacle
from gnn_mp_envs.robots.catalog import fetch_model, panda_model, ur5_model, xarm6_model
from gnn_mp_envs.robots.model import sphere_model_path, urdf_file
from gnn_mp_envs.robots.spheres.build import BULLET_MARGIN, COVER_TOLERANCE, coverage_gaps, max_overshoot
from gnn_mp_envs.robots.spheres.checker import SphereCollisionChecker
from gnn_mp_envs.robots.spheres.kernel import joint_distance
from gnn_mp_envs.robots.spheres.model import leaf_rows, load_sphere_model
from gnn_mp_envs.robots.urdf import read_urdf
from gnn_mp_envs.robots.world import CONTACT_DISTANCE, RobotWorld

#: The MotionBenchMaker robot models with a shipped sphere model, and the MBM task that plans each.
ROBOTS = {"panda": (panda_model, "panda-mbm"), "ur5": (ur5_model, "ur5-mbm"), "fetch": (fetch_model, "fetch-mbm")}
#: Every robot model with a shipped sphere model (the xArm6 of the arm task too), and the task that plans it.
SPHERE_ROBOTS = {**ROBOTS, "xarm6": (xarm6_model, "arm")}


@pytest.fixture(scope="module", params=sorted(SPHERE_ROBOTS))
def world(request):
    w = RobotWorld(SPHERE_ROBOTS[request.param][0]())
    yield w
    w.close()


_CHECKERS: dict[int, SphereCollisionChecker] = {}


def sphere_checker(world, scene):
    """The world's robot's :class:`SphereChecker` with ``scene`` loaded (one checker object per world)."""
    if id(world) not in _CHECKERS:
        _CHECKERS[id(world)] = SphereCollisionChecker(world)
    return _CHECKERS[id(world)].kernel(scene)


def _names(world):
    p, cid, r = world.p, world.client, world.robot
    return {j: p.getJointInfo(r, j, physicsClientId=cid)[12].decode() for j in range(p.getNumJoints(r, physicsClientId=cid))}


def test_leaf_rows_are_the_leaves_under_a_node_in_increasing_order():
    """A hand-made tree (children are consecutive rows after their parent, not a subtree's rows):
    0 -> 1, 2; 1 -> 3, 4; 4 -> 5, 6 (2, 3, 5, 6 are leaves)."""
    first_child = np.array([1, 3, 0, 0, 5, 0, 0])
    child_count = np.array([2, 2, 0, 0, 2, 0, 0])
    assert [leaf_rows(r, first_child, child_count).tolist() for r in range(7)] == [
        [2, 3, 5, 6], [3, 5, 6], [2], [3], [5, 6], [5], [6]]


def test_the_shipped_model_exists_and_matches_the_robot(world):
    path = sphere_model_path(world.robot_model.spheres)
    assert path.exists(), f"missing shipped sphere model {path}"
    model = load_sphere_model(path)
    robot = read_urdf(str(urdf_file(world.robot_model.urdf)))
    with_geometry = {link for link, cols in robot.collisions.items() if cols}
    assert set(model.roots) == with_geometry
    # the margin: pybullet's and a padding no larger than the pybullet checker's
    assert model.margin == pytest.approx(BULLET_MARGIN + model.meta["padding"])
    assert 0 < model.meta["padding"] <= world.robot_model.padding


def test_forward_kinematics_matches_pybullet(world):
    checker = sphere_checker(world, ())
    names = _names(world)
    rng = np.random.default_rng(0)
    p, cid = world.p, world.client
    for _ in range(20):
        q = rng.uniform(world.low, world.high)
        world.set_config(q)
        rot, trans = checker.link_frames(q)
        for j, name in names.items():
            s = p.getLinkState(world.robot, j, computeForwardKinematics=True, physicsClientId=cid)
            i = checker.links.index(name)
            np.testing.assert_allclose(trans[i], s[4], atol=1e-6)
            np.testing.assert_allclose(rot[i], np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3), atol=1e-6)


def test_every_inner_node_contains_the_leaves_below_it(world):
    """What the walk relies on: a sphere that misses a node misses every leaf under it; in the model's
    trees and in the trees the checker merges for links rigidly joined (rows after the model's)."""
    checker = sphere_checker(world, ())
    spheres = checker.spheres
    assert len(spheres.nodes) >= len(checker.model.nodes)
    np.testing.assert_array_equal(spheres.nodes[: len(checker.model.nodes)], checker.model.nodes)
    for i in np.flatnonzero(spheres.child_count > 0):
        below, stack = [], [int(i)]
        while stack:
            k = stack.pop()
            if spheres.child_count[k] == 0:
                below.append(k)
            else:
                stack.extend(range(spheres.first_child[k], spheres.first_child[k] + spheres.child_count[k]))
        leaves = spheres.nodes[below]
        reach = np.linalg.norm(leaves[:, :3] - spheres.nodes[i, :3], axis=1) + leaves[:, 3]
        assert (reach <= spheres.nodes[i, 3] + 1e-12).all()


def test_self_collision_of_rigid_bodies_answers_as_every_checked_link_pair(world):
    """Links rigidly joined are one body to the kernel (the UR5's forearm against the gripper's nine parts
    is one pair): its answers are those of every checked link pair (``self_pairs``), each link's own
    self-collision leaves in its own frame, brute force; and a pair that cannot move apart is dropped."""
    checker = sphere_checker(world, ())
    assert len(checker.spheres.pairs) <= len(checker.self_pairs)        # the xArm6 has no links to merge
    got, want = _kernel_and_brute_force(checker, np.random.default_rng(11), world, 80)
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < len(got)            # both answers occur


def test_rigidly_joined_links_whose_spheres_touch_are_refused_in_one_line(monkeypatch):
    """A pair of links that never move apart and touch would make every configuration collide: the
    checker says so when it is built, naming the pair, instead of planning nothing."""
    from gnn_mp_envs.robots.spheres import checker as checker_module
    from gnn_mp_envs.robots.spheres.model import SphereModel
    model = load_sphere_model(sphere_model_path(ur5_model().spheres))
    nodes = model.nodes.copy()
    stack = [model.self_roots["robotiq_85_left_finger_tip_link"]]
    while stack:                                # every sphere of one finger tip grown by 20 cm
        i = stack.pop()
        nodes[i, 3] += 0.2
        stack.extend(range(model.first_child[i], model.first_child[i] + model.child_count[i]))
    touching = SphereModel(nodes, model.first_child, model.child_count, model.roots, model.self_roots, model.meta)
    monkeypatch.setattr(checker_module, "load_sphere_model", lambda path: touching)
    world = RobotWorld(ur5_model())
    try:
        with pytest.raises(ValueError, match="rigidly joined and their spheres touch") as info:
            SphereCollisionChecker(world).kernel(())
    finally:
        world.close()
    assert "\n" not in str(info.value) and "robotiq_85_left_finger_tip_link" in str(info.value)


def test_spheres_cover_every_link_hull_grown_by_the_margin(world):
    """Every hull vertex (pushed out over its whole normal cone) and a fresh boundary sample 1.5 mm
    apart, grown by the margin less the cover's tolerance (still beyond pybullet's own margin), lie
    in the union of the link's leaves, for both trees of every link; no leaf reaches beyond the
    margin by more than the link's stated overshoot."""
    model = load_sphere_model(sphere_model_path(world.robot_model.spheres))
    robot = read_urdf(str(urdf_file(world.robot_model.urdf)))
    covered = model.margin - COVER_TOLERANCE
    assert covered > BULLET_MARGIN
    for link in model.roots:
        for self_collision, key in ((False, "overshoot"), (True, "self_overshoot")):
            leaves = model.leaves(link, self_collision)
            gaps = coverage_gaps(robot, link, leaves, covered, 0.0015, seed=7)
            assert gaps["vertices"] == 0 and gaps["surface"] == 0, (link, self_collision, gaps)
            assert gaps["checked"] > 200
            assert max_overshoot(robot, link, leaves, model.margin) <= model.meta["links"][link][key] + 1e-9


def _grazing_states(world, problem_scene, rng, count):
    """Configurations within 1e-4 rad of a pybullet contact (on both sides), by bisection between
    a free and a colliding configuration."""
    out = []
    world.load(problem_scene)
    while len(out) < count:
        a, b = rng.uniform(world.low, world.high, (2, len(world.low)))
        fa, fb = world.collides(a.tolist(), CONTACT_DISTANCE), world.collides(b.tolist(), CONTACT_DISTANCE)
        if fa == fb:
            continue
        lo, hi = (a, b) if not fa else (b, a)
        while np.linalg.norm(hi - lo) > 1e-4:
            mid = (lo + hi) / 2
            if world.collides(mid.tolist(), CONTACT_DISTANCE):
                hi = mid
            else:
                lo = mid
        out += [lo, hi]
    return np.array(out)


def test_spheres_say_collision_wherever_pybullet_does(world):
    """Random and grazing configurations of the first test problems: every configuration pybullet
    calls a collision, exactly or with the robot's padding, is a collision for the spheres."""
    from gnn_mp_envs.registration import make_task
    name = next(k for k, v in SPHERE_ROBOTS.items() if v[0]().urdf == world.robot_model.urdf)
    task = make_task(SPHERE_ROBOTS[name][1], checker="pybullet")
    model_padding = load_sphere_model(sphere_model_path(world.robot_model.spheres)).meta["padding"]
    rng = np.random.default_rng(1)
    pybullet_hits = 0
    try:
        for i in range(6):
            problem = task.problem("test", i)
            states = np.concatenate([rng.uniform(world.low, world.high, (400, len(world.low))),
                                     _grazing_states(world, problem.obstacles, rng, 100)])
            world.load(problem.obstacles)
            exact = np.array([world.collides(q.tolist(), CONTACT_DISTANCE) for q in states])
            padded = np.array([world.collides(q.tolist()) for q in states])
            spheres = ~sphere_checker(world, problem.obstacles).valid(states)
            assert not (exact & ~spheres).any(), states[exact & ~spheres][:3]
            if model_padding >= world.robot_model.padding:      # the Panda's spheres keep the padding too
                assert not (padded & ~spheres).any(), states[padded & ~spheres][:3]
            pybullet_hits += int(exact.sum())
    finally:
        task.close()
    assert pybullet_hits > 500        # the test saw collisions to agree on


def _brute_force_collides(checker, leaves, self_leaves, q):
    """Every obstacle-tree leaf against every obstacle and every self-tree leaf of every checked pair,
    no tree: the oracle of the walk."""
    from scipy.spatial import cKDTree
    rot, trans = checker.link_frames(q)
    world_leaves, world_self = {}, {}
    for i, link in enumerate(checker.links):
        if link in leaves:
            world_leaves[link] = np.c_[leaves[link][:, :3] @ rot[i].T + trans[i], leaves[link][:, 3]]
            world_self[link] = np.c_[self_leaves[link][:, :3] @ rot[i].T + trans[i], self_leaves[link][:, 3]]
    for o in range(len(checker.obstacles.kind)):
        for link, lv in world_leaves.items():
            if checker.obstacles.exempt[o, checker.links.index(link)]:
                continue
            d = lv[:, :3] - checker.obstacles.centre[o]
            local = d @ checker.obstacles.rot[o]
            size = checker.obstacles.size[o]
            if checker.obstacles.kind[o] == 0:
                gap = np.linalg.norm(np.maximum(np.abs(local) - size, 0.0), axis=1)
            elif checker.obstacles.kind[o] == 1:
                er = np.maximum(np.linalg.norm(local[:, :2], axis=1) - size[0], 0.0)
                ez = np.maximum(np.abs(local[:, 2]) - size[1], 0.0)
                gap = np.hypot(er, ez)
            else:
                gap = np.maximum(np.linalg.norm(d, axis=1) - size[0], 0.0)
            if (gap <= lv[:, 3]).any():
                return True
    trees: dict[str, cKDTree] = {}
    for a, b in checker.self_pairs:
        la, lb = world_self[a], world_self[b]
        for link in (a, b):
            if link not in trees:
                trees[link] = cKDTree(world_self[link][:, :3])
        # scipy's k-d trees pick the candidates (within the largest radius sum, grown far above
        # rounding); every candidate pair is then compared exactly, as the full distance matrix would
        near = trees[a].sparse_distance_matrix(trees[b], la[:, 3].max() + lb[:, 3].max() + 1e-9,
                                               output_type="ndarray")
        i, j = near["i"], near["j"]
        if (np.linalg.norm(la[i, :3] - lb[j, :3], axis=1) <= la[i, 3] + lb[j, 3]).any():
            return True
    return False


def _around(world, offset):
    """A point ``offset`` away from the middle of the robot's links at its middle configuration (so
    that hand-made obstacles sit where every robot reaches)."""
    _, trans = sphere_checker(world, ()).link_frames((world.low + world.high) / 2)
    return tuple(float(v) for v in trans.mean(axis=0) + np.asarray(offset))


def test_the_tree_walk_equals_brute_force(world):
    obstacles = (Obstacle("box", (0.1, 0.3, 0.02), _around(world, (0.25, 0.0, 0.0)), yaw=0.3),
                 Obstacle("cylinder", (0.05, 0.5), _around(world, (0.1, -0.3, -0.1))),
                 Obstacle("sphere", (0.08,), _around(world, (0.0, 0.35, 0.2))))
    checker = sphere_checker(world, obstacles)
    got, want = _kernel_and_brute_force(checker, np.random.default_rng(3), world, 60)
    np.testing.assert_array_equal(got, want)
    assert 5 < got.sum() < 55            # both answers occur


def _kernel_and_brute_force(checker, rng, world, count):
    """Whether each of ``count`` uniform configurations collides, by the kernel and by brute force."""
    states = rng.uniform(world.low, world.high, (count, len(world.low)))
    leaves = {link: checker.model.leaves(link) for link in checker.model.roots}
    self_leaves = {link: checker.model.leaves(link, True) for link in checker.model.roots}
    want = np.array([_brute_force_collides(checker, leaves, self_leaves, q) for q in states])
    return ~checker.valid(states), want


def _object_collides(checker, obstacles, exempt, leaves, q):
    """Every obstacle-tree leaf against each obstacle as the scene gives it (its own position, rotation
    and size, in the scene's order), links excused by ``exempt`` skipped: the oracle of the kernel's
    arrays (runs of one kind, columns by coordinate)."""
    from scipy.spatial.transform import Rotation
    rot, trans = checker.link_frames(q)
    for o, ob in enumerate(obstacles):
        r = Rotation.from_quat(ob.quaternion()).as_matrix()
        for i, link in enumerate(checker.links):
            if link not in leaves or link in exempt.get(o, ()):
                continue
            lv = leaves[link]
            local = (lv[:, :3] @ rot[i].T + trans[i] - np.asarray(ob.position)) @ r
            if ob.kind == "box":
                gap = np.linalg.norm(np.maximum(np.abs(local) - np.asarray(ob.size), 0.0), axis=1)
            elif ob.kind == "cylinder":
                gap = np.hypot(np.maximum(np.linalg.norm(local[:, :2], axis=1) - ob.size[0], 0.0),
                               np.maximum(np.abs(local[:, 2]) - ob.size[1] / 2, 0.0))
            else:
                gap = np.maximum(np.linalg.norm(local, axis=1) - ob.size[0], 0.0)
            if (gap <= lv[:, 3]).any():
                return True
    return False


def test_obstacles_of_mixed_kinds_in_any_order_answer_as_each_obstacle_alone(world):
    """The kernel keeps a scene's obstacles in runs of one kind and tests a link's root against all of
    them at once: a scene whose kinds come mixed, with one obstacle in the robot's way excused,
    answers as the leaves against each obstacle of the scene as given (and the robot's own pairs), in
    either order."""
    centre = _around(world, (0.0, 0.0, 0.0))
    obstacles = [Obstacle("sphere", (0.08,), _around(world, (0.0, 0.35, 0.2))),
                 Obstacle("box", (0.1, 0.3, 0.02), _around(world, (0.25, 0.0, 0.0)), yaw=0.3),
                 Obstacle("cylinder", (0.05, 0.5), _around(world, (0.1, -0.3, -0.1))),
                 Obstacle("box", (0.05, 0.05, 0.05), centre),
                 Obstacle("sphere", (0.05,), _around(world, (-0.2, 0.1, 0.1)))]
    checker = sphere_checker(world, ())
    exempt = {3: list(checker.links)}             # the box at the links' middle, excused for every link
    leaves = {link: checker.model.leaves(link) for link in checker.model.roots}
    states = np.random.default_rng(5).uniform(world.low, world.high, (60, len(world.low)))
    try:
        checker.set_obstacles(())                 # no table either: the robot alone (its pairs: the walk,
        alone = checker.valid(states)             # which test_the_tree_walk_equals_brute_force holds)
        want = np.array([free and not _object_collides(checker, obstacles, exempt, leaves, q)
                         for free, q in zip(alone, states)])
        checker.set_obstacles(obstacles, exempt)
        got = checker.valid(states)
        order = [4, 2, 0, 3, 1]
        checker.set_obstacles([obstacles[o] for o in order], {order.index(3): exempt[3]})
        again = checker.valid(states)
    finally:
        checker.set_obstacles(())
        _CHECKERS.pop(id(world))                  # the next test loads its own scene
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(again, want)
    assert 5 < (~want).sum() < 55                 # both answers occur


#: The moving rigid bodies whose links' obstacle trees the checker merges: head link -> links with spheres
#: (the xArm6's links with spheres each have a joint of their own; bodies fixed to the world stay per link).
RIGID_BODIES = {"panda_link7": 4, "wrist_3_link": 12, "wrist_roll_link": 4, "torso_lift_link": 3}


def test_a_scene_that_excuses_part_of_a_rigid_body_answers_link_by_link(world):
    """A moving rigid body (a gripper and the wrist link it hangs from) is one obstacle tree to the kernel
    where a scene excuses each obstacle for all of its links or none; a scene that excuses one for some
    of them gets the links' own trees for that body. Either way the answers are the leaves' against
    each obstacle as given."""
    checker = sphere_checker(world, ())
    assert {checker.links[h]: len(m) for h, (m, _, _) in checker.bodies.items()} == {
        name: k for name, k in RIGID_BODIES.items() if name in checker.links}
    obstacles = [Obstacle("sphere", (0.08,), _around(world, (0.0, 0.35, 0.2))),
                 Obstacle("box", (0.1, 0.3, 0.02), _around(world, (0.25, 0.0, 0.0)), yaw=0.3),
                 Obstacle("box", (0.05, 0.05, 0.05), _around(world, (0.0, 0.0, 0.0)))]
    leaves = {link: checker.model.leaves(link) for link in checker.model.roots}
    states = np.random.default_rng(17).uniform(world.low, world.high, (60, len(world.low)))
    scenes = [{}, {2: list(checker.links)}]
    for head, (members, _, _) in checker.bodies.items():
        scenes.append({2: [checker.links[members[-1]]]})        # the body's last link only
    try:
        checker.set_obstacles(())
        alone = checker.valid(states)
        for exempt in scenes:
            checker.set_obstacles(obstacles, exempt)
            roots = checker.spheres.link_root
            for head, (members, merged, _) in checker.bodies.items():
                names = [checker.links[m] for m in members]
                if 0 < len(set(exempt.get(2, ())) & set(names)) < len(members):
                    np.testing.assert_array_equal(roots[members], [checker.model.roots[name] for name in names])
                else:
                    assert roots[head] == merged and (roots[members[members != head]] == -1).all()
            want = np.array([free and not _object_collides(checker, obstacles, exempt, leaves, q)
                             for free, q in zip(alone, states)])
            np.testing.assert_array_equal(checker.valid(states), want)
            assert 5 < (~want).sum() < 55             # both answers occur
    finally:
        checker.set_obstacles(())
        _CHECKERS.pop(id(world))                  # the next test loads its own scene


def test_edge_check_answers_and_counts_as_a_state_by_state_loop(world):
    """The edge kernel skips states and pairs that its distance bounds vouch for; the answer and the
    count must be those of checking every state in order (the oracle: ``valid`` state by state, and
    the box test), for edges of every length, both orders and boxes cut anywhere, in clutter where
    edges end at every depth."""
    obstacles = (Obstacle("box", (0.05, 0.05, 0.05), _around(world, (0.25, 0.0, 0.05))),
                 Obstacle("box", (0.2, 0.4, 0.01), _around(world, (0.35, 0.0, -0.38))),
                 Obstacle("cylinder", (0.03, 0.4), _around(world, (0.15, 0.3, 0.0))),
                 Obstacle("sphere", (0.06,), _around(world, (0.1, -0.35, 0.1))))
    checker = sphere_checker(world, obstacles)
    rng = np.random.default_rng(4)
    outcomes = {True: 0, False: 0}
    for _ in range(3000):
        if min(outcomes.values()) >= 60:
            break
        a = rng.uniform(world.low, world.high)
        if not checker.valid(a[None])[0]:
            continue
        d = rng.normal(size=len(a))
        b = a + d / np.linalg.norm(d) * rng.choice([0.05, 0.2, 0.6])
        resolution = float(rng.choice([0.003, 0.01, 0.04]))
        low, high = world.low.copy(), world.high.copy()
        if rng.random() < 0.3:                    # a box that b may leave (a stays inside)
            low, high = np.minimum(a, low + 0.5 * (a - low)), np.maximum(a, high - 0.5 * (high - a))
        # n as the planner computes it (a sequential sum: numpy's pairwise sum can round across an integer)
        n = max(1, math.ceil(math.sqrt(sum(v * v for v in (b - a).tolist())) / resolution))
        for bisection in (True, False):
            order = np.array(bisection_order(n) if bisection else range(1, n + 1))
            states = np.array([a + (k / n) * (b - a) for k in order])
            ok = checker.valid(states) & np.all((states >= low) & (states <= high), axis=1)
            first_bad = int(np.argmin(ok)) if not ok.all() else None
            valid, checks = checker.check_motion(a, b, resolution, low, high, bisection)
            assert valid == (first_bad is None), (n, bisection)
            assert checks == (n if first_bad is None else first_bad + 1), (n, bisection)
            outcomes[valid] += 1
    assert min(outcomes.values()) >= 60, outcomes


def _fused_distance(a, b):
    """``|a - b|`` with each square added to the sum so far in one rounding (a fused multiply-add, in
    order), in exact rational arithmetic: ``float`` of a ``Fraction`` rounds once, to nearest."""
    s = 0.0
    for x, y in zip(a, b):
        d = Fraction(float(x)) - Fraction(float(y))     # rounded once, as the float subtraction is
        s = float(Fraction(float(d)) ** 2 + Fraction(s))
    return math.sqrt(s)


def test_joint_distance_sums_fused_squares_in_order_on_every_cpu():
    """The arms' one joint-space distance (steering, goal connections; compiled and Python): each square
    added in one rounding, in order, whatever numpy's ``d @ d`` does on this CPU's BLAS kernel: vectors
    of 6 to 8 joints, among them many where rounding each product before the sum gives another float."""
    rng = np.random.default_rng(3)
    unfused_differs = 0
    for dof in (6, 7, 8):
        for _ in range(2000):
            a, b = rng.uniform(-3, 3, (2, dof))
            assert joint_distance(a, b) == _fused_distance(a, b)
            unfused_differs += math.sqrt(sum(float(v) * float(v) for v in a - b)) != _fused_distance(a, b)
    assert unfused_differs > 100


def _oracle_edge(checker, a, b, resolution, low, high):
    """``(valid, checks)`` of the edge ``a -> b`` in bisection order, state by state (``valid``, the box)."""
    n = max(1, math.ceil(math.sqrt(sum(v * v for v in (b - a).tolist())) / resolution))
    states = np.array([a + (k / n) * (b - a) for k in bisection_order(n)])
    ok = checker.valid(states) & np.all((states >= low) & (states <= high), axis=1)
    return (True, n) if ok.all() else (False, int(np.argmin(ok)) + 1)


def test_growing_a_tree_answers_as_state_by_state_checks_whatever_the_checker_saw_before(world):
    """Grown as a tree grows, edges start where earlier ones ended; the checker remembers what it
    found at those states and the fused steer-and-check call steers itself. Every answer and count
    must still be the state-by-state oracle's, and the steered state the planner's formula, also
    after the scene changes under the same tree: a small ball put 2 mm from the first node's
    spheres, which edges from it hit within a few states (what was remembered there is void)."""
    first = (Obstacle("box", (0.05, 0.05, 0.05), _around(world, (0.25, 0.0, 0.05))),
             Obstacle("box", (0.2, 0.4, 0.01), _around(world, (0.35, 0.0, -0.38))),
             Obstacle("cylinder", (0.03, 0.4), _around(world, (0.15, 0.3, 0.0))),
             Obstacle("sphere", (0.06,), _around(world, (0.1, -0.35, 0.1))))
    rng = np.random.default_rng(6)
    low, high, step, resolution = world.low, world.high, 0.5, 0.01
    checker = sphere_checker(world, first)
    nodes = [q for q in rng.uniform(low, high, (200, len(low))) if checker.valid(q[None])[0]][:2]
    outcomes = {True: 0, False: 0}

    def grow(checker, starts, edges):
        for _ in range(edges):
            a = starts[int(rng.integers(len(starts)))]
            target = rng.uniform(low, high)
            d = target - a
            dist = _fused_distance(target, a)
            x_new, distance, valid, checks = checker.steer(a, target, step, resolution, low, high)
            assert distance == dist         # to the last bit
            np.testing.assert_array_equal(x_new, target if dist <= step else a + (step / dist) * d)
            assert (valid, checks) == _oracle_edge(checker, a, x_new, resolution, low, high)
            assert checker.check_motion(a, x_new, resolution, low, high) == (valid, checks)
            outcomes[valid] += 1
            if valid:
                nodes.append(x_new)

    grow(checker, nodes, 250)
    root = nodes[0]
    grow(checker, [root], 5)            # the root's clearances are fresh in the checker's memory
    rot, trans = checker.link_frames(root)
    # links the planned joints move (a ball by the xArm6's base, which stands still, no edge meets)
    links = [i for i, link in enumerate(checker.links) if link in checker.model.roots and checker.spheres.reach[i].any()]
    for _ in range(200):                # a ball 2 mm from a leaf at the root, touching nothing there
        i = links[int(rng.integers(len(links)))]
        leaves = checker.model.leaves(checker.links[i])
        leaf = leaves[int(rng.integers(len(leaves)))]
        centre, r = leaf[:3] @ rot[i].T + trans[i], leaf[3]
        u = rng.normal(size=3)
        at = centre + (r + 0.002 + 0.03) * u / np.linalg.norm(u)
        checker = sphere_checker(world, first + (Obstacle("sphere", (0.03,), tuple(float(v) for v in at)),))
        if checker.valid(root[None])[0]:
            break
    before = dict(outcomes)
    grow(checker, [root], 60)
    assert outcomes[False] - before[False] >= 10, outcomes          # edges from the root meet the ball
    assert outcomes[True] >= 100 and outcomes[False] >= 25, outcomes


# ---------------------------------------------------------------------- the checker as users choose it
def test_the_environment_takes_a_checker_and_refuses_unknown_ones():
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401
    env = gym.make("GNNMP/PandaMBM-v0", split="test")
    assert env.unwrapped.checker == "spheres"
    env.reset(options={"index": 0})
    assert env.unwrapped.problem.checker.name == "spheres"
    env.close()
    env = gym.make("GNNMP/PandaMBM-v0", split="test", checker="pybullet")
    env.reset(options={"index": 0})
    assert env.unwrapped.problem.checker.name == "pybullet"
    env.close()
    with pytest.raises(ValueError, match="unknown collision checker 'fcl'"):
        gym.make("GNNMP/PandaMBM-v0", checker="fcl")
    with pytest.raises(ValueError, match="one collision checker"):
        gym.make("GNNMP/Maze2DRRT-v0", checker="spheres")


def test_both_checkers_plan_the_same_problem_and_the_paths_pass_the_re_check():
    """The same problem and samples with either checker: both solve it and both paths pass the
    independent pybullet re-check at 10x finer resolution."""
    from agents.samplers import load_sampler
    from gnn_mp_envs.core.problem import PATH_CHECK_REFINE
    from gnn_mp_envs.evaluation import evaluation_env, plan_problem
    for checker in ("spheres", "pybullet"):
        env = evaluation_env("panda-mbm", checker=checker)
        run = plan_problem(env, load_sampler("uniform", task="panda-mbm", seed=0), 0, 0)
        assert run.success, checker
        solution = env.planner.solution
        assert env.problem.path_valid(solution.states, solution.controls, refine=PATH_CHECK_REFINE)
        env.close()


def test_the_benchmark_refuses_a_checker_the_task_lacks():
    from train.benchmark.args import BenchmarkArgs, BenchmarkError, validate_args
    with pytest.raises(BenchmarkError, match="--checker 'spheres': maze2d has one checker only"):
        validate_args(BenchmarkArgs(task="maze2d", checker="spheres"))
    with pytest.raises(BenchmarkError, match="unknown collision checker .fcl.; known: spheres, pybullet"):
        validate_args(BenchmarkArgs(task="panda-mbm", checker="fcl"))
    args = BenchmarkArgs(task="panda-mbm")
    validate_args(args)
    assert args.checker == "spheres"


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_exactly_the_listed_problems_are_invalid_under_the_sphere_model(robot):
    """Every start and goal of the robot's 700 MotionBenchMaker problems: invalid under the sphere
    model exactly where the data lists it (invalid for pybullet, or for the spheres only)."""
    from gnn_mp_envs.registration import make_task
    from gnn_mp_envs.tasks.mbm.data import INVALID_PROBLEMS, SCENES, SPHERE_INVALID_PROBLEMS, scene_records
    task = make_task(ROBOTS[robot][1], checker="spheres")
    try:
        invalid = set()
        for scene in SCENES:
            for record in scene_records(scene, robot):
                problem = task._mbm_problem(record)
                if not problem.is_state_valid(np.stack([problem.start, problem.goal])).all():
                    invalid.add((scene, record.file))
    finally:
        task.close()
    assert invalid - set(INVALID_PROBLEMS[robot]) == set(SPHERE_INVALID_PROBLEMS[robot])
    assert 700 - len(set(INVALID_PROBLEMS[robot]) | set(SPHERE_INVALID_PROBLEMS[robot])) >= 665   # 95%


def _row_leaves(checker):
    """Per link row of the kernel with an obstacle tree: the centres of that tree's leaves, and of the
    link's own self tree's where the tree is the link's own (its levers cover both), in the link's frame."""
    out = {}
    for i, link in enumerate(checker.links):
        leaves = checker.link_leaves(i)[:, :3]
        if not len(leaves):
            continue
        if checker.spheres.link_root[i] == checker.model.roots.get(link, -1):
            leaves = np.vstack([leaves, checker.model.leaves(link, True)[:, :3]])
        out[i] = leaves
    return out


def _in_world(rows, frames):
    """``rows`` (:func:`_row_leaves`) moved by the link frames ``frames``."""
    rot, trans = frames
    return {i: leaves @ rot[i].T + trans[i] for i, leaves in rows.items()}


def test_the_motion_bounds_hold_along_edges(world):
    """What lets the edge check skip states: over ``s`` states from state ``k`` of an edge, every leaf
    of a link's obstacle tree (a rigid body's, where the kernel merges them) and of its own self tree
    moves at most ``s delta`` and at most ``s rate + s^2 curve / 2`` (``rate`` measured at state ``k``),
    and a link below another moves at most the pair's bounds in that link's frame. The oracle: the
    leaves' positions from forward kinematics at both states."""
    checker = sphere_checker(world, ())
    rng = np.random.default_rng(5)
    tighter = []
    dof = len(world.low)
    rows = _row_leaves(checker)
    pair_leaves = [checker.pair_leaves(p) for p in range(len(checker.spheres.pairs))]
    for trial in range(40 + 2 * dof):
        a = rng.uniform(world.low, world.high)
        # random directions, then each joint alone (twice): a lever that misses a leaf shows there
        d = rng.normal(size=dof) if trial < 40 else np.eye(dof)[(trial - 40) % dof]
        b = a + d / np.linalg.norm(d) * rng.uniform(0.2, 1.5)
        n = int(rng.integers(20, 150))
        k = int(rng.integers(0, n))
        bounds = checker.motion_rates(a, b, n, k)
        frames_here = checker.link_frames(a + (k / n) * (b - a))
        here = _in_world(rows, frames_here)
        for s in (1, 3, 10, 40):
            for sign in (1, -1):
                j = k + sign * s
                if not 0 <= j <= n:
                    continue
                frames_there = checker.link_frames(a + (j / n) * (b - a))
                there = _in_world(rows, frames_there)
                for i, link in enumerate(checker.links):
                    if i not in here:
                        continue
                    moved = float(np.linalg.norm(there[i] - here[i], axis=1).max())
                    curved = s * bounds["rate"][i] + 0.5 * s * s * bounds["curve"][i]
                    assert moved <= s * bounds["delta"][i] + 1e-9, (link, s)
                    assert moved <= curved + 1e-9, (link, s, moved, curved)
                    if moved > 1e-6:
                        tighter.append(min(curved, s * bounds["delta"][i]) / (s * bounds["delta"][i]))
                for p, ((la, lb), m) in enumerate(zip(checker.spheres.pairs, checker.spheres.pair_moving)):
                    if m < 0:
                        continue
                    f = la + lb - m
                    own = pair_leaves[p][0 if m == la else 1][:, :3]   # the moving side's, in m's frame

                    def local(frames):     # the moving side's self leaves in the other link's frame
                        rot, trans = frames
                        return (own @ rot[m].T + trans[m] - trans[f]) @ rot[f]
                    moved = float(np.linalg.norm(local(frames_there) - local(frames_here), axis=1).max())
                    assert moved <= s * bounds["pair_delta"][p] + 1e-9
                    assert moved <= s * bounds["pair_rate"][p] + 0.5 * s * s * bounds["pair_curve"][p] + 1e-9
    assert np.median(tighter) < 0.9        # the local bound is what saves the work: it must be tighter


def _touching(small: np.ndarray, tree, big: np.ndarray) -> bool:
    """Whether a sphere of ``small`` ``(k, 4)`` touches one of ``big`` (centres and radii, in the same
    frame; ``tree``: a k-d tree of ``big``'s centres): brute force over the pairs it cannot rule out
    (some links have tens of thousands of spheres)."""
    for i, near in enumerate(tree.query_ball_point(small[:, :3], small[:, 3] + big[:, 3].max())):
        if near and (np.linalg.norm(big[near, :3] - small[i, :3], axis=1) <= small[i, 3] + big[near, 3]).any():
            return True
    return False


def test_joint_tables_call_free_only_configurations_the_brute_force_calls_free(world):
    """A self pair's joint-space table lets the edge check skip the pair's walk: wherever it says a
    cell is free, the pair's leaves (brute force, no tree) touch nowhere in the cell, at its border
    with cells that are not free above all."""
    checker = sphere_checker(world, ())
    at, joint, low, step, dim, table = checker.tables
    tabled = np.flatnonzero(at >= 0)
    assert len(tabled) >= 1
    rng = np.random.default_rng(6)
    border_seen = 0
    for p in tabled:
        moving = [j for j in joint[p] if j >= 0]
        cells = table[at[p]: at[p] + np.prod(dim[p][: len(moving)])]
        assert (cells >= 1).any()
        border = np.flatnonzero(cells == 1)
        picks = np.concatenate([rng.choice(border, min(len(border), 60), replace=False) if len(border) else [],
                                rng.choice(np.flatnonzero(cells >= 1), 20)]).astype(np.int64)
        border_seen += len(border) > 0
        from scipy.spatial import cKDTree
        (s_index, small), (b_index, big) = sorted(zip(checker.spheres.pairs[p], checker.pair_leaves(p)),
                                                  key=lambda side: len(side[1]))
        names = [checker.links[s_index], checker.links[b_index]]
        tree = cKDTree(big[:, :3])             # the larger link's spheres, in its own frame
        for c in picks:
            cell = np.unravel_index(c, dim[p][: len(moving)])
            q = rng.uniform(world.low, world.high)
            for k, j in enumerate(moving):
                q[j] = low[p, k] + (cell[k] + rng.uniform(0, 1)) * step[p, k]
            if np.any(q < world.low) or np.any(q > world.high):
                continue
            assert checker.table_room(q)[p] >= 1
            rot, trans = checker.link_frames(q)
            world_small = small[:, :3] @ rot[s_index].T + trans[s_index]
            in_big = np.c_[(world_small - trans[b_index]) @ rot[b_index], small[:, 3]]
            assert not _touching(in_big, tree, big), (names, q)
    assert border_seen       # some table has cells next to ones that are not free


def _spun_pairs(checker) -> list[tuple[int, int, int]]:
    """The self pairs whose table holds for every angle of a link turning about its own axis, as
    ``(pair, the other link's side, the turning link's side)``."""
    out = []
    for p, pair in enumerate(checker.spheres.pairs):
        side = checker._spin_side(pair, np.flatnonzero(checker.spheres.pair_reach[p] > 0))
        if side is not None:
            out.append((p, 1 - side, side))
    return out


def test_a_pair_of_three_joints_whose_link_turns_about_its_own_axis_has_a_table_over_the_other_two():
    """The UR5's forearm and wrist 3 (wrist 1, 2 and 3 move them) and the Panda's links 2 and 5 (joints 3, 4,
    5): a table over the two joints that do not turn the link about its own axis."""
    for make, pair, joints in ((ur5_model, ("forearm_link", "wrist_3_link"), [3, 4]),
                               (panda_model, ("panda_link2", "panda_link5"), [2, 3])):
        world = RobotWorld(make())
        try:
            checker = sphere_checker(world, ())
            names = [(checker.links[a], checker.links[b]) for a, b in checker.spheres.pairs]
            p = names.index(pair)
            assert np.flatnonzero(checker.spheres.pair_reach[p] > 0).size == 3
            assert checker.tables.at[p] >= 0 and checker.tables.joint[p].tolist() == joints
        finally:
            world.close()


def test_the_swept_solid_walk_finds_the_least_gap_of_the_brute_force_over_leaf_pairs(world):
    """:func:`~gnn_mp_envs.robots.spheres.kernel.spun_pair_near` against every leaf pair: a sphere of the
    turning link sweeps the points within its radius of its centre's circle about the axis, so the other's
    sphere comes within ``floor`` of it at some angle exactly when the two centres, as (distance from the
    axis, height along it), are within ``floor`` plus both radii. The walk must say near for a floor just
    above the least such gap and not near just below it."""
    from scipy.spatial import cKDTree

    from gnn_mp_envs.robots.spheres.kernel import spun_pair_near
    checker = sphere_checker(world, ())
    spun = _spun_pairs(checker)
    assert spun                 # every robot here has such a pair
    kin, spheres = checker.kinematics, checker.spheres
    rng = np.random.default_rng(11)
    tested = 0
    for p, still, turning in spun:
        la, lb = spheres.pairs[p, still], spheres.pairs[p, turning]
        leaves_a, leaves_b = (checker.pair_leaves(p)[side] for side in (still, turning))
        axis = kin.axis[lb] / np.linalg.norm(kin.axis[lb])
        h_b = leaves_b[:, :3] @ axis
        circles_b = np.c_[np.linalg.norm(leaves_b[:, :3] - h_b[:, None] * axis, axis=1), h_b]
        mine = 0
        for _ in range(200):            # configurations where the walk puts the pair within 1 cm (a walk with a
            if mine == 2:               # floor far above that descends every leaf pair), checked exactly
                break
            q = rng.uniform(world.low, world.high)
            rot, trans = checker.link_frames(q)
            if not spun_pair_near(la, lb, spheres.pair_root[p, still], spheres.pair_root[p, turning], 0.01, *axis,
                                  spheres.nodes, spheres.first_child, spheres.child_count, rot, trans,
                                  checker.scratch.pair_stack):
                continue
            local = ((leaves_a[:, :3] @ rot[la].T + trans[la]) - trans[lb]) @ rot[lb]
            h_a = local @ axis
            tree = cKDTree(np.c_[np.linalg.norm(local - h_a[:, None] * axis, axis=1), h_a])
            d, k = tree.query(circles_b, k=min(8, len(leaves_a)))
            upper = float((d - leaves_b[:, 3, None] - leaves_a[k, 3]).min())     # some leaf pairs' least gap
            reach = upper + leaves_b[:, 3] + leaves_a[:, 3].max() + 1e-9             # all pairs that may be less
            rows = np.flatnonzero(d[:, 0] <= reach)
            least = min(float((np.linalg.norm(tree.data[near] - circles_b[i], axis=1) - leaves_b[i, 3]
                               - leaves_a[near, 3]).min())
                        for i, near in zip(rows, tree.query_ball_point(circles_b[rows], reach[rows])) if near)
            assert least <= 0.01
            mine += 1
            for floor, near in ((least + 1e-7, True), (least - 1e-7, False)):
                walk = spun_pair_near(la, lb, spheres.pair_root[p, still], spheres.pair_root[p, turning], floor,
                                      *axis, spheres.nodes, spheres.first_child, spheres.child_count, rot, trans,
                                      checker.scratch.pair_stack)
                assert walk == near, (checker.self_pairs[p], q, floor, least)
        tested += mine
    assert tested >= 1


def test_joint_tables_are_kept_in_a_file_named_by_their_inputs_and_built_again_when_it_is_damaged(monkeypatch,
                                                                                                  tmp_path):
    """The second checker of a robot reads the tables the first one built (the UR5's take seconds to build),
    from a file in numba's cache folder whose name changes with every input; a damaged file is built again."""
    import numba.core.config

    from gnn_mp_envs.robots.spheres import checker as checker_module
    monkeypatch.setattr(numba.core.config, "CACHE_DIR", str(tmp_path))
    world = RobotWorld(panda_model())
    try:
        monkeypatch.setattr(checker_module, "_TABLES", {})
        built = SphereCollisionChecker(world).kernel(()).tables
        files = sorted(tmp_path.glob("joint-tables-*.npz"))
        assert len(files) == 1
        calls = []
        monkeypatch.setattr(checker_module.SphereChecker, "_build_joint_tables",
                            lambda self, *args: calls.append(1) or checker_module.Tables(*built))
        for damage in (None, b"not a zip file"):
            if damage is not None:
                files[0].write_bytes(damage)
            monkeypatch.setattr(checker_module, "_TABLES", {})
            read = SphereCollisionChecker(world).kernel(()).tables
            for a, b in zip(read, built):
                assert a.dtype == b.dtype and np.array_equal(a, b)
        assert len(calls) == 1                      # read once from the file, built again once it was damaged
        assert checker_module.read_npz(files[0], checker_module.TABLES_FORMAT)["cells"].size == built.cells.size
    finally:
        world.close()
    arrays = [np.arange(5.0), np.zeros((2, 2), dtype=np.int64)]
    names = {checker_module.tables_file(arrays, ("panda", 0.003)),
             checker_module.tables_file([arrays[0] + 1e-12, arrays[1]], ("panda", 0.003)),
             checker_module.tables_file([arrays[0], arrays[1].astype(np.int32)], ("panda", 0.003)),
             checker_module.tables_file(arrays, ("panda", 0.004))}
    assert len(names) == 4 and checker_module.tables_file(arrays, ("panda", 0.003)) in names


def test_the_kernel_views_each_array_of_its_table_as_the_array_it_names(world):
    """The kernel reads its arrays through a table of addresses and shapes (no reference counts), so a
    field read as another dtype or shape would read foreign memory: every group the compiled code views
    must hold the checker's own arrays (same address, shape, dtype), and an array of another dtype is
    refused when the table is built."""
    from gnn_mp_envs.robots.spheres import kernel
    from gnn_mp_envs.utils.compiled import jit

    checker = sphere_checker(world, ())
    viewers = (kernel.view_kinematics, kernel.view_spheres, kernel.view_tables, kernel.view_obstacles,
               kernel.view_scratch, kernel.view_memo)
    assert [type(g) for g in checker._packed_groups] == list(kernel.GROUPS)
    for view, group in zip(viewers, checker._packed_groups, strict=True):
        seen = jit(view.py_func)(checker._packed)              # the view, compiled as the kernel compiles it
        assert type(seen) is type(group)
        for (name, dtype, ndim), mine, theirs in zip(type(group).spec, group, seen, strict=True):
            assert theirs.__array_interface__["data"][0] == mine.ctypes.data, name
            assert theirs.shape == mine.shape and theirs.dtype == mine.dtype == dtype and mine.ndim == ndim, name
            np.testing.assert_array_equal(theirs, mine)
    kept = checker.scratch
    checker.scratch = kept._replace(q=kept.q.astype(np.float32))
    with pytest.raises(TypeError, match="Scratch.q must be a C-contiguous 1-D float64 array"):
        checker._pack()
    checker.scratch = kept
    checker._pack()


def test_the_planning_checks_bench_replays_the_edges_the_planner_counted(capsys, tmp_path):
    """tools/bench_planning_checks.py replays a planner's steer and edge calls through the compiled kernel:
    its edges and checks equal the environment's counters (it stops with an error otherwise) and the
    benchmark's, for the same problems and seeds."""
    import json

    from tools.bench_planning_checks import main
    from train.cli import main as cli
    assert main(["--task", "arm", "--split", "val", "--problems", "3", "--repeat", "1"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    edges, checks = int(line.split("): ")[1].split(" edges")[0]), int(line.split("edges, ")[1].split(" collision")[0])
    assert cli(["benchmark", "--task", "arm", "--split", "val", "--samplers", "uniform", "--problems", "3",
                "--seed", "0", "--workers", "1", "--no-recheck", "--no-progress", "--json",
                str(tmp_path / "runs.json")]) == 0
    runs = json.loads((tmp_path / "runs.json").read_text())["runs"]["uniform"]
    assert len(runs) == 3 and edges > 0
    assert (edges, checks) == (sum(r["edges"] for r in runs), sum(r["collision_checks"] for r in runs))
