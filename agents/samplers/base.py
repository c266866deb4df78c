"""The sampler interface: observation in, next sample out.

Every sampler (uniform, goal-biased, GNN, GAT, CVAE, GNN-CVAE, RL policy) is a
``tensordict.nn.TensorDictModuleBase``: ``in_keys`` are the observation keys
(:data:`SAMPLER_IN_KEYS`), ``out_keys`` start with ``"action"``. The one method a sampler
implements is :meth:`Sampler.propose`, ``Mapping[str, Tensor] -> Tensor`` over any leading
batch shape, reading only the keys it needs (listed in :attr:`Sampler.reads`):

* ``sampler(td)`` (``forward``) writes ``td["action"]``, so a sampler drops into TorchRL
  (``env.rollout(n, sampler)``, collectors) as it is;
* ``sampler.act(obs)`` serves plain Gymnasium loops: one numpy observation in, a float32
  numpy action out, converting only the keys in :attr:`Sampler.reads`;
* ``sampler.reset(seed)`` reseeds the sampler's own ``torch.Generator`` (the benchmark
  calls it before every problem); all randomness is drawn from it.

Learned samplers derive from :class:`LearnedSampler` (encoder -> ``"embed"`` -> head ->
``"loc"``/``"scale"`` -> bounded distribution, mixed with uniform samples), which also
writes ``"embed"``, ``"loc"``, ``"scale"`` and ``"sample_log_prob"``.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from gnn_mp_envs.envs.observation import OBSERVATION_KEYS

SAMPLER_IN_KEYS: tuple[str, ...] = OBSERVATION_KEYS
SAMPLER_OUT_KEYS: tuple[str, ...] = ("action",)


class Sampler(TensorDictModuleBase):
    """Base class: holds the sampling bounds and a seeded ``torch.Generator``.

    Subclasses implement :meth:`propose` and set :attr:`reads` to the observation keys it
    reads. Randomness must come from ``self.generator`` (``self.uniform(shape)``,
    ``torch.rand(..., generator=self.generator)``) so that runs are reproducible.
    """

    #: Observation keys :meth:`propose` reads; :meth:`act` converts only these.
    reads: tuple[str, ...] = SAMPLER_IN_KEYS

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None) -> None:
        super().__init__()
        self.in_keys = list(SAMPLER_IN_KEYS)
        self.out_keys = list(SAMPLER_OUT_KEYS)
        low = torch.as_tensor(np.asarray(low, dtype=np.float32))
        high = torch.as_tensor(np.asarray(high, dtype=np.float32))
        if low.shape != high.shape or low.dim() != 1 or not torch.all(high > low):
            raise ValueError(f"sampler bounds must be 1-D with high > low, got {low} and {high}")
        self.register_buffer("low", low)
        self.register_buffer("high", high)
        self.register_buffer("span", high - low, persistent=False)
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

    def uniform(self, batch_shape: torch.Size | tuple = ()) -> torch.Tensor:
        """``(*batch_shape, d)`` uniform samples in the bounds: one ``torch.rand`` call."""
        u = torch.rand(*batch_shape, self.state_dim, generator=self.generator)
        return self.low + u * self.span

    # ------------------------------------------------------------------ the core
    def propose(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """Next samples ``(*batch, d)`` for observations with leading batch shape ``batch``."""
        raise NotImplementedError

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """TensorDict in (observation keys), the same TensorDict out with ``"action"`` set."""
        tensordict.set("action", self.propose(tensordict))
        return tensordict

    # ------------------------------------------------------------------ adapters
    def as_module(self) -> TensorDictModuleBase:
        """The sampler as a TorchRL policy (it already is one; kept for older callers)."""
        return self

    def act(self, obs: Mapping) -> np.ndarray:
        """Next sample for one (unbatched) numpy observation, for plain Gymnasium loops."""
        with torch.no_grad():
            out = self.propose({k: torch.as_tensor(obs[k]) for k in self.reads})
        return np.asarray(out.cpu().numpy(), dtype=np.float32)


def batch_shape_of(start: torch.Tensor | np.ndarray) -> torch.Size:
    """Leading batch dimensions of an observation, read off its ``start`` entry."""
    return torch.Size(start.shape[:-1])
