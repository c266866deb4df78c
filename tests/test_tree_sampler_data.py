"""Algorithm 1's dataset: labels are the next path nodes; files are reproducible and checked."""

from __future__ import annotations

import numpy as np
import pytest

from gnn_mp_envs.utils.npz import DatasetCacheError
from train.tree.data import TreeDataConfig, TreeDataset, generate, load, load_or_generate, save
from train.tree.training import split_problems


def hand_made(iterations=((1, 0), (2, 0), (3, 0), (4, 0), (5, 0))) -> TreeDataset:
    """One RRT tree of 6 nodes; the path is 0 -> 2 -> 3 -> 5 (1 and 4 are side branches)."""
    states = np.array([[0, 0], [1, 0], [0, 1], [0, 2], [1, 1], [0, 3]], dtype=np.float32)
    parent = np.array([-1, 0, 0, 2, 1, 3], dtype=np.int32)
    it = np.asarray(iterations)
    return TreeDataset(
        config=TreeDataConfig(task="maze2d", problems=1), node_ptr=np.array([0, 6]), states=states,
        node_features=np.zeros((6, 5), np.float32), parent=parent, tree_id=np.zeros(6, np.int8),
        path_ptr=np.array([0, 4]), path_nodes=np.array([0, 2, 3, 5], np.int32), start=states[:1], goal=states[5:6],
        obstacles=np.zeros((1, 1, 1), np.float32), problem_index=np.array([0]), iter_ptr=np.array([0, len(it)]),
        iter_nodes=it[:, 0].astype(np.int32), iter_active=it[:, 1].astype(np.int8),
        iter_sample=np.zeros((len(it), 2), np.float32), iter_created=np.full(len(it), -1, np.int32))


def test_a_split_holds_out_a_tenth_but_never_the_last_problem_to_train_on():
    """A DAgger round splits the problems it solved: one is trained on, none adds nothing (a round that
    solved one problem failed in ``np.concatenate`` before); the subsets' offsets and arrays match."""
    one = hand_made()
    for n, expected in [(0, (0, 0)), (1, (1, 0)), (2, (1, 1)), (25, (23, 2))]:
        data = one.subset([0] * n)
        assert len(data) == n and data.node_ptr.tolist() == [6 * k for k in range(n + 1)]
        train, val = split_problems(data, seed=3)
        assert (len(train), len(val)) == expected
        for part in (train, val):
            assert part.states.shape == (6 * len(part), 2) and part.iter_sample.shape == (5 * len(part), 2)
            assert part.path_nodes.tolist() == [0, 2, 3, 5] * len(part)


def test_grown_labels_are_the_next_path_node_beyond_the_tree():
    rows, sizes, active, labels = hand_made().snapshots(0, "grown")
    assert rows.tolist() == list(range(6))
    # before iteration t the tree holds `size` nodes; the label is the first path node it lacks
    assert sizes.tolist() == [1, 2, 3, 4, 5] and active.tolist() == [0] * 5
    assert labels.tolist() == [2, 2, 3, 5, 5]


def test_prefix_labels_follow_the_path_over_path_only_graphs():
    rows, sizes, active, labels = hand_made().snapshots(0, "prefix")
    assert rows.tolist() == [0, 2, 3, 5]                 # the root and the path, no side branches
    assert sizes.tolist() == [1, 2, 3] and labels.tolist() == [2, 3, 5]


def test_birrt_goal_tree_walks_the_path_from_the_goal():
    # BiRRT: nodes 0 (start root, tree 0), 1 (goal root, tree 1), 2 (tree 0), 3 (tree 1); path 0 2 3 1
    data = hand_made()
    data.states = np.arange(8, dtype=np.float32).reshape(4, 2)
    data.node_features = np.zeros((4, 5), np.float32)
    data.parent = np.array([-1, -1, 0, 1], np.int32)
    data.tree_id = np.array([0, 1, 0, 1], np.int8)
    data.node_ptr, data.path_nodes, data.path_ptr = np.array([0, 4]), np.array([0, 2, 3, 1], np.int32), np.array([0, 4])
    data.iter_ptr, data.iter_nodes, data.iter_active = np.array([0, 3]), np.array([2, 3, 4], np.int32), np.array([0, 1, 0], np.int8)
    _, sizes, active, labels = data.snapshots(0, "grown")
    assert active.tolist() == [0, 1, 0]
    # tree 0 lacks node 2 first; tree 1 (walking 1 -> 3 -> 2 -> 0) lacks 3; then tree 0 holds 0, 2 and lacks 3
    assert labels.tolist() == [2, 3, 3]


