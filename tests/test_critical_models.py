"""Critical-sample models: output shapes, CVAE API and permutation equivariance (Theorem 1)."""

import numpy as np
import pytest
import torch

from agents.critical.data import graph_batch, image_batch, node_features
from agents.critical.models import (CriticalCNN, CriticalCVAE, CriticalGAT, CriticalGNN,
                                    CriticalGNNCVAE, build_model)
from gnn_mp_envs.critical.dataset import CriticalProblems
from gnn_mp_envs.critical.halton import halton_graph

torch.set_num_threads(2)


def _graph_inputs(n=120, seed=0):
    g = halton_graph(n)
    rng = np.random.default_rng(seed)
    free = rng.random(n) > 0.2
    x = torch.from_numpy(node_features(g.nodes, rng.random(2), rng.random(2), free))
    e = g.edges[free[g.edges[:, 0]] & free[g.edges[:, 1]]]
    ei = torch.from_numpy(np.concatenate([e, e[:, ::-1]]).T.copy())
    return g, x, ei


def _permute(x, ei, pos, seed=1):
    perm = torch.from_numpy(np.random.default_rng(seed).permutation(x.shape[0]))
    inv = torch.empty_like(perm)
    inv[perm] = torch.arange(len(perm))
    return perm, x[perm], inv[ei], pos[perm]


@pytest.mark.parametrize("cls", [CriticalGNN, CriticalGAT])
def test_graph_regressor_shapes_and_equivariance(cls):
    torch.manual_seed(0)
    g, x, ei = _graph_inputs()
    model = cls(5, 16, 3, 2).eval()
    with torch.no_grad():
        out = model(x, ei)
        assert out.shape == (1, 2)
        pos = torch.from_numpy(g.nodes).float()
        perm, xp, eip, _ = _permute(x, ei, pos)
        h, hp = model.node_embeddings(x, ei), model.node_embeddings(xp, eip)
        assert torch.allclose(hp, h[perm], atol=1e-5)          # node level: permuted
        assert torch.allclose(model(xp, eip), out, atol=1e-5)   # pooled: unchanged
        batch = torch.zeros(x.shape[0], dtype=torch.long)
        assert torch.allclose(model(x, ei, batch), out, atol=1e-6)


def test_gnn_cvae_decoder_equivariance_and_api():
    torch.manual_seed(0)
    g, x, ei = _graph_inputs()
    pos = torch.from_numpy(g.nodes).float()
    model = CriticalGNNCVAE(5, 16, 2, 2, latent_channels=3).eval()
    z = torch.randn(1, 3)
    y = torch.tensor([[0.4, 0.6]])
    with torch.no_grad():
        perm, xp, eip, posp = _permute(x, ei, pos)
        assert torch.allclose(model.decoder.node_embeddings(xp, eip),
                              model.decoder.node_embeddings(x, ei)[perm], atol=1e-5)
        assert torch.allclose(model.decode(z, xp, eip), model.decode(z, x, ei), atol=1e-5)
        mu, logstd = model.encode(x, ei, y, pos)
        mu_p, logstd_p = model.encode(xp, eip, y, posp)
        assert mu.shape == (1, 3) and torch.allclose(mu, mu_p, atol=1e-5)
        samples = model.sample(x, ei, None, 7, torch.Generator().manual_seed(0))
        assert samples.shape == (1, 7, 2)
    model.train()
    mu, logstd = model.encode(x, ei, y, pos)
    zt = model.reparametrize(mu, logstd)
    loss = model.recon_loss(model.decode(zt, x, ei), y) + model.kl_loss(mu, logstd)
    loss.backward()
    assert all(p.grad is not None for p in model.parameters())


def test_image_models_shapes():
    torch.manual_seed(0)
    occ = np.zeros((3, 64, 64), np.uint8)
    occ[:, :, 30:33] = 1
    img = image_batch(occ, np.full((3, 2), 0.2), np.full((3, 2), 0.8))
    assert img.shape == (3, 3, 64, 64) and float(img[0, 1].max()) > 0.5
    assert CriticalCNN()(img).shape == (3, 2)
    cvae = CriticalCVAE()
    mu, logstd = cvae.encode(img, torch.rand(3, 2))
    assert mu.shape == (3, 2) and cvae.decode(mu, img).shape == (3, 2)
    assert cvae.sample(img, 5).shape == (3, 5, 2)


