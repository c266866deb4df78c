"""A sampler as a TorchRL policy: :class:`SamplerModule`, what :meth:`Sampler.as_module` returns.

TorchRL takes a policy that is a ``tensordict.nn.TensorDictModuleBase`` reading and writing
keys of a ``TensorDict``; a :class:`~agents.samplers.base.Sampler` is plain numpy (so the
classical samplers run without torch), and this thin module is its TorchRL face::

    rollout = GymEnv("GNNMP/Maze2DRRT-v0").rollout(50, load_sampler("uniform", task="maze2d").as_module())
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

class SamplerModule(TensorDictModuleBase):
    """``sampler.propose`` as a TensorDict module: the observation keys in, ``"action"`` out
    (``sampler``: an :class:`agents.samplers.base.Sampler`)."""

    def __init__(self, sampler) -> None:
        super().__init__()
        self.sampler = sampler
        self.in_keys = list(sampler.in_keys)
        self.out_keys = list(sampler.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict.set("action", torch.as_tensor(self.sampler.propose(tensordict)))
        return tensordict


__all__ = ["SamplerModule"]
