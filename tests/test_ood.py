"""Out-of-distribution scene families: the oriented boxes of maze2d maps against a
brute-force oracle, each family's generator, the pendulum's torque limit, the arm's new layouts,
the suites and the training flags that keep OOD scenes out of training."""

import math

import numpy as np
import pytest
import torch

from gnn_mp_envs.registration import SQUARE_SYMMETRIES, task_spec
from gnn_mp_envs.tasks.maze2d import Maze2DTask, MazeMap, box_corners, maze_rows
from gnn_mp_envs.tasks.maze2d.scenes import (
    SCENE_FAMILIES,
    Maze2DScenesTask,
    connected,
    families,
    square_symmetry,
    turned,
    walls_as_boxes,
)


# ---------------------------------------------------------------------------- oriented boxes
def separated(p, q, corners) -> bool:
    """Separating-axis test of a segment and a convex polygon: the oracle of the slab test in the
    box's frame (an independent method: projections on the box's two axes and the segment's normal)."""
    d = q - p
    axes = [corners[1] - corners[0], corners[3] - corners[0], np.array([-d[1], d[0]])]
    for a in axes:
        if not np.any(a):
            continue
        box = corners @ a
        seg = np.array([p @ a, q @ a])
        if seg.max() < box.min() or seg.min() > box.max():
            return True
    return False


def test_oriented_box_segment_test_matches_the_separating_axis_oracle_and_dense_sampling():
    rng = np.random.default_rng(0)
    boxes = np.column_stack([rng.uniform(0.2, 0.8, (6, 2)), rng.uniform(0.02, 0.2, 6), rng.uniform(0.01, 0.08, 6),
                             rng.uniform(-math.pi, math.pi, 6)])
    maze = MazeMap(boxes=boxes)
    p = rng.random((3000, 2))
    q = np.clip(p + rng.normal(0, 0.2, (3000, 2)), 0, 1)
    exact = maze.segments_free(p, q)
    corners = box_corners(boxes)
    oracle = np.array([all(separated(a, b, c) for c in corners) for a, b in zip(p, q)])
    np.testing.assert_array_equal(exact, oracle)
    t = np.linspace(0, 1, 300)
    dense = np.array([maze.is_free(a + t[:, None] * (b - a)).all() for a, b in zip(p, q)])
    assert not np.any(exact & ~dense)          # dense sampling can only miss a hit, never invent one
    assert 0.2 < exact.mean() < 0.95           # both outcomes occur
    # the one-segment test takes the same path
    assert [maze.segment_free(a, b) for a, b in zip(p[:200], q[:200])] == exact[:200].tolist()


def test_an_unturned_box_is_its_wall_and_walls_keep_their_answers():
    rng = np.random.default_rng(1)
    walls = np.array([[0.4, 0.0, 0.45, 0.6], [0.1, 0.7, 0.3, 0.75]])
    as_walls, as_boxes = MazeMap(walls=walls), MazeMap(boxes=walls_as_boxes(walls))
    p = rng.random((2000, 2))
    q = np.clip(p + rng.normal(0, 0.2, (2000, 2)), 0, 1)
    np.testing.assert_array_equal(as_walls.segments_free(p, q), as_boxes.segments_free(p, q))
    np.testing.assert_array_equal(as_walls.is_free(p), as_boxes.is_free(p))


def test_points_inside_a_turned_box():
    box = np.array([[0.5, 0.5, 0.2, 0.05, math.pi / 4]])
    maze = MazeMap(boxes=box)
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    along, across = np.array([c, s]), np.array([-s, c])
    inside = [0.5 + 0.19 * along, 0.5 - 0.19 * along + 0.04 * across]
    outside = [0.5 + 0.21 * along, 0.5 + 0.06 * across, np.array([0.65, 0.5])]
    assert not maze.is_free(np.array(inside)).any()
    assert maze.is_free(np.array(outside)).all()


def test_bad_boxes_are_refused():
    with pytest.raises(ValueError, match="half extent"):
        MazeMap(boxes=[[0.5, 0.5, 0.0, 0.1, 0.0]])
    with pytest.raises(ValueError, match="rows of 5"):
        MazeMap(boxes=[[0.5, 0.5, 0.1, 0.1]])