def test_graph_batch_follows_labels():
    g = halton_graph()
    rng = np.random.default_rng(0)
    n = g.num_nodes
    probs = CriticalProblems(
        walls=[np.zeros((0, 4))] * 2, blobs=[np.zeros((0, 3))] * 2, start=rng.random((2, 2)),
        goal=rng.random((2, 2)), node_free=np.ones((2, n), bool), edge_free=np.ones((2, len(g.edges)), bool),
        label_ptr=np.array([0, 1, 3]), label_nodes=np.array([5, 6, 7]), path_cost=np.ones(2),
        map_index=np.arange(2), split=np.zeros(2, np.int8))
    b = graph_batch(probs, g, np.arange(2))
    assert b.x.shape == (2 * n, 5) and b.y.shape == (3, 2)
    assert b.y_batch.tolist() == [0, 1, 1]
    assert b.edge_index.shape[1] == 4 * len(g.edges)
    out = build_model("gnn", hidden_channels=8, num_layers=2)(b.x, b.edge_index, b.batch)
    assert out.shape == (2, 2)


@pytest.mark.parametrize("cls", [CriticalGNN, CriticalGAT])
def test_attention_readout_equivariance(cls):
    """Attention readout: node scores permute with the nodes, the prediction is invariant."""
    torch.manual_seed(0)
    g, _, ei = _graph_inputs()
    rng = np.random.default_rng(0)
    x = torch.from_numpy(node_features(g.nodes, rng.random(2), rng.random(2), rng.random(len(g.nodes)) > 0.2,
                                       with_position=True))
    assert x.shape[1] == 7
    pos = torch.from_numpy(g.nodes).float()
    model = cls(7, 16, 3, 2, readout="attention").eval()
    with torch.no_grad():
        out = model(x, ei, None, pos)
        assert out.shape == (1, 2)
        # zero-initialised offset: the prediction is a convex combination of node positions
        assert bool((out >= 0).all() and (out <= 1).all())
        perm, xp, eip, posp = _permute(x, ei, pos)
        assert torch.allclose(model(xp, eip, None, posp), out, atol=1e-5)
        # two graphs in one batch give the same predictions as separately
        xx, ee = torch.cat([x, xp]), torch.cat([ei, eip + x.shape[0]], 1)
        batch = torch.cat([torch.zeros(len(x)), torch.ones(len(x))]).long()
        both = model(xx, ee, batch, torch.cat([pos, posp]))
        assert torch.allclose(both, out.expand(2, -1), atol=1e-5)
    with pytest.raises(ValueError):
        model(x, ei)


def test_gnn_cvae_attention_decoder():
    torch.manual_seed(0)
    g, x, ei = _graph_inputs()
    pos = torch.from_numpy(g.nodes).float()
    model = CriticalGNNCVAE(5, 16, 2, 2, latent_channels=3, readout="attention").eval()
    z = torch.randn(1, 3)
    with torch.no_grad():
        perm, xp, eip, posp = _permute(x, ei, pos)
        ref = model.decode(z, x, ei, None, pos)
        assert ref.shape == (1, 2)
        assert torch.allclose(model.decode(z, xp, eip, None, posp), ref, atol=1e-5)
        samples = model.sample(x, ei, None, 5, torch.Generator().manual_seed(0), pos)
        assert samples.shape == (1, 5, 2)
        # k latents decode like k single decodes
        zs = torch.randn(1, 4, 3)
        many = model.decode(zs, x, ei, None, pos)
        single = torch.cat([model.decode(zs[:, j], x, ei, None, pos) for j in range(4)])
        assert torch.allclose(many[0], single, atol=1e-5)
    model.train()
    y = torch.tensor([[0.4, 0.6]])
    mu, logstd = model.encode(x, ei, y, pos)
    loss = model.recon_loss(model.decode(model.reparametrize(mu, logstd), x, ei, None, pos), y)
    (loss + model.kl_loss(mu, logstd)).backward()
    assert all(p.grad is not None for p in model.parameters())


def test_tagconv_csr_propagation_matches_message_passing():
    """The CSR fast path gives the same embeddings as TAGConv's own normalisation."""
    from torch_geometric.nn import TAGConv
    torch.manual_seed(0)
    g, x, ei = _graph_inputs()
    model = CriticalGNN(5, 8, 2, 2).eval()
    ref = x
    for conv in model.convs:
        c = TAGConv(conv.in_channels, conv.out_channels, K=conv.K)
        c.load_state_dict(conv.state_dict())
        ref = torch.relu(c(ref, ei))
    with torch.no_grad():
        assert torch.allclose(model.node_embeddings(x, ei), ref, atol=1e-5)


