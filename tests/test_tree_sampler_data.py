"""Algorithm 1's dataset: labels are the next path nodes; files are reproducible and checked."""

from __future__ import annotations

import numpy as np
import pytest

from gnn_mp_envs.utils.npz import DatasetCacheError
from train.tree_samplers.data import TreeDataConfig, TreeDataset, generate, load, load_or_generate, save


def hand_made() -> TreeDataset:
    """One RRT tree of 6 nodes; the path is 0 -> 2 -> 3 -> 5 (1 and 4 are side branches)."""
    states = np.array([[0, 0], [1, 0], [0, 1], [0, 2], [1, 1], [0, 3]], dtype=np.float32)
    parent = np.array([-1, 0, 0, 2, 1, 3], dtype=np.int32)
    return TreeDataset(
        config=TreeDataConfig(task="maze2d", problems=1), node_ptr=np.array([0, 6]), states=states,
        node_features=np.zeros((6, 5), np.float32),
        parent=parent, tree_id=np.zeros(6, np.int8), path_ptr=np.array([0, 4]),
        path_nodes=np.array([0, 2, 3, 5], np.int32), start=states[:1], goal=states[5:6],
        obstacles=np.zeros((1, 1, 1), np.float32), problem_index=np.array([0]))


def test_labels_are_the_next_path_nodes_on_a_hand_made_tree():
    data = hand_made()
    assert data.examples().tolist() == [[0, 2], [0, 3], [0, 5]]
    np.testing.assert_array_equal([data.label(0, j) for j in (2, 3, 5)], [[0, 1], [0, 2], [0, 3]])
    # prefix view: the root and the path nodes before the label
    states, parent, _, active = data.graph(0, 5, "prefix")
    np.testing.assert_array_equal(states, [[0, 0], [0, 1], [0, 2]])
    assert parent.tolist() == [-1, 0, 1] and active == 0
    # grown view: everything the planner had when node 5 was inserted, side branches too
    states, parent, _, _ = data.graph(0, 5, "grown")
    assert len(states) == 5 and parent.tolist() == [-1, 0, 0, 2, 1]
    assert data.graph(0, 2, "prefix")[0].tolist() == [[0, 0]]


def test_rrt_labels_follow_the_solution_path():
    data = generate(TreeDataConfig(task="maze2d", problems=2, max_nodes=2000), progress=False)
    assert len(data) == 2
    for p, j in data.examples():
        states, parent, tree_id = data.tree(p)
        path = list(data.path(p))
        assert path[path.index(j) - 1] == parent[j]          # the label's parent is the previous path node
        assert data.graph(p, j, "grown")[0].shape[0] == j


def test_arm_examples_cover_both_trees():
    data = generate(TreeDataConfig(task="arm", scene="train", problems=3), progress=False)
    actives = {data.graph(p, j, "grown")[3] for p, j in data.examples()}
    assert actives == {0, 1}
    for p, j in data.examples():
        states, parent, tree_id = data.tree(p)
        assert tree_id[parent[j]] == tree_id[j]               # a label extends its own tree


def test_files_regenerate_byte_identically_and_damage_is_named(tmp_path):
    config = TreeDataConfig(task="maze2d", problems=3, max_nodes=2000)
    a = save(generate(config, progress=False), tmp_path / "a.npz")
    b = save(generate(config, progress=False), tmp_path / "b.npz")
    assert a.read_bytes() == b.read_bytes()
    assert load(a).config == config
    cached = tmp_path / config.file_name()
    cached.write_bytes(a.read_bytes()[:100])                   # truncated
    with pytest.raises(DatasetCacheError, match=config.file_name()):
        load(cached)
    assert load_or_generate(config, tmp_path, progress=False).config == config
    assert cached.read_bytes() == a.read_bytes()
