"""The candidate picker's network (``Discrete(K)`` actions), shared by SB3's export, TorchRL's actor and
the sampler; here rather than in :mod:`agents.rl.policies` so that :mod:`agents.rl.torchrl` builds it
without importing the policies module (which imports TorchRL's heads)."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import torch
from torch import nn

from agents.encoders import ACTIVATIONS, CandidateEncoder, prior_head_init


def mlp(in_dim: int, hidden: Sequence[int], activation: str) -> nn.Sequential:
    """``Linear, act, Linear, act, ...`` (SB3's ``create_mlp`` layout: indices 0, 2, ...)."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, int(width)), ACTIVATIONS[activation]()]
        in_dim = int(width)
    return nn.Sequential(*layers)



class PickPolicy(nn.Module):
    """A candidate picker (``Discrete(K)`` actions): :class:`CandidateEncoder` -> body MLP -> ``K`` logits.

    SB3 PPO's layout with ``net_arch=dict(pi=hidden, ...)`` (``mlp_extractor.policy_net`` ->
    ``action_net``) and the TorchRL actor's of :func:`agents.rl.torchrl.make_pick_actor`.
    ``forward(obs)`` returns the logits ``(*batch, K)`` of a categorical over the candidates.
    With a candidate prior (the encoder's ``prior``) the head is linear and starts as the prior's
    logits (:func:`~agents.encoders.prior_head_init`).
    """

    def __init__(self, encoder: Mapping[str, Any], hidden: Sequence[int] = (), activation: str = "tanh") -> None:
        super().__init__()
        self.encoder = CandidateEncoder(**dict(encoder))
        if self.encoder.prior_model is not None and hidden:
            raise ValueError("a picker with a candidate prior has a linear head (its logits start as the prior's); "
                             f"got hidden layers {list(hidden)}")
        self.body = mlp(self.encoder.out_channels, hidden, activation)
        self.logits = nn.Linear(int(hidden[-1]) if hidden else self.encoder.out_channels, self.encoder.count)
        if self.encoder.prior_model is not None:
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


__all__ = ["PickPolicy", "mlp"]