def test_observation_rows_describe_every_obstacle_kind():
    maze = MazeMap(walls=[[0.1, 0.2, 0.3, 0.6]], blobs=[[0.7, 0.7, 0.05]], boxes=[[0.5, 0.4, 0.2, 0.03, 0.5]])
    rows = maze_rows(maze, 64)
    np.testing.assert_allclose(rows, [[0.2, 0.4, 0.1, 0.2, 1, 0, 0], [0.7, 0.7, 0.05, 0.05, 1, 0, 1],
                                      [0.5, 0.4, 0.2, 0.03, math.cos(0.5), math.sin(0.5), 0]])
    with pytest.raises(ValueError, match="at most 2"):
        maze_rows(maze, 2)


def test_square_symmetries_move_maps_and_points_together():
    rng = np.random.default_rng(2)
    maze = MazeMap(walls=[[0.1, 0.2, 0.3, 0.6]], blobs=[[0.7, 0.7, 0.05]], boxes=[[0.5, 0.4, 0.2, 0.03, 0.5]])
    pts = rng.random((500, 2))
    free = maze.is_free(pts)
    for k in range(8):
        moved, (mp,) = square_symmetry(maze, [pts], k)
        np.testing.assert_array_equal(moved.is_free(mp), free)
        # the same map as the registered symmetry matrices of the task (k-th of SQUARE_SYMMETRIES)
        np.testing.assert_allclose(mp, (pts - 0.5) @ np.asarray(SQUARE_SYMMETRIES[k]).T + 0.5, atol=1e-12)


def test_a_turned_map_turns_its_points():
    boxes = np.array([[0.5, 0.3, 0.2, 0.02, 0.0]])
    pts = np.random.default_rng(3).random((400, 2))
    turned_maze = MazeMap(boxes=turned(boxes, 0.7))
    c, s = math.cos(0.7), math.sin(0.7)
    rot = (pts - 0.5) @ np.array([[c, -s], [s, c]]).T + 0.5
    inside = np.all((rot >= 0) & (rot <= 1), axis=1)          # outside the square nothing is free
    np.testing.assert_array_equal(turned_maze.is_free(rot[inside]), MazeMap(boxes=boxes).is_free(pts[inside]))
    assert not MazeMap(boxes=boxes).is_free(pts[inside]).all()


# ---------------------------------------------------------------------------- maze2d scene families
def test_walls_scene_is_the_task_generator_bit_for_bit():
    a, b = Maze2DScenesTask(), Maze2DTask()
    for i in range(5):
        pa, pb = a.problem("test", i), b.problem("test", i)
        np.testing.assert_array_equal(pa.maze.walls, pb.maze.walls)
        np.testing.assert_array_equal(pa.start, pb.start)
        np.testing.assert_array_equal(pa.goal, pb.goal)


@pytest.mark.parametrize("scene", [s for s in SCENE_FAMILIES if s != "walls"])
def test_every_maze2d_family_makes_reproducible_solvable_problems(scene):
    task = Maze2DScenesTask(scene=scene)
    for i in range(3):
        p, again = task.problem("test", i), task.problem("test", i)
        np.testing.assert_array_equal(p.start, again.start)
        np.testing.assert_array_equal(maze_rows(p.maze, 64), maze_rows(again.maze, 64))
        assert len(task.obstacle_rows(p)) <= task.max_obstacles
        assert connected(p.maze, p.start, p.goal, clearance=0.0)
    assert not np.array_equal(task.problem("test", 0).start, task.problem("val", 0).start)


def test_trap_faces_the_start_and_the_goal_trap_holds_the_goal():
    """The straight start-goal segment of a trap problem is blocked (the U is in the way); the
    goal of a goal-trap problem has walls on three sides (rays in 3 of 4 directions hit)."""
    trap, goal_trap = Maze2DScenesTask(scene="trap"), Maze2DScenesTask(scene="goal-trap")
    for i in range(10):
        p = trap.problem("test", i)
        assert not p.maze.segment_free(p.start, p.goal)
        g = goal_trap.problem("test", i)
        rays = [not g.maze.segment_free(g.goal, np.clip(g.goal + 0.6 * np.array(v), 0, 1))
                for v in ((1, 0), (-1, 0), (0, 1), (0, -1))]
        assert sum(rays) == 3


