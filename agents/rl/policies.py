"""RL policies as plain modules: the shared :class:`TreeEncoder` + the library's action head.

A trained SB3 or TorchRL agent holds its policy inside library objects (an SB3
``ActorCriticPolicy``, a TorchRL ``ProbabilisticActor``) that cannot be stored with
``torch.load(weights_only=True)``. The classes here are the same networks as small
``nn.Module`` s with the same parameter layout, so a policy is exported by copying tensors
(:func:`policy_from_sb3`, :func:`policy_from_torchrl`), saved in the one checkpoint format
(:mod:`agents.checkpoints`, one kind per policy type) and turned into a sampler by
:mod:`agents.rl.sampler`. Every policy acts in ``[-1, 1]^d`` (the action box of
:func:`gnn_mp_envs.envs.wrappers.make_rl_env`) and returns the parameters of its Normal:

=====================  ====================  ===============================================
kind                   class                 action from ``(loc, scale)``
=====================  ====================  ===============================================
``rl/sb3-ppo``         :class:`SB3PPOPolicy`   ``clip(loc + scale * eps, -1, 1)`` (SB3 PPO's
                                             diagonal Gaussian, state-independent ``log_std``,
                                             clipped to the box as SB3 does)
``rl/sb3-sac``         :class:`SB3SACPolicy`   ``tanh(loc + scale * eps)`` (SAC's squashed
                                             Gaussian, ``log_std`` head clamped to [-20, 2])
``rl/torchrl-ppo``     :class:`TorchRLPPOPolicy` ``tanh(loc + scale * eps)`` (TorchRL's
                                             ``TanhNormal``; scale from ``NormalParamExtractor``)
=====================  ====================  ===============================================

:func:`warm_start_encoder` copies the ``TreeEncoder`` weights of any checkpoint (a supervised
sampler's, another policy's) into an encoder: the ``--init-from`` of ``gnn-mp train rl``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import torch
from torch import nn

from agents.checkpoints import CheckpointError, read_checkpoint, register_model_kind
from agents.nn.encoders import ACTIVATIONS, CandidateEncoder, TreeEncoder, encoder_class
from agents.rl.pick import PickPolicy, mlp as _mlp

#: SB3 SAC's clamp of the log standard deviation (``stable_baselines3.sac.policies``).
SAC_LOG_STD_MIN, SAC_LOG_STD_MAX = -20.0, 2.0
#: SB3's names for activation classes -> keys of :data:`agents.nn.encoders.ACTIVATIONS`.
_ACT_NAMES = {nn.ReLU: "relu", nn.Tanh: "tanh", nn.ELU: "elu", nn.SiLU: "silu"}


def encoder_config(encoder: nn.Module) -> dict[str, Any]:
    """Constructor arguments that rebuild ``encoder`` (plain values, for a checkpoint); an encoder of
    another registered class (:data:`agents.nn.encoders.ENCODERS`, e.g. ``TreeGNNEncoder``) gives its
    own, ``config()``, with its ``"class"`` name."""
    if type(encoder) is not TreeEncoder and callable(getattr(encoder, "config", None)):
        return encoder.config()
    first = encoder.tree_convs[0] if len(encoder.tree_convs) else None
    return {
        "in_channels": encoder.in_channels, "hidden_channels": encoder.hidden_channels,
        "num_layers": encoder.num_layers, "out_channels": encoder.out_channels,
        "state_dim": encoder.state_dim, "conv": encoder.conv, "knn": encoder.knn,
        "heads": int(getattr(first, "heads", 4) or 4), "act": _ACT_NAMES.get(type(encoder.act), "relu"),
        "feature_scale": encoder.feature_scale.tolist(),
        "state_low": (encoder.state_center - encoder.state_half_span).tolist(),
        "state_high": (encoder.state_center + encoder.state_half_span).tolist(),
        "features": encoder.features,
    }


class RLPolicy(nn.Module):
    """Base: ``obs -> encoder -> (loc, scale)`` in the ``[-1, 1]`` action box.

    ``squash`` says how a Normal draw ``z`` becomes an action: ``"clip"`` or ``"tanh"``.
    ``forward(obs)`` takes a Mapping of tensors (any leading batch shape, the keys of the
    observation) and returns ``(loc, scale)`` of shape ``(*batch, action_dim)``.
    """

    squash = "tanh"

    def __init__(self, encoder: Mapping[str, Any], action_dim: int) -> None:
        super().__init__()
        config = dict(encoder)
        self.encoder = encoder_class(config.pop("class", "tree"))(**config)
        self.action_dim = int(action_dim)

    def params(self, embed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(loc, scale)`` from the graph embedding."""
        raise NotImplementedError

    def squash_action(self, z: torch.Tensor) -> torch.Tensor:
        """A Normal draw ``z`` -> the action in ``[-1, 1]^d`` (clipped, or tanh-squashed)."""
        return torch.clamp(z, -1.0, 1.0) if self.squash == "clip" else torch.tanh(z)

    def forward(self, obs: Mapping) -> tuple[torch.Tensor, torch.Tensor]:
        return self.params(self.encoder(obs)[1])


