"""The policy interface: vectorised to_pyg, k-NN edges, TreeEncoder, the ModelSampler hook, SB3 and TorchRL."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch_geometric.data import Batch, Data

from agents.nn.encoders import CONVS, TreeEncoder
from agents.rl.backbones import EncoderModule
from agents.nn.graph import knn_edge_index, to_pyg
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS, observation_space

MAZE_SPACE = observation_space(np.zeros(2), np.ones(2), 60)
ARM_SPACE = observation_space(np.full(6, -np.pi), np.full(6, np.pi), 60)   # xArm6-shaped: 6-D, 13 features


def random_tree_obs(space, sizes, rng, bidirectional=True):
    """Valid padded observations (one per entry of ``sizes``) stacked along a leading axis.

    ``sizes[i]`` real nodes; ``None`` gives an all-zero element (what a TorchRL reset may hold),
    a negative size -n gives n real nodes whose ``num_nodes`` entry is zeroed (mask only).
    """
    d = space["nodes"].shape[1]
    low, high = space["start"].low, space["start"].high
    elements = []
    for size in sizes:
        o = {k: np.zeros(space[k].shape, space[k].dtype) for k in OBSERVATION_KEYS}
        o["parent"][:] = -1
        if size is not None:
            n = abs(size)
            o["start"][:] = rng.uniform(low, high)
            o["goal"][:] = rng.uniform(low, high)
            x = rng.uniform(low, high, (n, d)).astype(np.float32)
            x[0] = o["start"]
            tree = np.zeros(n, np.float32)
            if bidirectional and n > 2:            # second root: the goal tree
                x[1] = o["goal"]
                tree[1:] = rng.integers(0, 2, n - 1)
                tree[1] = 1
            for i in range(1, n):
                if bidirectional and i == 1 and n > 2:
                    continue
                same = [j for j in range(i) if tree[j] == tree[i]]
                o["parent"][i] = rng.choice(same) if same else -1
            o["nodes"][:n] = x
            o["node_features"][:n] = np.concatenate([o["start"] - x, o["goal"] - x, tree[:, None]], 1)
            o["mask"][:n] = 1
            o["num_nodes"][0] = 0 if size < 0 else n
            o["active_tree"][0] = int(rng.integers(0, 2))
            assert space.contains(o)
        elements.append(o)
    return {k: np.stack([e[k] for e in elements]) for k in OBSERVATION_KEYS}


def reference_batch(obs):
    """Batch.from_data_list of per-graph Data built with plain Python loops."""
    B = obs["start"].shape[0]
    graphs = []
    for b in range(B):
        n = int(obs["num_nodes"][b][0]) or int(obs["mask"][b].sum())
        edges = []
        for c in range(n):
            p = int(obs["parent"][b][c])
            if 0 <= p < n:
                edges += [(p, c), (c, p)]
        graphs.append(Data(x=torch.as_tensor(obs["node_features"][b][:n]), pos=torch.as_tensor(obs["nodes"][b][:n]),
                           edge_index=torch.tensor(edges, dtype=torch.long).reshape(-1, 2).T,
                           start=torch.as_tensor(obs["start"][b]).reshape(1, -1),
                           goal=torch.as_tensor(obs["goal"][b]).reshape(1, -1),
                           active_tree=torch.as_tensor(obs["active_tree"][b]).reshape(1), num_nodes=n))
    return Batch.from_data_list(graphs)


GRAPH_ATTRS = ("x", "pos", "edge_index", "batch", "ptr", "start", "goal", "active_tree")


def assert_same_batch(got, want):
    assert got.num_graphs == want.num_graphs and got.num_nodes == want.num_nodes
    for key in GRAPH_ATTRS:
        assert torch.equal(got[key], want[key]), key
    for i in range(want.num_graphs):
        a, b = got.get_example(i), want.get_example(i)
        assert a.num_nodes == b.num_nodes
        for key in ("x", "pos", "edge_index", "start", "goal", "active_tree"):
            assert torch.equal(a[key], b[key]), (i, key)


# ---------------------------------------------------------------------------- to_pyg
SIZES = [1, 7, 60, 2, None, 33, -12, 59, 3]


@pytest.mark.parametrize("space", [MAZE_SPACE, ARM_SPACE], ids=["maze2d", "arm"])
@pytest.mark.parametrize("form", ["numpy", "torch", "tensordict", "float"])
def test_to_pyg_equals_per_graph_reference(space, form):
    rng = np.random.default_rng(0)
    obs = random_tree_obs(space, SIZES, rng)
    want = reference_batch(obs)
    if form == "numpy":
        inp = obs
    elif form == "torch":
        inp = {k: torch.as_tensor(v) for k, v in obs.items()}
    elif form == "tensordict":
        inp = TensorDict({k: torch.as_tensor(v) for k, v in obs.items()}, batch_size=[len(SIZES)])
    else:                                   # SB3 casts every Box (parent, num_nodes, mask, ...) to float
        inp = {k: torch.as_tensor(v).float() for k, v in obs.items()}
    before = {k: np.array(v) for k, v in obs.items()}
    assert_same_batch(to_pyg(inp), want)
    for k in obs:                           # the input is left untouched
        np.testing.assert_array_equal(obs[k], before[k])


def test_to_pyg_two_leading_batch_dims_and_unbatched():
    rng = np.random.default_rng(1)
    obs = random_tree_obs(MAZE_SPACE, [5, 60, 1, 17, 40, 2], rng)
    want = reference_batch(obs)
    grid = {k: v.reshape(2, 3, *v.shape[1:]) for k, v in obs.items()}   # graphs numbered row-major
    got = to_pyg(grid)
    assert got.start.shape == (6, 2) and got.active_tree.shape == (6,)
    assert_same_batch(got, want)
    one = to_pyg({k: v[1] for k, v in obs.items()})
    assert isinstance(one, Data) and not isinstance(one, Batch)
    ref = want.get_example(1)
    for key in ("x", "pos", "edge_index", "start", "goal", "active_tree"):
        assert torch.equal(one[key], ref[key]), key
    assert one.num_nodes == 60


def test_to_pyg_edges_are_the_tree_edges_of_a_real_env():
    env = gym.make("GNNMP/Maze2DBiRRT-v0", max_nodes=300)
    rng = np.random.default_rng(0)
    obs_list = []
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        for _ in range(20 * (seed + 1)):
            obs, *_ = env.step(rng.uniform(0, 1, 2).astype(np.float32))
        obs_list.append(obs)
    batch = to_pyg({k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]})
    for b, obs in enumerate(obs_list):
        n = int(obs["num_nodes"][0])
        g = batch.get_example(b)
        edges = set(map(tuple, g.edge_index.T.tolist()))
        want = {(int(obs["parent"][c]), c) for c in range(n) if obs["parent"][c] >= 0}
        assert edges == want | {(c, p) for p, c in want}
        np.testing.assert_array_equal(g.pos.numpy(), obs["nodes"][:n])


# ---------------------------------------------------------------------------- k-NN edges
def brute_force_knn(pos, sizes, k, loop):
    out, offset = set(), 0
    for n in sizes:
        p = pos[offset:offset + n].double()
        dist = torch.cdist(p, p)
        if not loop:
            dist.fill_diagonal_(float("inf"))
        kk = min(k, n if loop else n - 1)
        for i in range(n):
            for j in dist[i].argsort()[:kk].tolist():
                out.add((offset + j, offset + i))
        offset += n
    return out


@pytest.mark.parametrize("loop", [False, True])
def test_knn_edge_index_matches_brute_force_per_graph(loop):
    torch.manual_seed(0)
    sizes = [1, 4, 30, 9, 70]
    pos = torch.rand(sum(sizes), 3)
    batch = torch.repeat_interleave(torch.arange(len(sizes)), torch.tensor(sizes))
    want = brute_force_knn(pos, sizes, 6, loop)
    for max_block in (1 << 22, 500, 1):     # one block; several graphs/rows per block; one row at a time
        edges = knn_edge_index(pos, batch, k=6, loop=loop, max_block=max_block)
        assert edges.shape[0] == 2 and edges.shape[1] == len(want)
        assert set(map(tuple, edges.T.tolist())) == want
        assert torch.equal(batch[edges[0]], batch[edges[1]])     # never across graphs
    assert knn_edge_index(pos[:1], None, k=3).shape == (2, 0)


# ---------------------------------------------------------------------------- the encoder
def as_tensors(obs):
    return {k: torch.as_tensor(v) for k, v in obs.items()}


@pytest.mark.parametrize("space", [MAZE_SPACE, ARM_SPACE], ids=["maze2d", "arm"])
def test_encoder_from_space_any_state_dim_and_batch_shape(space):
    d = space["start"].shape[0]
    enc = TreeEncoder.from_space(space, hidden_channels=16, num_layers=2, out_channels=24)
    assert enc.in_channels == 2 * d + 1 and enc.state_dim == d
    obs = random_tree_obs(space, [5, 60, 12, 1], np.random.default_rng(0))
    nodes, embed, batch = enc(as_tensors(obs))
    assert nodes.shape == (78, 16) and embed.shape == (4, 24) and batch.shape == (78,)
    assert torch.equal(batch, torch.repeat_interleave(torch.arange(4), torch.tensor([5, 60, 12, 1])))
    _, grid, _ = enc({k: v.reshape(2, 2, *v.shape[1:]) for k, v in as_tensors(obs).items()})
    assert grid.shape == (2, 2, 24)
    torch.testing.assert_close(grid.reshape(4, 24), embed)
    one_nodes, one, one_batch = enc({k: v[1] for k, v in as_tensors(obs).items()})
    assert one.shape == (24,) and one_nodes.shape == (60, 16) and torch.all(one_batch == 0)
    torch.testing.assert_close(one, embed[1], rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("conv", sorted(CONVS))
@pytest.mark.parametrize("knn", [0, 4])
def test_encoder_is_equivariant_to_permuting_the_batch(conv, knn):
    torch.manual_seed(0)
    enc = TreeEncoder.from_space(ARM_SPACE, hidden_channels=16, num_layers=2, out_channels=8, conv=conv, knn=knn)
    obs = as_tensors(random_tree_obs(ARM_SPACE, [5, 60, 12, 30, 2], np.random.default_rng(2)))
    perm = torch.tensor([3, 0, 4, 1, 2])
    nodes, embed, batch = enc(obs)
    p_nodes, p_embed, p_batch = enc({k: v[perm] for k, v in obs.items()})
    torch.testing.assert_close(p_embed, embed[perm], rtol=1e-4, atol=1e-5)
    for new, old in enumerate(perm.tolist()):          # node embeddings move with their graph
        torch.testing.assert_close(p_nodes[p_batch == new], nodes[batch == old], rtol=1e-4, atol=1e-5)
    assert not torch.allclose(embed[0], embed[1])       # and graphs are not all mapped to one point


@pytest.mark.parametrize("knn", [0, 4])
def test_encoder_sage_fast_path_is_pygs_sageconv_bit_for_bit(knn, monkeypatch):
    """MeanEdges.conv computes what PyG's SAGEConv (mean) computes, bit for bit, forward and backward:
    the oracle is the same encoder calling the PyG layers themselves."""
    import agents.nn.encoders as encoders
    torch.manual_seed(0)
    enc = TreeEncoder.from_space(ARM_SPACE, hidden_channels=16, num_layers=3, out_channels=8, knn=knn)
    batched = as_tensors(random_tree_obs(ARM_SPACE, [5, 60, 12, None, 1, 30], np.random.default_rng(4)))
    inputs = [batched, {k: v[1] for k, v in batched.items()}]
    fast = [enc(o) for o in inputs]
    grads_fast = torch.autograd.grad(fast[0][1].square().sum(), list(enc.parameters()))
    with monkeypatch.context() as m:
        m.setattr(encoders, "plain_mean_sage", lambda conv: False)       # every layer through PyG
        slow = [enc(o) for o in inputs]
        grads_slow = torch.autograd.grad(slow[0][1].square().sum(), list(enc.parameters()))
    for got, want in zip(fast, slow):
        for a, b in zip(got, want):
            assert torch.equal(a, b)
    assert all(torch.equal(a, b) for a, b in zip(grads_fast, grads_slow))
    assert encoders.plain_mean_sage(enc.tree_convs[0])                 # the fast path was taken


def test_encoder_trains_end_to_end_and_rejects_unknown_names():
    enc = TreeEncoder.from_space(MAZE_SPACE, hidden_channels=8, num_layers=2, out_channels=4, knn=3)
    obs = as_tensors(random_tree_obs(MAZE_SPACE, [5, 40, None], np.random.default_rng(3)))
    _, embed, _ = enc(obs)
    assert torch.isfinite(embed).all()                  # an all-zero (empty) element too
    embed.square().sum().backward()
    missing = [n for n, p in enc.named_parameters() if p.grad is None or not torch.any(p.grad != 0)]
    assert not missing, missing
    with pytest.raises(ValueError, match="sage"):
        TreeEncoder(5, conv="nope")


def test_encoder_module_writes_embed():
    module = EncoderModule.from_space(MAZE_SPACE, hidden_channels=8, out_channels=12)
    assert list(module.in_keys) == list(OBSERVATION_KEYS) and list(module.out_keys) == ["embed"]
    td = TensorDict(as_tensors(random_tree_obs(MAZE_SPACE, [3, 9, 27, 60], np.random.default_rng(4))),
                    batch_size=[4])
    out = module(td)
    assert out is td and out["embed"].shape == (4, 12)


# ---------------------------------------------------------------------------- the learned-sampler hook
def make_offset_sampler(low, high, seed=0, **kw):
    """A learned sampler of one's own: ``model_sample`` puts a Gaussian at the goal."""
    from agents.samplers import ModelSampler

    class GoalGaussian(ModelSampler):
        def model_sample(self, obs):
            return np.asarray(obs["goal"], np.float64) + 1e-3 * self.rng.standard_normal(self.state_dim)

    return GoalGaussian(low, high, seed, **kw)


