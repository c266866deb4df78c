"""TorchRL actor and value head over the shared :class:`agents.nn.encoders.TreeEncoder`.

    from torchrl.envs import GymEnv
    env = GymEnv("GNNMP/Maze2DRRT-v0", max_nodes=200)
    encoder = EncoderModule.from_space(gym_env.observation_space)      # optional, to share it
    actor = make_actor(gym_env.observation_space, gym_env.action_space, encoder=encoder)
    value = make_value(gym_env.observation_space, encoder=encoder)
    rollout = env.rollout(256, actor)          # "embed", "loc", "scale", "action", log-prob
    value(rollout)                             # "state_value" (T, 1)

This module is ``agents.rl.torchrl``; it imports the TorchRL package absolutely (``import
torchrl`` anywhere resolves to the installed package, never to this file).
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

from agents.nn.encoders import CandidateEncoder
from agents.rl.backbones import EncoderModule
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS

#: The observation keys a candidate picker reads (the tree view's, with a tree context).
PICK_KEYS = ("candidate_features",)


def _encoder(observation_space: spaces.Dict, encoder: EncoderModule | None, encoder_kw: dict) -> EncoderModule:
    if encoder is not None:
        if encoder_kw:
            raise ValueError("pass either an encoder or encoder keyword arguments, not both")
        return encoder
    return EncoderModule.from_space(observation_space, **encoder_kw)


def make_gaussian_head(embed_dim: int, action_dim: int, hidden: int = 64, num_cells: int = 2,
                       in_key: str = "embed", init_scale: float = 1.0) -> TensorDictModule:
    """``"embed"`` -> ``"loc"``, ``"scale"`` (pre-squash Normal parameters), an MLP.

    ``init_scale``: the scale for a zero MLP output (``NormalParamExtractor``'s biased softplus).
    """
    net = nn.Sequential(MLP(in_features=embed_dim, out_features=2 * action_dim, num_cells=[hidden] * num_cells,
                            activation_class=nn.ReLU),
                        NormalParamExtractor(scale_mapping=f"biased_softplus_{float(init_scale)}"))
    return TensorDictModule(net, in_keys=[in_key], out_keys=["loc", "scale"])


def make_actor(observation_space: spaces.Dict, action_space: spaces.Box, *, encoder: EncoderModule | None = None,
               head_hidden: int = 64, init_scale: float = 1.0, **encoder_kw) -> ProbabilisticActor:
    """encoder -> ``"embed"`` -> Gaussian head -> ``"loc"``/``"scale"`` -> ``TanhNormal`` on the box.

    ``return_log_prob=True``: the actor writes the action's log-probability under TorchRL's
    default key (``actor.log_prob_key``; ``"action_log_prob"`` in TorchRL 0.14, what
    ``ClipPPOLoss`` reads). ``encoder_kw`` go to ``TreeEncoder.from_space`` (or pass a built
    ``encoder`` to share it with :func:`make_value`); ``init_scale`` is the head's initial scale.
    """
    enc = _encoder(observation_space, encoder, encoder_kw)
    low = torch.as_tensor(np.asarray(action_space.low, np.float32))
    high = torch.as_tensor(np.asarray(action_space.high, np.float32))
    head = make_gaussian_head(enc.out_channels, int(low.shape[-1]), head_hidden, in_key=enc.out_keys[0],
                              init_scale=init_scale)
    return ProbabilisticActor(TensorDictSequential(enc, head), in_keys=["loc", "scale"], out_keys=["action"],
                              distribution_class=TanhNormal, distribution_kwargs={"low": low, "high": high},
                              return_log_prob=True)


def make_value(observation_space: spaces.Dict, encoder: EncoderModule | None = None, *, hidden: int = 64,
               **encoder_kw) -> TensorDictSequential:
    """encoder -> ``"embed"`` -> MLP -> ``"state_value"`` ``(*batch, 1)``.

    Pass the actor's ``encoder`` to share it (one set of GNN weights for actor and critic);
    otherwise a new encoder of the same class is built from ``encoder_kw``.
    """
    enc = _encoder(observation_space, encoder, encoder_kw)
    net = MLP(in_features=enc.out_channels, out_features=1, num_cells=[hidden, hidden], activation_class=nn.ReLU)
    return TensorDictSequential(enc, ValueOperator(net, in_keys=[enc.out_keys[0]]))



class PickModule(TensorDictModuleBase):
    """A :class:`~agents.rl.policies.PickPolicy` (or a value net over a :class:`CandidateEncoder`) as a
    TensorDict module: ``candidate_features`` (and, with a tree context, the view's keys) in, ``out_key`` out."""

    def __init__(self, net: nn.Module, out_key: str, reads_tree: bool) -> None:
        super().__init__()
        self.net = net
        self.in_keys = list(PICK_KEYS) + (list(OBSERVATION_KEYS) if reads_tree else [])
        self.out_keys = [out_key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict.set(self.out_keys[0], self.net(tensordict))
        return tensordict


class CandidateValue(nn.Module):
    """``CandidateEncoder.flat`` -> MLP -> the state value ``(*batch, 1)``."""

    def __init__(self, encoder: CandidateEncoder, hidden: list[int]) -> None:
        super().__init__()
        self.encoder = encoder
        self.mlp = MLP(in_features=encoder.out_channels, out_features=1, num_cells=list(hidden),
                       activation_class=nn.Tanh)

    def forward(self, obs) -> torch.Tensor:
        return self.mlp(self.encoder.flat(obs))


def make_pick_actor(observation_space: spaces.Dict, *, action_spec=None, head_hidden: list[int] | tuple[int, ...] = (),
                    head: str = "linear", **encoder_kw) -> ProbabilisticActor:
    """A candidate picker: ``PickPolicy`` -> ``"logits"`` -> a categorical over the candidates.

    The action is in the encoding of ``action_spec``, the TorchRL env's: a one-hot vector (a
    ``OneHot`` spec) or the candidate's index (``Categorical``, what
    ``GymEnv(id, categorical_action_encoding=True)`` takes). Without a spec it is one-hot, TorchRL's
    default for a ``Discrete`` space, so ``GymEnv(id)`` and this actor work together as they are (an
    index read as one-hot by TorchRL would become candidate 0 every step; a one-hot vector sent to an
    env that reads indices is refused in one line). ``return_log_prob=True`` as ``ClipPPOLoss`` needs;
    ``head``: :class:`~agents.rl.pick.PickPolicy`'s. ``encoder_kw`` go to
    ``CandidateEncoder.from_space`` (``hidden``, ``embed``, ``tree_context``, ...).
    """
    from torchrl.data import Categorical as IndexSpec
    from torchrl.data import OneHot
    from torchrl.modules import OneHotCategorical
    if action_spec is not None and not isinstance(action_spec, (OneHot, IndexSpec)):
        raise ValueError(f"a picker acts in a Discrete action space (one-hot or index), not {type(action_spec).__name__}")
    one_hot = action_spec is None or isinstance(action_spec, OneHot)
    from agents.rl.pick import PickPolicy
    encoder = CandidateEncoder.from_space(observation_space, **encoder_kw)
    policy = PickPolicy(encoder.config(), hidden=list(head_hidden), activation="tanh", head=head)
    policy.encoder.load_state_dict(encoder.state_dict())
    module = PickModule(policy, "logits", policy.reads_tree)
    return ProbabilisticActor(module, in_keys=["logits"], out_keys=["action"], spec=action_spec,
                              distribution_class=OneHotCategorical if one_hot else torch.distributions.Categorical,
                              return_log_prob=True)


def make_pick_value(observation_space: spaces.Dict, *, head_hidden: list[int] | tuple[int, ...] = (64, 64),
                    **encoder_kw) -> TensorDictModuleBase:
    """``CandidateEncoder`` (its own) -> MLP -> ``"state_value"``."""
    encoder = CandidateEncoder.from_space(observation_space, **encoder_kw)
    return PickModule(CandidateValue(encoder, list(head_hidden)), "state_value", encoder.tree is not None)