class SB3PPOPolicy(RLPolicy):
    """SB3 PPO's actor: ``mlp_extractor.policy_net`` -> ``action_net``; ``log_std`` a parameter."""

    squash = "clip"

    def __init__(self, encoder: Mapping[str, Any], action_dim: int, hidden: Sequence[int] = (64, 64),
                 activation: str = "tanh") -> None:
        super().__init__(encoder, action_dim)
        self.body = _mlp(self.encoder.out_channels, hidden, activation)
        self.mu = nn.Linear(int(hidden[-1]) if hidden else self.encoder.out_channels, self.action_dim)
        self.log_std = nn.Parameter(torch.zeros(self.action_dim))

    def params(self, embed):
        loc = self.mu(self.body(embed))
        return loc, self.log_std.exp().expand_as(loc)


class SB3SACPolicy(RLPolicy):
    """SB3 SAC's actor: ``latent_pi`` -> ``mu`` and a ``log_std`` head (clamped), tanh-squashed."""

    def __init__(self, encoder: Mapping[str, Any], action_dim: int, hidden: Sequence[int] = (256, 256),
                 activation: str = "relu") -> None:
        super().__init__(encoder, action_dim)
        self.body = _mlp(self.encoder.out_channels, hidden, activation)
        width = int(hidden[-1]) if hidden else self.encoder.out_channels
        self.mu = nn.Linear(width, self.action_dim)
        self.log_std = nn.Linear(width, self.action_dim)

    def params(self, embed):
        latent = self.body(embed)
        log_std = self.log_std(latent).clamp(SAC_LOG_STD_MIN, SAC_LOG_STD_MAX)
        return self.mu(latent), log_std.exp()


class TorchRLPPOPolicy(RLPolicy):
    """The actor of :func:`agents.rl.torchrl.make_actor`: the same Gaussian head (MLP +
    ``NormalParamExtractor``), ``TanhNormal`` on the box."""

    def __init__(self, encoder: Mapping[str, Any], action_dim: int, head_hidden: int = 64,
                 init_scale: float = 1.0) -> None:
        super().__init__(encoder, action_dim)
        from agents.rl.torchrl import make_gaussian_head
        self.head = make_gaussian_head(self.encoder.out_channels, self.action_dim, int(head_hidden),
                                       init_scale=init_scale).module

    def params(self, embed):
        return self.head(embed)


#: checkpoint kind -> policy class (continuous actions)
POLICY_KINDS: dict[str, type[RLPolicy]] = {
    "rl/sb3-ppo": SB3PPOPolicy,
    "rl/sb3-sac": SB3SACPolicy,
    "rl/torchrl-ppo": TorchRLPPOPolicy,
}
#: checkpoint kind -> policy class (candidate selection)
PICK_KINDS: dict[str, type[PickPolicy]] = {"rl/sb3-ppo-pick": PickPolicy, "rl/torchrl-ppo-pick": PickPolicy}
for _kind, _cls in {**POLICY_KINDS, **PICK_KINDS}.items():
    register_model_kind(_kind, _cls)