def test_model_sampler_is_seeded_bounded_and_mixes_at_its_rates():
    env = gym.make("GNNMP/Maze2DBiRRT-v0", max_nodes=200)
    low, high = env.action_space.low, env.action_space.high
    sampler = make_offset_sampler(low, high, seed=3, uniform_mix=0.3, goal_bias=0.2)
    runs = []
    for _ in range(2):
        sampler.reset(3)
        obs, _ = env.reset(seed=0)
        run = []
        for _ in range(30):
            a = sampler.act(obs)
            assert a.dtype == np.float32 and env.action_space.contains(a)
            run.append(a)
            obs, *_ = env.step(a)
        runs.append(np.array(run))
    np.testing.assert_array_equal(runs[0], runs[1])
    sampler.reset(4)
    assert not np.array_equal(np.array([sampler.act(obs) for _ in range(30)]), runs[0])
    # the rates: a target sample equals the active tree's target exactly, a model sample lies near the goal
    obs, _ = env.reset(seed=1)
    draws = np.array([sampler.act(obs) for _ in range(4000)])
    target = np.all(draws == obs["goal"], axis=1)
    near = ~target & (np.linalg.norm(draws - obs["goal"], axis=1) < 0.01)
    assert abs(target.mean() - 0.2) < 0.025 and abs(near.mean() - 0.5) < 0.03
    td = TensorDict({k: torch.as_tensor(np.stack([obs[k]] * 3)) for k in OBSERVATION_KEYS}, batch_size=[3])
    out = sampler.as_module()(td)
    assert out["action"].shape == (3, 2) and out["action"].dtype == torch.float32
    with pytest.raises(ValueError, match="3-D states"):
        sampler.act({**obs, "start": np.zeros(3, np.float32)})


