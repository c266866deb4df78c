"""The hook for learned samplers: encoder -> ``"embed"`` -> head -> ``"loc"``/``"scale"`` -> action.

A :class:`LearnedSampler` composes three TensorDict stages and a bounded distribution:

1. ``encoder``: an :class:`agents.encoders.EncoderModule` (observation keys -> ``"embed"``);
2. ``head``: any TensorDict module with ``in_keys=["embed"]``, ``out_keys=["loc", "scale"]``
   (e.g. ``TensorDictModule(nn.Sequential(MLP, NormalParamExtractor()), ...)``);
3. a tanh-squashed Normal on the action box (TorchRL's ``TanhNormal(loc, scale, low, high)``),
   mixed with uniform samples at rate ``uniform_mix`` (the classical trick that keeps a learned
   sampler probabilistically complete).

Random draws, all from ``self.generator`` in this order: ``torch.randn(*batch, d)`` (the
Normal), then, only if ``uniform_mix > 0``, ``torch.rand(*batch, d)`` (the uniform sample) and
``torch.rand(*batch, 1)`` (the choice). ``forward`` writes ``"embed"``, ``"loc"``, ``"scale"``,
``"action"`` and ``self.log_prob_key`` (the log-density of the mixture at the action).
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.modules import TanhNormal

from agents.samplers.base import SAMPLER_IN_KEYS, Sampler, batch_shape_of


class LearnedSampler(Sampler):
    """Encoder + Gaussian head + tanh-squashed Normal on ``[low, high]``, mixed with uniform.

    Args:
        low, high, seed: as for every :class:`Sampler`.
        encoder: observation keys -> ``"embed"`` (an ``EncoderModule``).
        head: ``"embed"`` -> ``"loc"``, ``"scale"`` (pre-tanh Normal parameters, ``(*batch, d)``).
        uniform_mix: probability of returning a uniform sample instead of the model's.
        deterministic: return ``tanh(loc)`` mapped to the box instead of a sample (no mixing).
        log_prob_key: where ``forward`` writes the log-density of the returned action.

    Subclasses (GNN, GNN-CVAE, RL policies) may override :meth:`distribution` or
    :meth:`forward`; the registry factory should call ``.eval()``. ``act`` runs under
    ``torch.no_grad()``.
    """

    reads = SAMPLER_IN_KEYS

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *,
                 encoder: TensorDictModuleBase, head: TensorDictModuleBase, uniform_mix: float = 0.0,
                 deterministic: bool = False, log_prob_key: str = "sample_log_prob") -> None:
        if not 0.0 <= uniform_mix <= 1.0:
            raise ValueError(f"uniform_mix must be in [0, 1], got {uniform_mix}")
        super().__init__(low, high, seed)
        if list(head.in_keys) != list(encoder.out_keys):
            raise ValueError(f"head reads {list(head.in_keys)} but the encoder writes {list(encoder.out_keys)}")
        if len(head.out_keys) != 2:
            raise ValueError(f"head must write (loc, scale), got out_keys {list(head.out_keys)}")
        self.encoder = encoder
        self.head = head
        self.uniform_mix = float(uniform_mix)
        self.deterministic = bool(deterministic)
        self.log_prob_key = log_prob_key
        self.out_keys = [*encoder.out_keys, *head.out_keys, "action", log_prob_key]

    def distribution(self, loc: torch.Tensor, scale: torch.Tensor) -> TanhNormal:
        """The model's distribution over the action box for Normal parameters ``loc``/``scale``."""
        return TanhNormal(loc, scale, low=self.low, high=self.high)

    def log_prob(self, loc: torch.Tensor, scale: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """``log((1 - m) p_model(action) + m / volume)``, ``(*batch,)``."""
        return self.mix_log_prob(self.distribution(loc, scale).log_prob(action))

    def mix_log_prob(self, model: torch.Tensor) -> torch.Tensor:
        """The model's log-density ``model`` mixed with the uniform one at rate ``uniform_mix``."""
        if self.uniform_mix == 0.0:
            return model
        log_uniform = -torch.log(self.span).sum()
        if self.uniform_mix == 1.0:
            return log_uniform.expand_as(model)
        return torch.logaddexp(model + math.log1p(-self.uniform_mix),
                               log_uniform + math.log(self.uniform_mix))

    def mix_uniform(self, action: torch.Tensor) -> torch.Tensor:
        """``action`` with each row replaced by a uniform sample at rate ``uniform_mix`` (drawn
        from the sampler's generator: the uniform states first, then the coin flips)."""
        if self.uniform_mix == 0.0 or self.deterministic:
            return action
        shape = action.shape[:-1]
        uniform = self.uniform(shape)
        pick = torch.rand(*shape, 1, generator=self.generator) < self.uniform_mix
        return torch.where(pick, uniform, action)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self.encoder(tensordict)
        self.head(tensordict)
        loc_key, scale_key = self.head.out_keys
        loc, scale = tensordict.get(loc_key), tensordict.get(scale_key)
        z = loc if self.deterministic else loc + scale * torch.randn(loc.shape, generator=self.generator)
        # Same map as TanhNormal's transform: center + half-span * tanh(z).
        action = (self.low + self.high) / 2 + self.span / 2 * torch.tanh(z)
        action = self.mix_uniform(torch.minimum(torch.maximum(action, self.low), self.high))
        tensordict.set("action", action)
        tensordict.set(self.log_prob_key, self.log_prob(loc, scale, action))
        return tensordict

    def propose(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        # A shallow copy: the caller's TensorDict does not receive "embed", "loc", ...
        td = obs.copy() if isinstance(obs, TensorDictBase) else TensorDict(
            dict(obs), batch_size=batch_shape_of(obs["start"]))
        return self.forward(td)["action"]