# ----------------------------------------------------------------------------- export
def _hidden_of(seq: nn.Sequential) -> tuple[list[int], str]:
    linears = [m for m in seq if isinstance(m, nn.Linear)]
    acts = [m for m in seq if not isinstance(m, nn.Linear)]
    act = _ACT_NAMES.get(type(acts[0]), None) if acts else "tanh"
    if act is None:
        raise ValueError(f"unsupported activation {type(acts[0]).__name__} (known: {sorted(_ACT_NAMES.values())})")
    return [m.out_features for m in linears], act


def policy_from_sb3(model: Any) -> tuple[nn.Module, str, dict[str, Any]]:
    """``(policy, kind, ctor_args)`` holding a copy of an SB3 PPO or SAC model's actor (a PPO over
    ``Discrete`` candidate actions: a :class:`PickPolicy`)."""
    from gymnasium import spaces
    from stable_baselines3 import PPO, SAC
    if isinstance(model, PPO) and isinstance(model.action_space, spaces.Discrete):
        sb3 = model.policy
        encoder = sb3.pi_features_extractor.encoder
        if not isinstance(encoder, CandidateEncoder):
            raise TypeError(f"a Discrete-action PPO is exported with a CandidateFeaturesExtractor, "
                            f"not {type(encoder).__name__}")
        hidden, act = _hidden_of(sb3.mlp_extractor.policy_net)
        args = {"encoder": encoder.config(), "hidden": hidden, "activation": act,
                "head": getattr(sb3, "pick_head", "linear")}
        policy = PickPolicy(**args)
        policy.encoder.load_state_dict(encoder.state_dict())
        policy.body.load_state_dict(sb3.mlp_extractor.policy_net.state_dict())
        policy.logits.load_state_dict(sb3.action_net.state_dict())
        return policy.eval(), "rl/sb3-ppo-pick", args
    if isinstance(model, PPO):
        sb3 = model.policy
        encoder = sb3.pi_features_extractor.encoder
        hidden, act = _hidden_of(sb3.mlp_extractor.policy_net)
        args = {"encoder": encoder_config(encoder), "action_dim": sb3.action_net.out_features,
                "hidden": hidden, "activation": act}
        policy = SB3PPOPolicy(**args)
        policy.encoder.load_state_dict(encoder.state_dict())
        policy.body.load_state_dict(sb3.mlp_extractor.policy_net.state_dict())
        policy.mu.load_state_dict(sb3.action_net.state_dict())
        policy.log_std.data.copy_(sb3.log_std.data)
        return policy.eval(), "rl/sb3-ppo", args
    if isinstance(model, SAC):
        actor = model.policy.actor
        encoder = actor.features_extractor.encoder
        hidden, act = _hidden_of(actor.latent_pi)
        args = {"encoder": encoder_config(encoder), "action_dim": actor.mu.out_features, "hidden": hidden,
                "activation": act}
        policy = SB3SACPolicy(**args)
        policy.encoder.load_state_dict(encoder.state_dict())
        policy.body.load_state_dict(actor.latent_pi.state_dict())
        policy.mu.load_state_dict(actor.mu.state_dict())
        policy.log_std.load_state_dict(actor.log_std.state_dict())
        return policy.eval(), "rl/sb3-sac", args
    raise TypeError(f"cannot export a {type(model).__name__} (PPO and SAC are supported)")