def test_generated_runs_record_iterations_and_solve():
    data = generate(TreeDataConfig(task="maze2d", problems=2, max_nodes=2000), progress=False)
    assert len(data) == 2
    for p in range(len(data)):
        _, parent, _ = data.tree(p)
        i0, i1 = data.iter_ptr[p], data.iter_ptr[p + 1]
        assert data.iter_nodes[i0] == 1 and np.all(np.diff(data.iter_nodes[i0:i1]) >= 0)
        path = data.path(p)
        assert path[0] == 0 and all(parent[b] == a for a, b in zip(path[:-1], path[1:]))
        _, sizes, _, labels = data.snapshots(p, "grown")
        assert np.all(labels >= sizes)                   # RRT: the label is not in the tree yet
        created = data.iter_created[i0:i1]
        made = created >= 0
        # an iteration creates the node at the tree's size, whose parent is its sample's nearest node
        assert np.array_equal(created[made], data.iter_nodes[i0:i1][made])
        states, parent, _ = data.tree(p)
        for t in np.flatnonzero(made)[:20]:
            n, c = data.iter_nodes[i0 + t], created[t]
            x = data.iter_sample[i0 + t]
            assert np.argmin(((states[:n] - x) ** 2).sum(1)) == parent[c]


def test_arm_snapshots_cover_both_trees():
    data = generate(TreeDataConfig(task="arm", scene="train", problems=3), progress=False)
    actives = set()
    for p in range(len(data)):
        _, _, tree_id = data.tree(p)
        _, sizes, active, labels = data.snapshots(p, "grown")
        actives |= set(active.tolist())
    assert actives == {0, 1}


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


def test_worker_processes_make_the_same_dataset_file(tmp_path):
    """Dataset collection in the benchmark's worker processes assembles the problems in index order:
    the file is byte-identical to a one-process run."""
    from train.tree.data import TreeDataConfig, generate, save
    config = TreeDataConfig(task="maze2d", problems=6, max_nodes=800)
    one = save(generate(config, progress=False, workers=1), tmp_path / "one.npz")
    two = save(generate(config, progress=False, workers=2), tmp_path / "two.npz")
    assert one.read_bytes() == two.read_bytes()


def test_ray_actors_make_the_same_dataset_file(tmp_path):
    """`gnn-mp train sampler --ray`: the problems planned on Ray actors give the one-process file."""
    from train.tree.data import TreeDataConfig, generate, save
    config = TreeDataConfig(task="maze2d", problems=4, max_nodes=800)
    one = save(generate(config, progress=False, workers=1), tmp_path / "one.npz")
    on_ray = save(generate(config, progress=False, workers=2, ray="local"), tmp_path / "ray.npz")
    assert one.read_bytes() == on_ray.read_bytes()


def test_a_runs_batches_share_one_set_of_worker_processes(tmp_path, monkeypatch):
    """A :class:`~train.workers.SharedPool` makes its processes on its first batch and keeps them for the next
    (a tree sampler's data, then its DAgger rounds'); each batch's file is the one-process run's."""
    import train.workers
    from train.tree.data import TreeDataConfig, generate, save
    made = []

    class Counted(train.workers.WorkerPool):
        def __init__(self, *args, **kwargs):
            made.append(args)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(train.workers, "WorkerPool", Counted)
    configs = (TreeDataConfig(task="maze2d", problems=4, max_nodes=800),
               TreeDataConfig(task="maze2d", problems=3, max_nodes=800, first_problem=4, seed=7))
    with train.workers.SharedPool(2) as pool:
        shared = [save(generate(config, progress=False, pool=pool), tmp_path / f"shared{k}.npz")
                  for k, config in enumerate(configs)]
    assert made == [(2, [])]
    for k, (config, file) in enumerate(zip(configs, shared)):
        assert save(generate(config, progress=False), tmp_path / f"one{k}.npz").read_bytes() == file.read_bytes()