def test_model_sampler_uniform_mix_one_is_uniform():
    low, high = np.array([0.0, -2.0], np.float32), np.array([1.0, 2.0], np.float32)
    sampler = make_offset_sampler(low, high, uniform_mix=1.0)
    obs = random_tree_obs(MAZE_SPACE, [4], np.random.default_rng(5))
    a = np.array([sampler.act({k: v[0] for k, v in obs.items()}) for _ in range(2000)])
    assert np.all(a >= low) and np.all(a <= high)
    assert abs(float(a[:, 1].mean())) < 0.15 and a[:, 1].std() > 1.0     # spread over the box


# ---------------------------------------------------------------------------- SB3 and TorchRL
def test_sb3_ppo_learns_with_the_tree_features_extractor():
    from stable_baselines3 import PPO

    from agents.rl.sb3 import TreeFeaturesExtractor
    torch.manual_seed(0)
    env = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=200)
    model = PPO("MultiInputPolicy", env, n_steps=128, batch_size=64, n_epochs=1, seed=0, device="cpu",
                policy_kwargs={"features_extractor_class": TreeFeaturesExtractor,
                               "features_extractor_kwargs": {"hidden_channels": 16, "num_layers": 2,
                                                             "out_channels": 32}})
    extractor = model.policy.features_extractor
    assert isinstance(extractor, TreeFeaturesExtractor) and extractor.features_dim == 32
    before = [p.detach().clone() for p in extractor.parameters()]
    model.learn(256)
    assert model.num_timesteps == 256
    assert any(not torch.equal(a, b) for a, b in zip(before, extractor.parameters()))   # the GNN was trained
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2,)


