"""The GNN sample scorer: incremental numpy inference equals the torch model, labels are right,
a briefly trained scorer plans through the registry, save/load keeps its proposals."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from agents.checkpoints import save_checkpoint
from agents.tree.scorer import TreeGNNScorer, frontier_edges, tree_depth
from agents.samplers import load_sampler
from agents.tree.engine import IncrementalTreeScorer
from agents.tree.samplers import TreeScorerSampler
from gnn_mp_envs.registration import task_spec
from train.tree.adapters import adapter_for, task_scales
from train.tree.data import TreeDataConfig, TreeDataset, generate
from train.tree.items import make_scorer_run, sample_labels

LOW, HIGH = task_spec("pendulum").state_bounds()     # the action box (float32), as load_sampler takes it


@pytest.fixture(scope="module")
def adapter_and_space():
    return adapter_for("gnn", "pendulum"), task_scales("pendulum")


def random_scorer(adapter_and_space, seed: int = 0) -> TreeGNNScorer:
    adapter, scales = adapter_and_space
    torch.manual_seed(seed)
    model, _ = adapter.build(scales, hidden_channels=32)
    with torch.no_grad():   # larger weights than the initialisation: logits that differ visibly
        for p in model.parameters():
            if p.dim() == 2:
                p.mul_(2.0)
    return model.eval()


@pytest.fixture(scope="module")
def grown_obs():
    """A pendulum tree of ~400 nodes from uniform samples, states jittered (no k-NN ties)."""
    env = gym.make("GNNMP/PendulumRRT-v0", split="val", disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    rng = np.random.default_rng(0)
    while int(obs["num_nodes"][0]) < 400:
        obs, _, terminated, truncated, _ = env.step(rng.uniform(LOW, HIGH).astype(np.float32))
        assert not truncated
        if terminated:
            break
    env.close()
    obs = {k: np.array(v) for k, v in obs.items()}
    n = int(obs["num_nodes"][0])
    obs["nodes"][1:n] += rng.normal(0.0, 1e-3, (n - 1, 2)).astype(np.float32)
    return obs


def reference_logits(model: TreeGNNScorer, obs: dict, samples: np.ndarray) -> torch.Tensor:
    """The torch model's scores of candidate ``samples`` at one padded observation."""
    n = int(obs["num_nodes"][0])
    nodes = torch.as_tensor(obs["nodes"][:n])
    feats = torch.as_tensor(obs["node_features"][:n])
    parent = torch.as_tensor(obs["parent"][:n]).long()
    s = torch.as_tensor(samples, dtype=torch.float32)
    with torch.no_grad():
        knn = model.causal_knn(nodes, feats[:, 2 * model.state_dim].long())
        near = model.nearest(s, nodes)
        return model(nodes, feats, parent, knn, torch.as_tensor(obs["goal"]), near, torch.full_like(near, n), s)


def prefix(obs: dict, n: int) -> dict:
    out = {k: np.array(v) for k, v in obs.items()}
    out["nodes"][n:], out["node_features"][n:], out["parent"][n:], out["num_nodes"][0] = 0, 0, -1, n
    return out


def test_tree_depth_and_frontier_edges_on_a_small_tree():
    parent = torch.tensor([-1, 0, 0, 1, 3])
    assert tree_depth(parent).tolist() == [0, 1, 1, 2, 3]
    knn = torch.tensor([[-1], [0], [1], [2], [2]])     # node 4's nearest earlier node is 2
    # node 2 at tree size 4 hears node 3 (k-NN); at size 5 also node 4 (k-NN); node 0 hears 1, 2 (children), 1 (k-NN)
    edge_index, etype = frontier_edges(parent, knn, torch.tensor([2, 2, 0]), torch.tensor([4, 5, 3]))
    got = sorted(zip(edge_index[1].tolist(), edge_index[0].tolist(), etype.tolist()))
    assert got == [(0, 3, 1), (1, 3, 1), (1, 4, 1), (2, 1, 0), (2, 1, 1), (2, 2, 0)]


