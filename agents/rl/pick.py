"""The candidate picker's network (``Discrete(K)`` actions), shared by SB3's export, TorchRL's actor and
the sampler; here rather than in :mod:`agents.rl.policies` so that :mod:`agents.rl.torchrl` builds it
without importing the policies module (which imports TorchRL's heads)."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import torch
from torch import nn

from agents.nn.encoders import ACTIVATIONS, CandidateEncoder, prior_head_init


def mlp(in_dim: int, hidden: Sequence[int], activation: str) -> nn.Sequential:
    """``Linear, act, Linear, act, ...`` (SB3's ``create_mlp`` layout: indices 0, 2, ...)."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, int(width)), ACTIVATIONS[activation]()]
        in_dim = int(width)
    return nn.Sequential(*layers)



class SharedCandidateHead(nn.Module):
    """Logits from one score shared by the candidates, over :meth:`CandidateEncoder.flat`'s layout:
    ``logit_k = w . [e_k, mean, max] + bias_k (+ prior_scale * prior_k)``.

    A slot-wise linear head learns each candidate slot's score separately, from a ``K``-th of the
    data (the uniform slots are exchangeable); this one learns one score for all, a bias per slot
    (the slot's kind: target, near-target, newest, greedy, uniform) and, with a prior, how much to
    trust it. It starts as exactly the prior (``w = 0``, biases 0, scale 1; without a prior: a
    uniform pick), so PPO's first updates move a few hundred parameters from there, not the
    ``K x (K E + 2 E)`` of the slot-wise head.
    """

    def __init__(self, count: int, embed: int, prior: bool = False) -> None:
        super().__init__()
        self.count, self.embed, self.has_prior = int(count), int(embed), bool(prior)
        self.score = nn.Linear(3 * self.embed, 1)
        self.slot_bias = nn.Parameter(torch.zeros(self.count))
        self.prior_scale = nn.Parameter(torch.ones(1)) if self.has_prior else None
        with torch.no_grad():
            self.score.weight.zero_()
            self.score.bias.zero_()

    def forward(self, flat: torch.Tensor) -> torch.Tensor:
        K, E = self.count, self.embed
        per = flat[..., :K * E].unflatten(-1, (K, E))
        summary = flat[..., K * E:K * E + 2 * E].unsqueeze(-2).expand(*per.shape[:-1], 2 * E)
        logits = self.score(torch.cat([per, summary], -1)).squeeze(-1) + self.slot_bias
        if self.has_prior:
            logits = logits + self.prior_scale * flat[..., -K:]
        return logits


def set_prior_scale(module: nn.Module, scale: float) -> int:
    """Start every :class:`SharedCandidateHead` with a prior inside ``module`` at weight ``scale`` on the
    prior's logits (1: the policy is the prior; 0: blind to it); returns how many heads were set."""
    heads = [m for m in module.modules() if isinstance(m, SharedCandidateHead) and m.prior_scale is not None]
    with torch.no_grad():
        for head in heads:
            head.prior_scale.fill_(float(scale))
    return len(heads)


#: ``PickPolicy(head=...)``: a linear score per candidate slot, or one score shared by the candidates.
PICK_HEADS = ("linear", "shared")


class PickPolicy(nn.Module):
    """A candidate picker (``Discrete(K)`` actions): :class:`CandidateEncoder` -> body MLP -> ``K`` logits.

    SB3 PPO's layout with ``net_arch=dict(pi=hidden, ...)`` (``mlp_extractor.policy_net`` ->
    ``action_net``) and the TorchRL actor's of :func:`agents.rl.torchrl.make_pick_actor`.
    ``forward(obs)`` returns the logits ``(*batch, K)`` of a categorical over the candidates.
    ``head="shared"``: a :class:`SharedCandidateHead` (no body) instead of the slot-wise linear layer.
    With a candidate prior (the encoder's ``prior``) the head has no body and starts as the prior's
    logits (:func:`~agents.nn.encoders.prior_head_init`, or the shared head's own start).
    """

    def __init__(self, encoder: Mapping[str, Any], hidden: Sequence[int] = (), activation: str = "tanh",
                 head: str = "linear") -> None:
        super().__init__()
        if head not in PICK_HEADS:
            raise ValueError(f"head must be one of {PICK_HEADS}, got {head!r}")
        self.encoder = CandidateEncoder(**dict(encoder))
        prior = self.encoder.prior_model is not None
        if (prior or head == "shared") and hidden:
            raise ValueError(f"a picker with a candidate prior or a shared head has no hidden layers before its scores "
                             f"(a linear head: its logits start as the prior's); got hidden layers {list(hidden)}")
        self.head = head
        self.body = mlp(self.encoder.out_channels, hidden, activation)
        if head == "shared":
            self.logits = SharedCandidateHead(self.encoder.count, self.encoder.embed, prior)
        else:
            self.logits = nn.Linear(int(hidden[-1]) if hidden else self.encoder.out_channels, self.encoder.count)
            if prior:
                prior_head_init(self.logits, self.encoder.count)

    @property
    def count(self) -> int:
        return self.encoder.count

    @property
    def reads_tree(self) -> bool:
        """Whether the encoder reads the tree view (a tree context) besides the candidate features."""
        return self.encoder.tree is not None

    def forward(self, obs: Mapping) -> torch.Tensor:
        return self.logits(self.body(self.encoder.flat(obs)))


__all__ = ["PICK_HEADS", "PickPolicy", "SharedCandidateHead", "mlp", "set_prior_scale"]