def test_torchrl_actor_rollout_and_shared_value_head():
    import torchrl
    from torchrl.envs import GymEnv

    import agents.rl.torchrl as agents_torchrl
    from agents.rl.torchrl import make_actor, make_value
    assert torchrl.__file__ != agents_torchrl.__file__ and hasattr(torchrl, "envs")   # no shadowing

    torch.manual_seed(0)
    env = GymEnv("GNNMP/Maze2DRRT-v0", max_nodes=200)
    space = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=200)
    encoder = EncoderModule.from_space(space.observation_space, hidden_channels=16, out_channels=16)
    actor = make_actor(space.observation_space, space.action_space, encoder=encoder)
    value = make_value(space.observation_space, encoder=encoder)
    env.set_seed(0)
    with torch.no_grad():
        rollout = env.rollout(256, actor, break_when_any_done=False)
    assert rollout.batch_size == (256,)
    low, high = torch.as_tensor(space.action_space.low), torch.as_tensor(space.action_space.high)
    assert torch.all(rollout["action"] >= low) and torch.all(rollout["action"] <= high)
    log_prob_key = [k for k in rollout.keys() if isinstance(k, str) and k.endswith("log_prob")]
    assert len(log_prob_key) == 1 and torch.isfinite(rollout[log_prob_key[0]]).all()
    assert rollout["embed"].shape == (256, 16)
    out = value(rollout)
    assert out["state_value"].shape == (256, 1) and torch.isfinite(out["state_value"]).all()
    # One set of encoder weights serves both heads: the critic's loss reaches the actor's encoder.
    assert value[0] is actor.module[0][0]
    value(rollout[:32])["state_value"].sum().backward()
    assert all(p.grad is not None for p in encoder.parameters())
    # A separate value head builds its own encoder of the same class.
    other = make_value(space.observation_space, hidden_channels=8, out_channels=8)
    assert isinstance(other[0], EncoderModule) and other[0] is not encoder