def test_attention_log_attention_and_label_likelihood():
    """Log attention normalises per graph; the label term rewards attention on label nodes."""
    from train.critical.losses import label_log_likelihood
    torch.manual_seed(0)
    g, x, ei = _graph_inputs()
    pos = torch.from_numpy(g.nodes).float()
    model = CriticalGNN(5, 8, 2, 2, readout="attention").eval()
    xx, ee = torch.cat([x, x]), torch.cat([ei, ei + x.shape[0]], 1)
    batch = torch.cat([torch.zeros(len(x)), torch.ones(len(x))]).long()
    with torch.no_grad():
        out, log_a = model(xx, ee, batch, torch.cat([pos, pos]), return_log_attention=True)
    assert out.shape == (2, 2) and log_a.shape == (2 * len(x),)
    sums = torch.zeros(2).index_add(0, batch, log_a.exp())
    assert torch.allclose(sums, torch.ones(2), atol=1e-5)
    label_index, owner = torch.tensor([3, 7, len(x) + 5]), torch.tensor([0, 0, 1])
    ll = label_log_likelihood(log_a, label_index, owner, 2)
    want = (torch.log(log_a[[3, 7]].exp().sum()) + log_a[len(x) + 5]) / 2
    assert torch.allclose(ll, want, atol=1e-5)


def test_graph_batch_all_edges_and_position():
    g = halton_graph()
    n = g.num_nodes
    probs = CriticalProblems(
        walls=[np.zeros((0, 4))], blobs=[np.zeros((0, 3))], start=np.full((1, 2), 0.1),
        goal=np.full((1, 2), 0.9), node_free=np.ones((1, n), bool), edge_free=np.zeros((1, len(g.edges)), bool),
        label_ptr=np.array([0, 1]), label_nodes=np.array([5]), path_cost=np.ones(1),
        map_index=np.arange(1), split=np.zeros(1, np.int8))
    assert graph_batch(probs, g, np.arange(1)).edge_index.shape[1] == 0
    b = graph_batch(probs, g, np.arange(1), with_position=True, all_edges=True)
    assert b.edge_index.shape[1] == 2 * len(g.edges) and b.x.shape == (n, 7)
    assert torch.allclose(b.x[:, 5:], torch.from_numpy(g.nodes).float())
    with pytest.raises(ValueError):
        CriticalGNN(edges="some")


def _random_graph(n, width, dim, seed=0):
    g = torch.Generator().manual_seed(seed)
    x, pos = torch.rand(n, width, generator=g), torch.rand(n, dim, generator=g)
    ei = torch.randint(0, n, (2, 6 * n), generator=g)
    return x, pos, torch.cat([ei, ei.flip(0)], 1)


@pytest.mark.parametrize("cls", [CriticalGNN, CriticalGAT])
def test_generic_regressors_take_any_state_dimension(cls):
    """The arm's trees: 13 node features, 6-D states; the centre is a constructor argument."""
    torch.manual_seed(0)
    x, pos, ei = _random_graph(40, 13, 6)
    centre = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
    att = cls(13, 16, 2, 6, readout="attention").eval()
    mx = cls(13, 16, 2, 6, readout="max", centre=centre).eval()
    with torch.no_grad():
        out = att(x, ei, None, pos)
        assert out.shape == (1, 6)
        assert bool(((out >= 0) & (out <= 1)).all())          # a mean of node positions at init
        pooled = mx.pool(x, ei)
        assert torch.allclose(mx(x, ei), mx.head(pooled) + torch.tensor(centre), atol=1e-6)
    assert "_centre" not in mx.state_dict()                   # not a weight: old checkpoints load unchanged
    with pytest.raises(ValueError, match="pos has 2 columns"):
        att(x, ei, None, pos[:, :2])


def test_generic_cvae_and_image_models_take_any_state_dimension():
    torch.manual_seed(0)
    x, pos, ei = _random_graph(40, 13, 6)
    cvae = CriticalGNNCVAE(13, 16, 2, 6, latent_channels=3, readout="attention").eval()
    with torch.no_grad():
        assert cvae.sample(x, ei, None, 4, torch.Generator().manual_seed(0), pos).shape == (1, 4, 6)
        mu, _ = cvae.encode(x, ei, torch.rand(1, 6), pos)
        assert mu.shape == (1, 3)
    cvae_max = CriticalGNNCVAE(13, 16, 2, 6, latent_channels=3, centre=[1.0] * 6).eval()
    with torch.no_grad():
        cond = cvae_max.condition(x, ei)
        z = torch.zeros(1, 2, 3)
        want = cvae_max.decoder.head(torch.cat([cond[:, None].expand(-1, 2, -1), z], -1)) + 1.0
        assert torch.allclose(cvae_max.decode_pooled(cond, z), want, atol=1e-6)
    img = torch.rand(2, 3, 64, 64)
    assert torch.allclose(CriticalCNN(out_channels=4, centre=2.0).eval()(img).mean(), torch.tensor(2.0), atol=0.5)
    assert CriticalCVAE(out_channels=4, centre=(0.0, 1.0, 2.0, 3.0)).sample(img, 3).shape == (2, 3, 4)