def test_incremental_engine_equals_the_torch_model(adapter_and_space, grown_obs):
    model = random_scorer(adapter_and_space)
    engine = IncrementalTreeScorer(model, capacity=64)           # grows on the way
    n_final = int(grown_obs["num_nodes"][0])
    rng = np.random.default_rng(1)
    sizes = [1, 2, 3, 10, 11, 57, 200, n_final]                  # batches of 1 and of many rows
    for n in sizes:
        obs = prefix(grown_obs, n)
        engine.ingest(obs)
        cands = rng.uniform(LOW, HIGH, (24, 2))
        ours = engine.logits(cands, engine.nearest(cands))
        ref = reference_logits(model, obs, cands).double().numpy()
        np.testing.assert_allclose(ours, ref, atol=2e-5, rtol=1e-4)
        # the compiled head (what the sampler runs) is the numpy head up to the last bits of erf and BLAS
        np.testing.assert_allclose(engine.candidate_logits(cands), ours, atol=1e-12, rtol=1e-12)
    assert np.std(ours) > 1e-2
    # every node's frontier (sum, counts) equals the torch layer at the final tree
    nodes = torch.as_tensor(grown_obs["nodes"][:n_final])
    parent = torch.as_tensor(grown_obs["parent"][:n_final]).long()
    knn = model.causal_knn(nodes, torch.zeros(n_final, dtype=torch.long))
    with torch.no_grad():
        h = model.embed(nodes, torch.as_tensor(grown_obs["node_features"][:n_final]), parent, knn,
                        torch.as_tensor(grown_obs["goal"]))
        q = torch.arange(n_final)
        edge_index, etype = frontier_edges(parent, knn, q, torch.full_like(q, n_final))
        rel = model.relative(nodes[edge_index[0]], nodes[edge_index[1]])
        front = model.frontier(h, rel, etype, edge_index, n_final)
    np.testing.assert_allclose(engine.h[model.num_layers, :n_final], h.numpy(), atol=2e-5)
    np.testing.assert_allclose(engine.front[:n_final], front.numpy(), atol=1e-4)
    assert engine.front[:n_final, -2:].sum() == len(etype)     # one count per causal edge


def hand_made() -> TreeDataset:
    """One RRT tree of 5 nodes, path 0 -> 2 -> 4; six iterations, one blocked (created -1)."""
    states = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0, 2]], dtype=np.float32)
    parent = np.array([-1, 0, 0, 1, 2], dtype=np.int32)
    sizes = np.array([1, 2, 2, 3, 4, 4], np.int32)            # tree size before each iteration
    created = np.array([1, -1, 2, 3, -1, 4], np.int32)
    samples = np.array([[2, 0], [0.9, 0.2], [0, 1.5], [2, 1], [1.2, 0.8], [0, 3]], np.float32)
    return TreeDataset(
        config=TreeDataConfig(task="pendulum", problems=1), node_ptr=np.array([0, 5]), states=states,
        node_features=np.zeros((5, 5), np.float32), parent=parent, tree_id=np.zeros(5, np.int8),
        path_ptr=np.array([0, 3]), path_nodes=np.array([0, 2, 4], np.int32), start=states[:1], goal=states[4:5],
        obstacles=np.zeros((1, 1, 1), np.float32), problem_index=np.array([0]), iter_ptr=np.array([0, 6]),
        iter_nodes=sizes, iter_active=np.zeros(6, np.int8), iter_sample=samples, iter_created=created)


def test_compiled_candidate_head_reads_only_the_active_tree(adapter_and_space, grown_obs):
    """With two trees in the caches, each candidate is scored at its nearest node of the active tree:
    the compiled head equals the numpy head with the numpy nearest (brute force over that tree)."""
    engine = IncrementalTreeScorer(random_scorer(adapter_and_space), capacity=64)
    engine.ingest(grown_obs)
    n = engine.n
    engine.tree_id[:n] = np.arange(n) % 2             # every other node in tree 1
    engine.multi_tree = True
    cands = np.random.default_rng(4).uniform(LOW, HIGH, (32, 2))
    for active in (0, 1):
        near = engine.nearest(cands, active)
        assert (engine.tree_id[near] == active).all()
        np.testing.assert_allclose(engine.candidate_logits(cands, active), engine.logits(cands, near),
                                   atol=1e-12, rtol=1e-12)
    assert not np.allclose(engine.candidate_logits(cands, 0), engine.candidate_logits(cands, 1))