# ---------------------------------------------------------------------------- tools/bench_sampler.py
def test_bench_sampler_reports_both_measurements(capsys):
    from tools.bench_sampler import main
    code = main(["--batch", "6", "--nodes", "40", "--trees", "2", "--conversions", "2",
                 "--rounds", "1", "--act-nodes", "30", "--window", "20", "--tasks", "maze2d",
                 "--samplers", "uniform,goal-bias", "--clock", "cpu"])
    out = capsys.readouterr().out
    assert code == 0
    assert "to_pyg: 6 maze2d observations x 40 nodes" in out and "per-graph reference" in out
    rows = {line.split()[0]: line.split()[1:] for line in out.splitlines() if line.startswith("  ")}
    assert float(rows["uniform"][0]) > 0 and float(rows["goal-bias"][0]) > 0
    with pytest.raises(SystemExit) as exc:
        main(["--samplers", "nope"])
    assert exc.value.code == 2 and "unknown sampler" in capsys.readouterr().err


def test_bench_sampler_takes_repeatable_flags_like_the_benchmark(capsys, tmp_path):
    """--checkpoint NAME=PATH and --import MODULE repeat, as in `gnn-mp benchmark` (they were comma lists)."""
    from agents.checkpoints import shipped_checkpoint
    from tools.bench_sampler import Args, main
    from train.args import OneLineParser, add_dataclass_arguments, from_namespace
    parser = OneLineParser()
    add_dataclass_arguments(parser, Args)
    gnn, cvae = shipped_checkpoint("gnn", "maze2d"), shipped_checkpoint("cvae", "maze2d")
    args = from_namespace(Args, parser.parse_args(["--checkpoint", f"gnn={gnn}", "--checkpoint", f"cvae={cvae}",
                                                   "--import", "tests.tiny_task", "--import", "json"]))
    assert args.checkpoints == {"gnn": gnn, "cvae": cvae} and args.modules == ["tests.tiny_task", "json"]
    with pytest.raises(SystemExit) as exc:
        main(["--checkpoint", f"gnn={tmp_path / 'missing.pt'}"])
    assert exc.value.code == 2 and "does not exist" in capsys.readouterr().err


def test_bench_sampler_skips_a_task_whose_planner_solves_before_the_tree_size(capsys):
    """BiRRT ends when its trees connect whatever the goal test says: the arm never reaches
    1,000 nodes, and the timing says so instead of looping forever."""
    from tools.bench_sampler import main
    code = main(["--skip-to-pyg", "--rounds", "1", "--act-nodes", "1000", "--window", "5",
                 "--tasks", "maze2d,arm", "--samplers", "uniform", "--clock", "cpu"])
    captured = capsys.readouterr()
    assert code == 0
    assert "skipping arm: arm problem 0: the planner solved at" in captured.err
    rows = {line.split()[0]: line.split()[1:] for line in captured.out.splitlines() if line.startswith("  ")}
    assert float(rows["uniform"][0]) > 0 and rows["uniform"][1] == "n/a"
