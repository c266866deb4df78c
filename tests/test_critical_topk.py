"""Node-level predictions, k diverse samples, hit rate / distance metrics, fresh
evaluation seeds, and report rows that carry their model and k."""

import numpy as np
import pytest
import torch

from gnn_mp_envs.critical.dataset import CriticalProblems, DatasetConfig, cache_path, load_or_generate
from gnn_mp_envs.critical.halton import halton_graph
from gnn_mp_envs.critical.selection import first_k_diverse, sample_k_diverse, top_k_diverse

torch.set_num_threads(1)


# ----------------------------------------------------------------------------- selection


def test_top_k_keeps_no_two_within_the_separation():
    # three high scores clustered at x = 0.10 .. 0.12, a lower one far away, then a low one
    points = np.array([[0.10, 0.5], [0.11, 0.5], [0.12, 0.5], [0.60, 0.5], [0.16, 0.5]])
    scores = np.array([5.0, 4.0, 3.0, 2.0, 1.0])
    assert top_k_diverse(scores, points, 1, 0.05).tolist() == [0]
    # 1 and 2 are within 0.05 of node 0: the next picks are 3 (far) and 4 (0.06 from node 0)
    assert top_k_diverse(scores, points, 3, 0.05).tolist() == [0, 3, 4]
    assert top_k_diverse(scores, points, 10, 0.05).tolist() == [0, 3, 4]     # ran out of candidates
    assert top_k_diverse(scores, points, 3, 0.0).tolist() == [0, 1, 2]      # no separation: plain top-k
    # exactly at the separation counts as "within"
    assert top_k_diverse(np.array([2.0, 1.0]), np.array([[0.0, 0.0], [0.05, 0.0]]), 2, 0.05).tolist() == [0]
    assert top_k_diverse(scores, points, 0, 0.05).tolist() == []


def test_top_k_on_the_graph_respects_r():
    g = halton_graph()
    scores = np.random.default_rng(0).normal(size=g.num_nodes)
    idx = top_k_diverse(scores, g.nodes, 10, g.radius)
    assert len(idx) == 10 and idx[0] == np.argmax(scores)
    d = np.linalg.norm(g.nodes[idx][:, None] - g.nodes[idx][None], axis=-1)
    assert (d[~np.eye(10, dtype=bool)] > g.radius).all()


def test_sampled_nodes_are_diverse_and_reproducible():
    g = halton_graph()
    logp = np.random.default_rng(1).normal(size=g.num_nodes) * 3
    a = sample_k_diverse(logp, g.nodes, 10, g.radius, np.random.default_rng(5))
    b = sample_k_diverse(logp, g.nodes, 10, g.radius, np.random.default_rng(5))
    assert np.array_equal(a, b) and len(set(a.tolist())) == 10
    d = np.linalg.norm(g.nodes[a][:, None] - g.nodes[a][None], axis=-1)
    assert (d[~np.eye(10, dtype=bool)] > g.radius).all()
    # a distribution on one node gives that node first
    peaked = np.full(g.num_nodes, -np.inf)
    peaked[7] = 0.0
    assert sample_k_diverse(peaked, g.nodes, 3, g.radius, np.random.default_rng(0)).tolist() == [7]


def test_first_k_diverse_keeps_draw_order():
    s = np.array([[0.5, 0.5], [0.51, 0.5], [0.9, 0.9], [0.2, 0.2], [0.21, 0.2]])
    assert np.array_equal(first_k_diverse(s, 3, 0.05), s[[0, 2, 3]])
    assert np.array_equal(first_k_diverse(s, 10, 0.05), s[[0, 2, 3]])
    assert np.array_equal(first_k_diverse(s, 2, 0.0), s[:2])


# ----------------------------------------------------------------------------- metrics


def _one_problem(graph, label_nodes):
    n, e = graph.num_nodes, len(graph.edges)
    return CriticalProblems(
        walls=[np.zeros((0, 4))], blobs=[np.zeros((0, 3))], start=np.full((1, 2), 0.1), goal=np.full((1, 2), 0.9),
        node_free=np.ones((1, n), bool), edge_free=np.ones((1, e), bool),
        label_ptr=np.array([0, len(label_nodes)]), label_nodes=np.array(label_nodes), path_cost=np.ones(1),
        map_index=np.arange(1), split=np.zeros(1, np.int8))