def test_labels_mark_the_samples_that_created_path_nodes(adapter_and_space):
    data = hand_made()
    assert sample_labels(data, 0).tolist() == [False, False, True, False, False, True]
    run = make_scorer_run(data, 0, random_scorer(adapter_and_space), negatives=10, rng=np.random.default_rng(0))
    # positives first (iterations 2, 5), then every other iteration as a negative (in order)
    assert run.labels.tolist() == [1, 1, 0, 0, 0, 0]
    assert run.sizes.tolist() == [2, 4, 1, 2, 3, 4]
    # nearest node: the created node's parent; blocked samples: planner metric (omega weighted 0.4)
    # among the nodes of that iteration's tree ([0.9, 0.2] at size 2 -> node 1; [1.2, 0.8] at size 4 -> node 3)
    assert run.near.tolist() == [0, 2, 0, 1, 1, 3]
    assert len(run.nodes) == 4 and run.samples[0].tolist() == [0, 1.5]
    few = make_scorer_run(data, 0, random_scorer(adapter_and_space), negatives=2, rng=np.random.default_rng(0))
    assert few.labels.tolist() == [1, 1, 0, 0]


@pytest.fixture(scope="module")
def trained_checkpoint(adapter_and_space, tmp_path_factory):
    """A scorer trained a few steps on three uniform pendulum solutions, saved as a checkpoint."""
    adapter, scales = adapter_and_space
    data = generate(TreeDataConfig(task="pendulum", problems=3, max_nodes=1500, first_problem=5), progress=False)
    torch.manual_seed(0)
    model, ctor_args = adapter.build(scales, hidden_channels=16, num_layers=1)
    items = adapter.items(model, data, "grown", np.random.default_rng(0), 32)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    first = None
    for _ in range(15):
        loss, count, _ = adapter.loss(model, items)
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert count == sum(len(r.labels) for r in items) and loss.item() < first
    settings = task_spec("pendulum").sampler_defaults("gnn")
    path = save_checkpoint(tmp_path_factory.mktemp("scorer") / "model.pt", model, adapter.kind, ctor_args,
                           meta={"task": "pendulum", "sampler": settings})
    return path, model.eval()


def test_trained_scorer_plans_through_the_registry(trained_checkpoint):
    path, _ = trained_checkpoint
    env = gym.make("GNNMP/PendulumRRT-v0", split="val", copy_observations=False, disable_env_checker=True,
                   max_nodes=3000)
    sampler = load_sampler("gnn", task="pendulum", checkpoint=str(path))
    assert isinstance(sampler, TreeScorerSampler)
    assert (sampler.uniform_mix, sampler.goal_bias, sampler.candidates) == (0.2, 0.05, 16)
    sampler.reset(3)
    obs, _ = env.reset(seed=3, options={"index": 1})
    for _ in range(3000):
        action = sampler.act(obs)
        assert action.dtype == np.float32 and env.action_space.contains(action)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    assert 100 < sampler.engine.n <= int(obs["num_nodes"][0])     # the engine read the tree as it grew
    env.close()
    with pytest.raises(ValueError, match="takes"):
        load_sampler("gnn", task="pendulum", checkpoint=str(path), sigma_scale=1.0)


def test_save_load_gives_identical_proposals(trained_checkpoint, grown_obs):
    path, model = trained_checkpoint
    direct = TreeScorerSampler(LOW, HIGH, model=model, uniform_mix=0.2, goal_bias=0.05, candidates=16)
    loaded = [load_sampler("gnn", task="pendulum", checkpoint=str(path)) for _ in range(2)]
    runs = []
    for sampler in [direct] + loaded:
        sampler.reset(11)
        runs.append(np.stack([sampler.act(prefix(grown_obs, n)) for n in range(20, 220, 5)]))
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[1], runs[2])
    assert len(np.unique(runs[0], axis=0)) > 30


def test_shipped_pendulum_gnn_is_the_scorer():
    sampler = load_sampler("gnn", task="pendulum", seed=0)
    assert isinstance(sampler, TreeScorerSampler)
    assert (sampler.uniform_mix, sampler.goal_bias, sampler.candidates, sampler.temperature) == (0.2, 0.05, 16, 1.0)