def test_angled_training_and_validation_kinds_are_seeded_in_bounds_and_turned():
    """``mixed-angled`` (training) draws walls at an angle as well as the axis-aligned kinds;
    ``slanted`` (validation) is a tilted wall plus turned bays. Problems are reproducible, their
    endpoints free and inside the square, their oriented boxes off the axes."""
    def off_axis(boxes):
        turn = np.mod(boxes[:, 4], math.pi / 2)
        return bool(np.any((turn > 1e-6) & (turn < math.pi / 2 - 1e-6)))

    for scene in ("mixed-angled", "slanted"):
        task = Maze2DScenesTask(scene=scene)
        angled = 0
        for i in range(12):
            split = "train" if scene == "mixed-angled" else "val"
            p, again = task.problem(split, i), task.problem(split, i)
            np.testing.assert_array_equal(p.goal, again.goal)
            np.testing.assert_array_equal(maze_rows(p.maze, 64), maze_rows(again.maze, 64))
            ends = np.array([p.start, p.goal])
            assert np.all((ends > 0) & (ends < 1)) and p.maze.is_free(ends).all()
            assert connected(p.maze, p.start, p.goal, clearance=0.0)
            angled += len(p.maze.boxes) > 0 and off_axis(p.maze.boxes)
        if scene == "slanted":
            assert angled == 12
        else:
            assert 0 < angled < 12          # angled and axis-aligned kinds both occur
    spec = task_spec("maze2d")
    assert "slanted" in spec.validation_scenes and "mixed-angled" not in spec.validation_scenes + spec.ood_scenes


def test_scene_roles_are_registered_and_kept_apart():
    for task in ("maze2d", "pendulum", "arm"):
        spec = task_spec(task)
        assert spec.ood_scenes and spec.validation_scenes
        assert not set(spec.ood_scenes) & set(spec.validation_scenes)
        assert spec.default_scene("test") not in spec.ood_scenes + spec.validation_scenes
    assert families("ood") == task_spec("maze2d").ood_scenes
    assert families("val") == task_spec("maze2d").validation_scenes


def test_an_ood_scene_plans_through_the_environment():
    import gymnasium as gym
    env = gym.make("GNNMP/Maze2DRRT-v0", split="test", scene="forest")
    obs, _ = env.reset(options={"index": 0})
    assert obs["obstacles"].shape == (64, 8) and int(obs["obstacles"][:, 0].sum()) >= 30


# ---------------------------------------------------------------------------- pendulum
def test_pendulum_upright_scene_is_the_old_generator_and_torque_is_a_problem_parameter():
    from gnn_mp_envs.tasks.pendulum import MAX_TORQUE, PendulumProblem, PendulumTask
    rng = np.random.default_rng([2, 0])
    old_goal = np.array([np.pi + rng.uniform(-0.5, 0.5), rng.uniform(-1.0, 1.0)])
    p = PendulumTask().problem("test", 0)
    np.testing.assert_array_equal(p.goal, PendulumProblem(np.zeros(2), old_goal).goal)
    assert p.max_torque == MAX_TORQUE
    weak = PendulumTask("weak").problem("test", 0)
    assert weak.max_torque < 0.14 * 9.81
    # steering only reaches what the torque limit allows: from rest, one edge's speed change is bounded
    for problem in (p, weak):
        edge = problem.steer(np.zeros(2), np.array([0.0, 8.0]))
        assert abs(edge.control[0]) == pytest.approx(problem.max_torque)
    with pytest.raises(ValueError, match="max_torque"):
        PendulumProblem(np.zeros(2), np.array([3.0, 0.0]), max_torque=0.0)
    hang = PendulumTask("hang").problem("test", 1)
    assert abs(hang.start[0]) > 2.8 and abs(hang.goal[0]) < 0.31


# ---------------------------------------------------------------------------- arm
@pytest.mark.parametrize("scene", ["pillars", "shelves", "bins"])
def test_arm_layouts_make_blocked_problems(scene):
    from gnn_mp_envs.tasks.arm import ArmTask
    task = ArmTask(scene=scene)
    try:
        p = task.problem("test", 0)
        assert not p.straight_line_free() and task.unblocked_problems == 0
        assert len(task.obstacle_rows(p)) <= task.max_obstacles
    finally:
        task.close()