def policy_from_torchrl(actor: Any) -> tuple[nn.Module, str, dict[str, Any]]:
    """``(policy, kind, ctor_args)`` holding a copy of an :func:`agents.rl.torchrl.make_actor` actor (or of a
    :func:`~agents.rl.torchrl.make_pick_actor` picker)."""
    inner = [m for m in actor.modules() if isinstance(m, PickPolicy)]
    if inner:
        source = inner[0]
        args = {"encoder": source.encoder.config(), "hidden": [m.out_features for m in source.body
                                                               if isinstance(m, nn.Linear)],
                "activation": _hidden_of(source.body)[1] if len(source.body) else "tanh", "head": source.head}
        policy = PickPolicy(**args)
        policy.load_state_dict(source.state_dict())
        return policy.eval(), "rl/torchrl-ppo-pick", args
    sequential = actor.module[0] if hasattr(actor, "module") else actor
    encoder_module, head = sequential.module[0], sequential.module[1]
    encoder = encoder_module.encoder
    mlp, extractor = head.module[0], head.module[1]
    linears = [m for m in mlp.modules() if isinstance(m, nn.Linear)]
    mapping = extractor.scale_mapping
    init_scale = float(mapping.forward(torch.zeros(1)).item()) if isinstance(mapping, nn.Module) else 1.0
    args = {"encoder": encoder_config(encoder), "action_dim": linears[-1].out_features // 2,
            "head_hidden": linears[0].out_features, "init_scale": round(init_scale, 6)}
    policy = TorchRLPPOPolicy(**args)
    policy.encoder.load_state_dict(encoder.state_dict())
    policy.head.load_state_dict(head.module.state_dict())
    return policy.eval(), "rl/torchrl-ppo", args


# ----------------------------------------------------------------------------- warm start
def backbone(encoder: nn.Module) -> nn.Module:
    """The module whose weights a warm start copies: the ``TreeEncoder`` itself, or an encoder's
    ``backbone`` (the ``TreeGNN`` inside a ``TreeGNNEncoder``, the supervised GNN sampler's class)."""
    return getattr(encoder, "backbone", encoder)


def encoder_state_from(state: Mapping[str, torch.Tensor], encoder: nn.Module) -> tuple[str, dict]:
    """``(prefix, encoder_state)``: the entries of ``state`` under the first prefix that holds
    every parameter and buffer of ``encoder``'s backbone with the same shapes."""
    own = backbone(encoder).state_dict()
    anchor = next(iter(own))
    prefixes = sorted({k[: -len(anchor)] for k in state if k.endswith(anchor)}, key=lambda p: (len(p), p))
    mismatches = []
    for prefix in prefixes:
        sub = {k: state.get(prefix + k) for k in own}
        if any(v is None for v in sub.values()):
            continue
        bad = [k for k in own if tuple(sub[k].shape) != tuple(own[k].shape)]
        if bad:
            mismatches.append(f"{prefix or '<root>'}: {bad[0]} {tuple(sub[bad[0]].shape)} vs {tuple(own[bad[0]].shape)}")
            continue
        return prefix, sub
    detail = f" (shape mismatch: {'; '.join(mismatches[:2])})" if mismatches else ""
    raise ValueError(f"no {type(backbone(encoder)).__name__} of this size in the checkpoint{detail}")


def warm_start_encoder(path: str | Path, *encoders: nn.Module) -> str:
    """Copy the backbone weights of checkpoint ``path`` into each of ``encoders``.

    Works for any kind whose state dict holds the same backbone (a ``TreeEncoder``, or the
    ``TreeGNN`` of a ``TreeGNNEncoder``) of the same size under some prefix: the supervised
    GNN sampler's (``tree/gnn``: at the root), a GNN-CVAE's, an RL policy's. Returns the checkpoint's kind and
    the prefix used, e.g. ``"rl/sb3-ppo:encoder."``. Raises ``CheckpointError`` for an
    unusable file and ``ValueError`` when no encoder of the right size is found.
    """
    record = read_checkpoint(path)
    prefix = ""
    for encoder in encoders:
        try:
            prefix, sub = encoder_state_from(record["state_dict"], encoder)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
        backbone(encoder).load_state_dict(sub)
    return f"{record['kind']}:{prefix}"


__all__ = ["PICK_KINDS", "POLICY_KINDS", "PickPolicy", "RLPolicy", "SB3PPOPolicy", "SB3SACPolicy", "TorchRLPPOPolicy", "CheckpointError",
           "encoder_config", "encoder_state_from", "policy_from_sb3", "policy_from_torchrl", "warm_start_encoder"]