def test_train_sampler_plans_its_data_and_dagger_rounds_on_one_pool(tmp_path, monkeypatch):
    """`gnn-mp train sampler`: the initial data and each DAgger round are planned on the run's one pool
    (with --ray, Ray started once; with --workers, the processes made once), not a pool per batch."""
    import train.tree.data
    from train.tree.cli import main
    generate, pools = train.tree.data.generate, []

    def recorded(config, *args, pool=None, **kwargs):
        pools.append(pool)
        return generate(config, *args, pool=pool, **kwargs)

    monkeypatch.setattr(train.tree.data, "generate", recorded)
    main(["--task", "maze2d", "--model", "gnn", "--problems", "4", "--minutes", "0.005", "--dagger-rounds", "2",
          "--dagger-problems", "2", "--dagger-minutes", "0.005", "--eval-problems", "0", "--max-snapshots", "4",
          "--out", str(tmp_path / "run"), "--data-dir", str(tmp_path / "data"), "--no-progress"])
    assert len(pools) == 3 and pools[0] is not None and all(p is pools[0] for p in pools)


def test_train_sampler_refuses_an_unreachable_ray_address_in_one_line(capsys):
    from train.tree.cli import main
    with pytest.raises(SystemExit):
        main(["--ray", "127.0.0.1:9", "--problems", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert "cannot reach Ray at 127.0.0.1:9" in err[-1]


def _crafted(data: TreeDataset, case: str) -> TreeDataset:
    """A readable file whose contents do not fit together."""
    from dataclasses import replace
    if case == "offsets past the arrays":
        return replace(data, node_ptr=data.node_ptr + np.arange(len(data.node_ptr)) * 50)
    if case == "path node outside its tree":
        return replace(data, path_nodes=data.path_nodes + 10_000)
    if case == "parent after its child":
        parent = data.parent.copy()
        parent[1] = 5
        return replace(data, parent=parent)
    if case == "iteration creates a node past the tree":
        return replace(data, iter_created=data.iter_created + 10_000)
    if case == "third tree":
        return replace(data, tree_id=np.full_like(data.tree_id, 2))
    raise AssertionError(case)


CRAFTED = ["offsets past the arrays", "path node outside its tree", "parent after its child",
           "iteration creates a node past the tree", "third tree"]


@pytest.mark.parametrize("case", CRAFTED)
def test_a_cache_with_out_of_range_contents_is_named_and_regenerated(tmp_path, case, caplog):
    """Valid zips with contents that do not fit (offsets past the arrays, indices outside a tree)
    were accepted and ended in an IndexError (or silently wrong snapshots) later; now loading names
    the file and load_or_generate regenerates it with a one-line note."""
    from train.tree.data import check_contents
    data = hand_made()
    check_contents(data)                                     # the oracle: the hand-made tree is fine
    config = data.config
    cached = save(_crafted(data, case), tmp_path / config.file_name())
    with pytest.raises(DatasetCacheError, match=config.file_name()):
        load(cached)
    config = TreeDataConfig(task="maze2d", problems=2, max_nodes=600)
    cached = save(_crafted(generate(config, progress=False), case), tmp_path / config.file_name())
    with caplog.at_level("WARNING"):
        regenerated = load_or_generate(config, tmp_path, progress=False)
    assert [r.getMessage().count("\n") for r in caplog.records] == [0] and "regenerating" in caplog.text
    check_contents(regenerated)
    assert load(cached).node_ptr.tolist() == regenerated.node_ptr.tolist()


def test_a_dataset_worker_that_dies_is_one_line_naming_the_progress(monkeypatch):
    """A worker process (or Ray actor) killed while planning the training problems ends the
    collection with one line saying how far it got (before: a 30-line BrokenProcessPool)."""
    from tests.helpers import solve_job_dying_on_problem_one
    from train.args import UsageError
    from train.tree import data as data_module
    monkeypatch.setattr(data_module, "_solve_job", solve_job_dying_on_problem_one)
    with pytest.raises(UsageError, match=r"a worker died while planning the maze2d training problems \(\d of 4 "
                                             r"planned; no dataset was written\)"):
        generate(TreeDataConfig(task="maze2d", problems=4, max_nodes=300), progress=False, workers=2)