# ---------------------------------------------------------------------------- suites and training
def test_ood_suites_cover_every_ood_and_validation_kind():
    from train.benchmark.suites import SUITES
    for suite, attr, split in (("ood", "ood_scenes", "test"), ("ood-val", "validation_scenes", "val")):
        for task in ("maze2d", "pendulum", "arm"):
            entries = [e for e in SUITES[suite] if e.task == task]
            assert [e.scene for e in entries] == [None, *getattr(task_spec(task), attr)]
            assert {e.split for e in entries} == {split}
            assert "gnn" in entries[0].samplers and len({e.name for e in entries}) == len(entries)


def test_ood_summary_ratios_and_geometric_mean():
    from train.benchmark.suites import ood_markdown

    def report(scene, medians, success=1.0):
        return {"task": "maze2d", "scene": scene, "problems": 20, "split": "test",
                "results": {s: {"success_rate": success, "collision_checks": {"median": m}}
                            for s, m in medians.items()}}
    reports = {"maze2d": report(None, {"uniform": 100, "gnn": 50}),
               "maze2d-trap": report("trap", {"uniform": 100, "gnn": 200}),
               "maze2d-spiral": report("spiral", {"uniform": 100, "gnn": 50}, success=0.9)}
    text = ood_markdown(reports, "cmd")
    row = next(line for line in text.splitlines() if line.startswith("| gnn"))
    assert row == "| gnn | 0.50 (100%) | 2.00 (100%) | 0.50 (90%) | 1.00 | 2.00x |"


def test_training_refuses_ood_and_validation_scenes(tmp_path):
    from train.tree.training import TrainArgs, TrainError, train
    for scene, match in (("spiral", "out-of-distribution"), ("rotated", "out-of-distribution"),
                         ("pockets", "validation scene"), ("slanted", "validation scene")):
        with pytest.raises(TrainError, match=match):
            train(TrainArgs(task="maze2d", model="gnn", scene=scene, out=tmp_path / scene, progress=False))


def test_symmetry_augmentation_maps_a_run_like_the_raw_states():
    """A training run mapped by a symmetry equals the run built from the mapped tree: states,
    features, start, goal and labels move together; the causal k-NN edges stay valid."""
    from agents.nn.causal import causal_knn
    from train.tree.items import Run, symmetries_of, transformed
    rng = np.random.default_rng(4)
    nodes = torch.as_tensor(rng.random((30, 2)), dtype=torch.float32)
    start, goal = nodes[:1], torch.tensor([[0.9, 0.2]])
    feats = torch.cat([start - nodes, goal - nodes, torch.zeros(30, 1)], -1)
    step, periodic = torch.full((2,), 0.05), torch.zeros(2, dtype=torch.bool)
    run = Run(nodes, feats, torch.arange(-1, 29), torch.zeros(30, dtype=torch.long),
              causal_knn(nodes, torch.zeros(30, dtype=torch.long), 4, step, periodic), start, goal,
              torch.zeros(1, 1), torch.tensor([5, 10]), torch.tensor([0, 0]), nodes[[5, 10]] + 0.01)
    for sym in symmetries_of(SQUARE_SYMMETRIES, np.zeros(2), np.ones(2), periodic):
        m = transformed(run, sym)
        mat = sym.matrix.numpy()
        np.testing.assert_allclose(m.nodes.numpy(), (nodes.numpy() - 0.5) @ mat.T + 0.5, atol=1e-6)
        np.testing.assert_allclose(m.features[:, :2].numpy(), (m.start - m.nodes).numpy(), atol=1e-6)
        np.testing.assert_allclose(m.features[:, 2:4].numpy(), (m.goal - m.nodes).numpy(), atol=1e-6)
        np.testing.assert_allclose(m.labels.numpy(), m.nodes[[5, 10]].numpy() + (np.array([0.01, 0.01]) @ mat.T),
                                   atol=1e-6)
        knn = causal_knn(m.nodes, torch.zeros(30, dtype=torch.long), 4, step, periodic)
        d_old = ((nodes[:, None] - nodes[run.knn.clamp(min=0)]) ** 2).sum(-1)
        d_new = ((m.nodes[:, None] - m.nodes[knn.clamp(min=0)]) ** 2).sum(-1)
        np.testing.assert_allclose(d_new.numpy(), d_old.numpy(), atol=1e-6)   # the same neighbour distances
