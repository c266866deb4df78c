"""Training losses of the critical-sample models, one per (input family, output) pair.

* deterministic models: ``point_loss_weight`` x the squared error to the *nearest* label
  (several labels per problem; the mean over labels would average two passages into a
  wall), minus ``node_loss_weight`` x a label-node term for models that score the graph's
  nodes (attention readout, heat-map CNN): the log of the node distribution's mass on the
  labels (``node_target="any"``) or its mean log-probability of the labels (``"all"``, a
  cross-entropy against the uniform distribution over the labels);
* CVAEs: reconstruction of one randomly drawn label per problem + ``kl_weight`` x KL
  (GNN-CVAE with attention: minus ``node_loss_weight`` x the drawn label node's log attention).

:func:`loss` dispatches on :data:`agents.critical.models.MODELS` (``LOSSES`` table).
"""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor, nn

from agents.critical.models import MODELS
from train.critical.args import Optim

Batch = dict  # an Inputs(...) batch, see train.critical.data


def nearest_label_loss(pred: Tensor, y: Tensor, owner: Tensor) -> Tensor:
    """Mean over problems of the squared error to the nearest label (multi-label regression)."""
    se = ((pred[owner] - y) ** 2).sum(-1)
    best = torch.full((pred.shape[0],), float("inf")).scatter_reduce(0, owner, se, "amin")
    return best.mean()


def one_label_each(y: Tensor, owner: Tensor, size: int, gen: torch.Generator,
                   return_index: bool = False):
    """One random label per problem (CVAE targets: the label distribution is the target)."""
    counts = torch.bincount(owner, minlength=size)
    start = torch.cumsum(counts, 0) - counts
    pick = start + (torch.rand(size, generator=gen) * counts).long().clamp(max=counts.max() - 1)
    pick = torch.minimum(pick, start + counts - 1)
    return (y[pick], pick) if return_index else y[pick]


def label_log_likelihood(log_a: Tensor, label_index: Tensor, owner: Tensor, size: int) -> Tensor:
    """Mean over problems of log(sum of attention on the problem's label nodes).

    Node target ``"any"``: maximal once all mass sits on *one* of the labels.
    """
    la = log_a[label_index]
    m = la.detach().max()
    per = torch.zeros(size).index_add(0, owner, torch.exp(la - m))
    return (torch.log(per.clamp_min(1e-30)) + m).mean()


def label_mean_log_prob(log_a: Tensor, label_index: Tensor, owner: Tensor, size: int) -> Tensor:
    """Mean over problems of the mean log-probability of the problem's label nodes.

    Node target ``"all"``: minus the cross-entropy against the uniform distribution over the
    labels, maximal when every label gets an equal share, so the top-k nodes cover all of
    a problem's bottlenecks rather than one.
    """
    counts = torch.bincount(owner, minlength=size).clamp_min(1).to(log_a.dtype)
    per = torch.zeros(size, dtype=log_a.dtype).index_add(0, owner, log_a[label_index])
    return (per / counts).mean()


#: Node targets of the label-node term (``Optim.node_target``).
NODE_TARGETS = {"any": label_log_likelihood, "all": label_mean_log_prob}


def _node_weight(model: nn.Module, optim: Optim) -> float:
    return optim.node_loss_weight if getattr(model, "has_node_scores", False) else 0.0


def _det_loss(pred: Tensor, log_a: Tensor | None, inp: Batch, optim: Optim, node_w: float) -> Tensor:
    """``point_loss_weight`` x nearest-label squared error - ``node_w`` x the label-node term."""
    out = optim.point_loss_weight * nearest_label_loss(pred, inp["y"], inp["owner"])
    if log_a is not None:
        out = out - node_w * NODE_TARGETS[optim.node_target](log_a, inp["label_index"], inp["owner"], inp["size"])
    return out


def graph_det_loss(model: nn.Module, inp: Batch, optim: Optim, gen: torch.Generator) -> Tensor:
    node_w = _node_weight(model, optim)
    if node_w > 0:
        pred, log_a = model(inp["x"], inp["edge_index"], inp["batch"], inp["pos"], return_log_attention=True)
        return _det_loss(pred, log_a, inp, optim, node_w)
    return _det_loss(model(inp["x"], inp["edge_index"], inp["batch"], inp["pos"]), None, inp, optim, 0.0)


def image_det_loss(model: nn.Module, inp: Batch, optim: Optim, gen: torch.Generator) -> Tensor:
    if getattr(model, "has_node_scores", False):     # heat-map CNN: read at the graph's nodes
        pred, log_a = model(inp["image"], inp["pos"], return_log_attention=True)
        return _det_loss(pred, log_a, inp, optim, optim.node_loss_weight)
    return _det_loss(model(inp["image"]), None, inp, optim, 0.0)


def graph_cvae_loss(model: nn.Module, inp: Batch, optim: Optim, gen: torch.Generator) -> Tensor:
    y, pick = one_label_each(inp["y"], inp["owner"], inp["size"], gen, return_index=True)
    mu, logstd = model.encode(inp["x"], inp["edge_index"], y, inp["pos"], inp["batch"])
    z = model.reparametrize(mu, logstd, gen)
    node_w = _node_weight(model, optim)
    if node_w > 0:
        y_hat, log_a = model.decode(z, inp["x"], inp["edge_index"], inp["batch"], inp["pos"],
                                    return_log_attention=True)
        ll = log_a[inp["label_index"][pick]].mean()
        return model.recon_loss(y_hat, y) + optim.kl_weight * model.kl_loss(mu, logstd) - node_w * ll
    y_hat = model.decode(z, inp["x"], inp["edge_index"], inp["batch"], inp["pos"])
    return model.recon_loss(y_hat, y) + optim.kl_weight * model.kl_loss(mu, logstd)


def image_cvae_loss(model: nn.Module, inp: Batch, optim: Optim, gen: torch.Generator) -> Tensor:
    y = one_label_each(inp["y"], inp["owner"], inp["size"], gen)
    mu, logstd = model.encode(inp["image"], y)
    y_hat = model.decode(model.reparametrize(mu, logstd, gen), inp["image"])
    return model.recon_loss(y_hat, y) + optim.kl_weight * model.kl_loss(mu, logstd)


LossFn = Callable[[nn.Module, Batch, Optim, torch.Generator], Tensor]
#: (input family, output family) of :data:`MODELS` -> loss.
LOSSES: dict[tuple[str, str], LossFn] = {
    ("graph", "det"): graph_det_loss,
    ("image", "det"): image_det_loss,
    ("graph", "cvae"): graph_cvae_loss,
    ("image", "cvae"): image_cvae_loss,
}


def loss(model: nn.Module, name: str, inp: Batch, optim: Optim, gen: torch.Generator) -> Tensor:
    """The training loss of critical model ``name`` on one batch."""
    _, family, out = MODELS[name]
    return LOSSES[family, out](model, inp, optim, gen)