def test_hit_rate_and_distance_on_a_hand_made_case():
    from train.critical.evaluation import distance_metrics, nearest_label_distance
    g = halton_graph()
    r = g.radius
    probs = _one_problem(g, [100, 900])
    lab = g.nodes[[100, 900]]
    near, far = lab[0] + [0.5 * r, 0.0], lab[1] + [0.0, 1.5 * r]
    d_near = nearest_label_distance(near[None], probs, g)
    assert np.allclose(d_near, 0.5 * r)
    m = distance_metrics(d_near, r)
    assert m["hit_rate"] == 1.0 and np.isclose(m["median_dist_r"], 0.5)
    assert np.isclose(m["accuracy"], 1 - (0.5 * r) ** 2 / 2)        # 1 - MSE (mean over 2 coordinates)
    assert distance_metrics(nearest_label_distance(far[None], probs, g), r)["hit_rate"] == 0.0
    # k predictions: a hit if any of them is within r; the distance is the nearest one's
    both = nearest_label_distance([np.stack([far, near])], probs, g)
    assert np.allclose(both, 0.5 * r) and distance_metrics(both, r)["hit_rate"] == 1.0
    # no predictions at all: never a hit
    assert distance_metrics(nearest_label_distance([np.zeros((0, 2))], probs, g), r)["hit_rate"] == 0.0


def test_label_cross_entropy_terms():
    from train.critical.losses import label_log_likelihood, label_mean_log_prob
    log_a = torch.log(torch.tensor([0.5, 0.3, 0.2, 0.1, 0.9]))   # two graphs: nodes 0-2 and 3-4
    label_index, owner = torch.tensor([0, 1, 4]), torch.tensor([0, 0, 1])
    assert torch.isclose(label_log_likelihood(log_a, label_index, owner, 2),
                         (torch.log(torch.tensor(0.8)) + torch.log(torch.tensor(0.9))) / 2)
    want = ((torch.log(torch.tensor(0.5)) + torch.log(torch.tensor(0.3))) / 2 + torch.log(torch.tensor(0.9))) / 2
    assert torch.isclose(label_mean_log_prob(log_a, label_index, owner, 2), want)


# ----------------------------------------------------------------------------- models


def test_heatmap_cnn_reads_the_map_at_the_nodes(monkeypatch):
    from agents.critical.models import CriticalCNN
    g = halton_graph()
    model = CriticalCNN(readout="heatmap").eval()
    heat = torch.zeros(1, 64, 64)
    heat[0, 40, 10] = 50.0                       # row = y, column = x: the pixel centred at (10.5, 40.5) / 64
    monkeypatch.setattr(model, "heatmap", lambda image: heat.expand(image.shape[0], -1, -1))
    pos = torch.from_numpy(g.nodes).float()
    with torch.no_grad():
        out, log_a = model(torch.zeros(2, 3, 64, 64), pos, return_log_attention=True)
    assert log_a.shape == (2 * g.num_nodes,) and torch.allclose(log_a.view(2, -1).exp().sum(1), torch.ones(2))
    top = int(log_a[:g.num_nodes].argmax())
    assert np.linalg.norm(g.nodes[top] - np.array([10.5, 40.5]) / 64) < 1.5 / 64
    assert out.shape == (2, 2)
    assert torch.allclose(model.node_log_scores(torch.zeros(1, 3, 64, 64), pos), log_a[:g.num_nodes])
    with pytest.raises(ValueError):
        CriticalCNN().node_log_scores(torch.zeros(1, 3, 64, 64), pos)      # the point readout has none


def test_graph_models_node_distributions_normalise_per_graph():
    from agents.critical.models import CriticalGNN, CriticalGNNCVAE
    torch.manual_seed(0)
    g = halton_graph(150)
    n = g.num_nodes
    x = torch.rand(2 * n, 7)
    e = torch.from_numpy(np.concatenate([g.edges, g.edges[:, ::-1]]).T.copy())
    ei = torch.cat([e, e + n], 1)
    batch = torch.arange(2).repeat_interleave(n)
    pos = torch.from_numpy(np.concatenate([g.nodes, g.nodes])).float()
    with torch.no_grad():
        gnn = CriticalGNN(7, 8, 2, readout="attention").eval()
        ls = gnn.node_log_scores(x, ei, batch, pos)
        assert torch.allclose(torch.zeros(2).index_add(0, batch, ls.exp()), torch.ones(2), atol=1e-5)
        cvae = CriticalGNNCVAE(7, 8, 2, readout="attention").eval()
        smp, mix = cvae.sample_with_node_scores(x, ei, batch, 5, torch.Generator().manual_seed(0), pos)
        assert smp.shape == (2, 5, 2) and mix.shape == (2 * n,)
        assert torch.allclose(torch.zeros(2).index_add(0, batch, mix.exp()), torch.ones(2), atol=1e-5)
        # the same latents decode the same samples as sample()
        assert torch.allclose(cvae.sample(x, ei, batch, 5, torch.Generator().manual_seed(0), pos), smp, atol=1e-6)
    with pytest.raises(ValueError):
        CriticalGNN(7, 8, 2).node_log_scores(x, ei, batch, pos)


