"""Halton graph, bottleneck ground truth and dataset determinism (numpy side)."""

import hashlib

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from gnn_mp_envs.critical.bottleneck import bottleneck_nodes, problem_graph, shortest_path
from gnn_mp_envs.critical.dataset import (DatasetConfig, generate_all, load_problems)
from gnn_mp_envs.critical.halton import halton_graph, halton_points, is_connected
from gnn_mp_envs.tasks.maze2d import MazeMap


@pytest.mark.parametrize("n", [200, 2000])
def test_halton_graph_connected_and_deterministic(n):
    g1, g2 = halton_graph(n), halton_graph(n)
    assert np.array_equal(g1.nodes, g2.nodes) and np.array_equal(g1.edges, g2.edges)
    assert g1.nodes.shape == (n, 2) and (g1.nodes > 0).all() and (g1.nodes < 1).all()
    assert is_connected(n, g1.edges)
    assert (g1.edge_lengths() <= g1.radius + 1e-12).all()
    assert (g1.edges[:, 0] < g1.edges[:, 1]).all()


def test_halton_points_match_radical_inverse():
    pts = halton_points(4, 2)
    assert np.allclose(pts, [[0.5, 1 / 3], [0.25, 2 / 3], [0.75, 1 / 9], [0.125, 4 / 9]])


@pytest.mark.parametrize("n, d, digest", [(2000, 2, "f542b44dcdc551d7"), (200, 2, "79b69112c2e8e823"),
                                          (50, 7, "1c3d732c413f015c")])
def test_halton_points_are_the_hand_written_sequences_bit_for_bit(n, d, digest):
    """scipy's qmc.Halton replaced a hand-written radical inverse; the digests are of the old
    function's output, so every graph, dataset cache and shipped critical model still fits."""
    assert hashlib.sha256(halton_points(n, d).tobytes()).hexdigest()[:16] == digest


def test_too_small_radius_is_refused():
    with pytest.raises(ValueError):
        halton_graph(200, radius=0.01)


# Single wall at x in [0.47, 0.53] with one gap y in [0.45, 0.50].
GAP = np.array([0.47, 0.45, 0.53, 0.50])
SINGLE_GAP = MazeMap([[0.47, 0.0, 0.53, 0.45], [0.47, 0.50, 0.53, 1.0]])


def _dist_to_box(p, box):
    d = np.maximum(np.maximum(box[:2] - p, 0), p - box[2:])
    return float(np.linalg.norm(d))


@pytest.mark.parametrize("start,goal", [((0.1, 0.2), (0.9, 0.8)), ((0.1, 0.5), (0.9, 0.5)),
                                        ((0.2, 0.9), (0.8, 0.1))])
def test_bottleneck_lies_in_the_gap(start, goal):
    g = halton_graph()
    res = bottleneck_nodes(problem_graph(g, SINGLE_GAP, np.array(start), np.array(goal)))
    assert len(res.labels) >= 1
    for v in res.labels:  # in the passage or at its mouth (within one edge of it)
        assert _dist_to_box(g.nodes[v], GAP) <= g.radius


def test_bottleneck_is_the_costliest_deletion_brute_force():
    """Delete each path node by rebuilding the graph without it; the label is the argmax."""
    g = halton_graph(150)
    maze = MazeMap([[0.45, 0.0, 0.55, 0.3], [0.45, 0.42, 0.55, 1.0]])
    start, goal = np.array([0.1, 0.8]), np.array([0.9, 0.8])
    pg = problem_graph(g, maze, start, goal)
    res = bottleneck_nodes(pg)
    m = pg.matrix.tocsr()
    increases = {}
    for v in res.path[1:-1]:
        keep = np.array([i for i in range(m.shape[0]) if i != v])
        sub = m[keep][:, keep]
        s, t = int(np.flatnonzero(keep == pg.start_index)[0]), int(np.flatnonzero(keep == pg.goal_index)[0])
        increases[v] = dijkstra(sub, directed=False, indices=s)[t] - res.cost
    best = max(increases.values())
    assert best > 0
    expected = sorted(v for v, inc in increases.items() if inc >= best - 1e-9)
    assert sorted(res.labels.tolist()) == expected
    assert np.allclose([increases[v] for v in res.candidates], res.increase)


def test_disconnecting_node_is_a_label():
    """A gap only one node wide: deleting it disconnects start from goal."""
    g = halton_graph(2000)
    gap_node = int(np.argmin(np.linalg.norm(g.nodes - [0.5, 0.5], axis=1)))
    x, y = g.nodes[gap_node]
    maze = MazeMap([[x - 0.003, 0.0, x + 0.003, y - 0.004], [x - 0.003, y + 0.004, x + 0.003, 1.0]])
    if not maze.is_free(g.nodes[gap_node][None])[0]:
        pytest.skip("gap node landed in the wall")
    pg = problem_graph(g, maze, np.array([0.2, 0.5]), np.array([0.8, 0.5]))
    cost, path = shortest_path(pg.matrix, pg.start_index, pg.goal_index)
    if not path:
        pytest.skip("no edge threads the one-node gap")
    res = bottleneck_nodes(pg)
    assert np.isinf(res.increase).any()
    assert set(res.labels.tolist()) == set(res.candidates[np.isinf(res.increase)].tolist())


