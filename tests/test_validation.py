"""Bad problems and parameters are refused with a message naming the field (property-based)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gnn_mp_envs.core.problem import InvalidProblemError
from gnn_mp_envs.robots.geometry import Obstacle
from gnn_mp_envs.tasks.maze2d import Maze2DTask, MazeMap

SETTINGS = settings(max_examples=60, deadline=None)
finite = st.floats(-2, 2, allow_nan=False, allow_infinity=False)
non_finite = st.sampled_from([np.nan, np.inf, -np.inf])


@st.composite
def walls_with_a_bad_row(draw):
    """Some valid walls and one that is not finite or inverted, at a random position."""
    rows = [sorted(draw(st.lists(finite, min_size=2, max_size=2))) for _ in range(draw(st.integers(0, 3)))]
    rows = [[a[0], a[0], a[1], a[1]] for a in rows]
    x0, y0 = draw(finite), draw(finite)
    if draw(st.booleans()):
        bad = [x0, y0, x0 + draw(st.floats(0, 1)), y0 + draw(st.floats(0, 1))]
        bad[draw(st.integers(0, 3))] = draw(non_finite)
    else:  # inverted along x or y
        axis = draw(st.integers(0, 1))
        bad = [x0, y0, x0 + 0.1, y0 + 0.1]
        bad[axis + 2] = bad[axis] - draw(st.floats(1e-6, 1))
    at = draw(st.integers(0, len(rows)))
    return rows[:at] + [bad] + rows[at:], at


@SETTINGS
@given(walls_with_a_bad_row())
def test_walls_that_are_not_finite_or_inverted_are_refused_and_named(case):
    walls, at = case
    with pytest.raises(InvalidProblemError, match=rf"walls\[{at}\]"):
        MazeMap(walls=walls)


@SETTINGS
@given(st.floats(max_value=0.0, allow_nan=False) | non_finite)
def test_blobs_need_a_finite_positive_radius(radius):
    with pytest.raises(InvalidProblemError, match=r"blobs\[0\]"):
        MazeMap(blobs=[[0.5, 0.5, radius]])


def test_a_maze_problem_with_start_equal_to_goal_is_refused():
    task = Maze2DTask()
    with pytest.raises(InvalidProblemError, match="start .* already satisfies the goal"):
        task.make_problem({"start": [0.2, 0.2], "goal": [0.2, 0.2]})


@SETTINGS
@given(kind=st.sampled_from(["box", "cylinder"]), data=st.data())
def test_arm_obstacles_with_bad_sizes_are_refused_and_named(kind, data):
    width = 3 if kind == "box" else 2
    size = [0.1] * width
    if data.draw(st.booleans()):  # a bad value
        size[data.draw(st.integers(0, width - 1))] = data.draw(non_finite | st.floats(max_value=0.0))
    else:  # a wrong length
        size = [0.1] * data.draw(st.sampled_from([0, 1, 4, 5][:] if width == 3 else [0, 1, 3, 4]))
    with pytest.raises(InvalidProblemError, match="size"):
        Obstacle(kind, tuple(size), (0.3, 0.0, 0.1))


def test_arm_obstacles_of_unknown_kind_or_bad_position_are_refused():
    with pytest.raises(InvalidProblemError, match="kind"):
        Obstacle("cone", (0.1,), (0.3, 0.0, 0.1))     # box, cylinder and sphere (MotionBenchMaker) exist
    assert Obstacle("sphere", (0.1,), (0.3, 0.0, 0.1)).kind == "sphere"
    with pytest.raises(InvalidProblemError, match="position"):
        Obstacle("box", (0.1, 0.1, 0.1), (0.3, np.nan, 0.1))


bad_counts = (st.floats(allow_nan=True).filter(lambda v: not float(v).is_integer())
              | st.text(max_size=5) | st.integers(max_value=1) | st.integers(min_value=2_000_001)
              | st.sampled_from([None, [3], True]))


@SETTINGS
@given(value=bad_counts)
def test_bad_max_nodes_is_refused_by_name(value):
    if value is None:  # None means "the task's default"
        return
    with pytest.raises(ValueError, match="max_nodes"):
        gym.make("GNNMP/Maze2DRRT-v0", max_nodes=value)


@SETTINGS
@given(key=st.text(min_size=1, max_size=8).filter(lambda k: k not in {"problem", "index"}))
def test_unknown_reset_options_are_refused_by_name(key):
    env = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=50)
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={key: 3})


@SETTINGS
@given(index=st.floats(allow_nan=True).filter(lambda v: not float(v).is_integer()) | st.integers(max_value=-1)
       | st.text(max_size=3))
def test_bad_problem_index_is_refused_by_name(index):
    env = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=50)
    with pytest.raises(ValueError, match=r"options\['index'\]"):
        env.reset(options={"index": index})


def test_scene_is_a_keyword_of_tasks_with_scenes_only():
    with pytest.raises(ValueError, match="unknown scene 'test' for task 'maze2d'"):
        gym.make("GNNMP/Maze2DRRT-v0", scene="test")      # maze2d's scenes are its map kinds
    assert gym.make("GNNMP/Maze2DRRT-v0", scene="spiral", max_nodes=50).unwrapped.scene == "spiral"
    from tests import tiny_task  # noqa: F401  (a task without scenes)
    with pytest.raises(ValueError, match="has no scenes"):
        gym.make("Tiny/TinyRRT-v0", scene="test")
    arm = gym.make("GNNMP/ArmBiRRT-v0", scene="test", max_nodes=50)
    assert arm.unwrapped.scene == "test" and arm.unwrapped.task.scene == "test"
    assert gym.make("GNNMP/ArmBiRRT-v0", split="test", max_nodes=50).unwrapped.scene == "test"
    assert gym.make("GNNMP/ArmBiRRT-v0", split="train", max_nodes=50).unwrapped.scene == "train"
    with pytest.raises(ValueError, match="unknown scene"):
        gym.make("GNNMP/ArmBiRRT-v0", scene="kitchen")