# ----------------------------------------------------------------------------- fresh evaluation problems


TINY = DatasetConfig(seed=5, num_maps=2, pairs_per_map=1, eval_problems=3)


def test_eval_seed_draws_different_but_reproducible_problems(tmp_path):
    default = load_or_generate(TINY, tmp_path / "a", "test", progress=False)
    one = load_or_generate(TINY, tmp_path / "a", "test", progress=False, eval_seed=1)
    assert cache_path(TINY, tmp_path / "a", "test", 1).name == "eval_test_seed1.npz"
    assert (tmp_path / "a" / "eval_test.npz").exists() and (tmp_path / "a" / "eval_test_seed1.npz").exists()
    again = load_or_generate(TINY, tmp_path / "b", "test", progress=False, eval_seed=1)   # fresh directory
    assert np.array_equal(one.start, again.start) and np.array_equal(one.label_nodes, again.label_nodes)
    assert (tmp_path / "a" / "eval_test_seed1.npz").read_bytes() == (tmp_path / "b" / "eval_test_seed1.npz").read_bytes()
    two = load_or_generate(TINY, tmp_path / "a", "test", progress=False, eval_seed=2)
    for other in (default, two):
        assert not np.array_equal(one.start, other.start)
    # the data seed itself (or no seed) is the default set
    same = load_or_generate(TINY, tmp_path / "a", "test", progress=False, eval_seed=TINY.seed)
    assert np.array_equal(same.start, default.start)
    assert cache_path(TINY, tmp_path, "test", TINY.seed).name == "eval_test.npz"
    blob = load_or_generate(TINY, tmp_path / "a", "blob", progress=False, eval_seed=1)
    assert all(len(b) == TINY.num_blobs for b in blob.blobs) and blob.config.seed == 1


def test_evaluate_rows_carry_model_and_k(tmp_path):
    """Point and k rows for every model, k uniform random points, oracle, sparse, dense; two
    checkpoint directories give mean ± std; --eval-seed reaches the data."""
    from train.critical import evaluate, format_table
    from train.critical.args import CHECKPOINT_DIR
    rep = evaluate(models=["gnn", "cvae"], checkpoint_dir=[CHECKPOINT_DIR, CHECKPOINT_DIR], data_dir=tmp_path,
                   num_problems=2, num_samples=4, dataset=TINY, progress=False, eval_seed=7, ks=(1, 3))
    assert rep["settings"]["eval_seed"] == 7 and (tmp_path / "eval_blob_seed7.npz").exists()
    for key in ("test", "blob"):
        plan = {n: r for n, r in rep["planning"][key].items() if not n.startswith("_")}
        acc = rep["accuracy"][key]
        for rows in (plan, acc):
            assert all("model" in r and "k" in r for r in rows.values())
        want = {"sparse", "dense", "oracle (labels)", "uniform random k=1", "uniform random k=3"}
        want |= {f"{m} {s}" for m in ("gnn", "cvae") for s in ("point", "k=1", "k=3")}
        assert set(plan) == want
        assert (plan["gnn k=3"]["model"], plan["gnn k=3"]["k"]) == ("gnn", 3)
        assert plan["gnn k=3"]["points"] == 3 and plan["cvae k=1"]["points"] == 1
        assert plan["gnn k=3"]["seeds"] == 2 and plan["gnn k=3"]["success_rate_std"] == 0.0
        assert len(plan["gnn k=3"]["values"]["success_rate"]) == 2
        assert {"accuracy", "hit_rate", "median_dist_r"} <= set(acc["gnn k=3"])
        assert plan["dense"]["success_rate"] == 1.0
    assert "hit k=3" in format_table(rep) and "±" in format_table(rep)