TINY = DatasetConfig(seed=3, num_maps=2, pairs_per_map=2, eval_problems=2)


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_dataset_is_deterministic_and_round_trips(tmp_path):
    a = generate_all(TINY, tmp_path / "a", progress=False)
    b = generate_all(TINY, tmp_path / "b", progress=False)
    for key in a:
        assert _digest(a[key]) == _digest(b[key]), key
    lab = load_problems(a["labelled"])
    assert lab.config == TINY and len(lab) == 4
    assert np.diff(lab.label_ptr).min() >= 1
    blob = load_problems(a["blob"])
    assert all(len(bl) == TINY.num_blobs for bl in blob.blobs)
    # labels are free nodes of the dense graph
    g = halton_graph()
    for i in range(len(lab)):
        assert lab.maze(i).is_free(g.nodes[lab.labels_of(i)]).all()
    other = generate_all(DatasetConfig(seed=4, num_maps=2, pairs_per_map=2, eval_problems=2),
                         tmp_path / "c", progress=False)
    assert _digest(other["labelled"]) != _digest(a["labelled"])


def _truncate(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _empty(path):
    path.write_bytes(b"")


def _break_crc(path):
    """Flip bytes inside a compressed member: the zip directory stays valid, the CRC does not."""
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 16] = bytes(b ^ 0xFF for b in data[mid:mid + 16])
    path.write_bytes(bytes(data))


def _rewritten(path, **changes):
    """A valid zip of the format whose contents do not fit (an IndexError later)."""
    from dataclasses import replace

    from gnn_mp_envs.critical.dataset import save_problems
    save_problems(replace(load_problems(path), **changes), path)


def _label_outside_graph(path):
    problems = load_problems(path)
    _rewritten(path, label_nodes=problems.label_nodes + problems.config.graph_nodes)


def _offsets_past_labels(path):
    problems = load_problems(path)
    _rewritten(path, label_ptr=problems.label_ptr * 3)


def _another_graphs_edges(path):
    problems = load_problems(path)
    _rewritten(path, edge_free=problems.edge_free[:, :-7])


@pytest.mark.parametrize("corrupt", [_truncate, _empty, _break_crc, _label_outside_graph, _offsets_past_labels,
                                     _another_graphs_edges],
                         ids=["truncated", "empty", "crc", "label-outside-graph", "offsets-past-labels",
                              "another-graphs-edges"])
def test_damaged_cache_is_regenerated_with_a_one_line_warning(tmp_path, corrupt, caplog):
    """No BadZipFile / EOFError / TypeError traceback; byte-identical regeneration."""
    from gnn_mp_envs.critical.dataset import DatasetCacheError, load_or_generate
    fresh = generate_all(TINY, tmp_path / "fresh", progress=False)
    cache = generate_all(TINY, tmp_path / "cache", progress=False)
    for key in ("labelled", "blob"):
        path = cache[key]
        corrupt(path)
        with pytest.raises(DatasetCacheError) as info:
            load_problems(path)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
        caplog.clear()
        with caplog.at_level("WARNING", logger="gnn_mp_envs.critical.dataset"):
            problems = load_or_generate(TINY, cache[key].parent, key, progress=False)
        warnings = [r.getMessage() for r in caplog.records]
        assert len(warnings) == 1 and str(path) in warnings[0] and "\n" not in warnings[0]
        assert "regenerat" in warnings[0]
        assert _digest(path) == _digest(fresh[key])
        assert len(problems) == len(load_problems(fresh[key]))
    corrupt(cache["test"])                                  # generate_all repairs too
    with caplog.at_level("WARNING", logger="gnn_mp_envs.critical.dataset"):
        generate_all(TINY, tmp_path / "cache", progress=False)
    assert _digest(cache["test"]) == _digest(fresh["test"])


def test_cache_writers_use_unique_temporary_names(tmp_path):
    """Two writers of one cache never share a temporary file (the old code used <name>.tmp)."""
    import threading
    from gnn_mp_envs.critical.dataset import generate_eval, save_problems
    problems = generate_eval(TINY, "test", progress=False)
    path = tmp_path / "eval_test.npz"
    path.with_suffix(".tmp").mkdir()                        # a fixed temp name is taken: must not matter
    save_problems(problems, path)
    reference = path.read_bytes()
    errors = []

    def writer():
        try:
            for _ in range(10):
                save_problems(problems, path)
        except Exception as exc:   # noqa: BLE001 - collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=writer) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and path.read_bytes() == reference
    assert sorted(p.name for p in tmp_path.iterdir()) == ["eval_test.npz", "eval_test.tmp"]
