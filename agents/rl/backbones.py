"""RL backbones: the encoder by name (:data:`agents.nn.encoders.ENCODERS`, the shared floor's
registry: ``"tree"``, the :class:`~agents.nn.encoders.TreeEncoder`; ``"tree-gnn"``, the supervised
GNN sampler's causal backbone, :class:`agents.tree.backbone.TreeGNNEncoder`) and the TensorDict
module that wraps one.

:class:`EncoderModule` is an encoder as a TensorDict module (observation keys in, ``"embed"``
out): the first stage of the TorchRL actor and value head (:mod:`agents.rl.torchrl`);
:class:`agents.rl.sb3.TreeFeaturesExtractor` wraps an encoder for Stable-Baselines3.
"""

from __future__ import annotations

from gymnasium import spaces
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn

from agents.nn.encoders import ENCODERS, encoder_from_space
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS


class EncoderModule(TensorDictModuleBase):
    """A :class:`TreeEncoder` as a TensorDict module: observation keys in, ``"embed"`` out.

    ``EncoderModule.from_space(observation_space, **encoder_kwargs)`` builds the encoder
    (``backbone="tree-gnn"``: the GNN sampler's backbone instead); ``module.encoder`` is it,
    ``module.out_channels`` its embedding width. Node embeddings are not written (their
    number varies per observation).
    """

    def __init__(self, encoder: nn.Module, out_key: str = "embed") -> None:
        super().__init__()
        self.encoder = encoder
        self.in_keys = list(OBSERVATION_KEYS)
        self.out_keys = [out_key]

    @classmethod
    def from_space(cls, observation_space: spaces.Dict, out_key: str = "embed", **kwargs) -> "EncoderModule":
        return cls(encoder_from_space(observation_space, **kwargs), out_key=out_key)

    @property
    def out_channels(self) -> int:
        return self.encoder.out_channels

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        _, embed, _ = self.encoder(tensordict)
        tensordict.set(self.out_keys[0], embed)
        return tensordict


__all__ = ["ENCODERS", "EncoderModule", "encoder_from_space"]
