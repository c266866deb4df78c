"""The sampler interface: observation in, next sample out.

Every sampler (uniform, goal-biased, GNN, GAT, CVAE, GNN-CVAE, RL policy) is a
``torch.nn.Module`` whose ``forward`` takes the observation keys in
:data:`SAMPLER_IN_KEYS` order and returns the action. :meth:`Sampler.as_module` wraps
it as a TorchRL ``TensorDictModule`` (``in_keys`` = observation keys, ``out_keys`` =
``["action"]``); :meth:`Sampler.act` serves plain Gymnasium loops with numpy dicts.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn

from gnn_mp_envs.envs.observation import OBSERVATION_KEYS

SAMPLER_IN_KEYS: tuple[str, ...] = OBSERVATION_KEYS
SAMPLER_OUT_KEYS: tuple[str, ...] = ("action",)


class Sampler(nn.Module):
    """Base class: holds the sampling bounds and a seeded torch generator."""

    in_keys = list(SAMPLER_IN_KEYS)
    out_keys = list(SAMPLER_OUT_KEYS)

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None) -> None:
        super().__init__()
        low = torch.as_tensor(np.asarray(low, dtype=np.float32))
        high = torch.as_tensor(np.asarray(high, dtype=np.float32))
        if low.shape != high.shape or low.dim() != 1 or not torch.all(high > low):
            raise ValueError(f"sampler bounds must be 1-D with high > low, got {low} and {high}")
        self.register_buffer("low", low)
        self.register_buffer("high", high)
        self.generator = torch.Generator()
        self.reset(seed)

    @property
    def state_dim(self) -> int:
        return int(self.low.shape[0])

    def reset(self, seed: int | None = None) -> None:
        """Reseed the sampler's random stream (None draws a fresh seed from the OS)."""
        if seed is None:
            self.generator.seed()
        else:
            self.generator.manual_seed(int(seed))

    def uniform(self, batch_shape: torch.Size) -> torch.Tensor:
        u = torch.rand(*batch_shape, self.state_dim, generator=self.generator)
        return self.low + u * (self.high - self.low)

    def forward(self, nodes, node_features, parent, mask, num_nodes, start, goal, active_tree):
        raise NotImplementedError

    # ------------------------------------------------------------------ adapters
    def as_module(self) -> TensorDictModule:
        """This sampler as a TorchRL policy reading the observation keys, writing ``action``."""
        return TensorDictModule(self, in_keys=list(self.in_keys), out_keys=list(self.out_keys))

    @torch.no_grad()
    def act(self, obs: Mapping) -> np.ndarray:
        """Next sample for one (unbatched) numpy observation, for plain Gymnasium loops."""
        args = [torch.as_tensor(np.asarray(obs[k])) for k in self.in_keys]
        return self(*args).detach().cpu().numpy().astype(np.float32)


def batch_shape_of(start: torch.Tensor) -> torch.Size:
    """Leading batch dimensions of an observation, read off its ``start`` entry."""
    return start.shape[:-1]
