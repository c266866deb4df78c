"""Trained RL policies as samplers of the shared interface (``rl-ppo``, ``rl-sac``, ``rl-ppo-torchrl``).

:class:`RLSampler` is a :class:`~agents.samplers.learned.LearnedSampler` around a policy of
:mod:`agents.models.rl`. It applies what training applied: the bounded view of the tree
(:func:`gnn_mp_envs.envs.wrappers.tree_view`, ``view_nodes`` rows, read from the checkpoint)
and the action map of :func:`~gnn_mp_envs.envs.wrappers.make_rl_env` (the policy acts in
``[-1, 1]^d``: offsets from the active tree's target in box spans, ``action_frame="target"``,
or the box rescaled, ``"absolute"``; stored in the checkpoint with the periodic dimensions). Its randomness is its own: the Normal
draw is ``torch.randn(*batch, d, generator=self.generator)`` (then, with ``uniform_mix > 0``,
the uniform sample and the choice, as in ``LearnedSampler``), never ``model.predict``, so the
benchmark's ``reset(seed)`` reproduces every action.

    sampler = load_sampler("rl-ppo", low, high, task="maze2d", seed=0)            # shipped weights
    sampler = load_sampler("rl-ppo", low, high, task="maze2d", checkpoint="runs/.../policy.pt")

Checkpoints are the one format of :mod:`agents.checkpoints` (kinds ``rl/sb3-ppo``,
``rl/sb3-sac``, ``rl/torchrl-ppo``); ``meta`` holds ``task``, ``view_nodes``, the action
bounds and the sampler defaults (``uniform_mix``, chosen on split ``val``). The shipped ones
are ``agents/checkpoints/<name>_<task>.pt``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn

from agents.checkpoints import (
    SHIPPED_DIR,
    load_checkpoint,
    resolve_checkpoint,
    save_checkpoint,
)
from agents.encoders import EncoderModule
from agents.models.rl import POLICY_KINDS, RLPolicy
from agents.samplers.base import batch_shape_of
from agents.samplers.learned import LearnedSampler
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS
from gnn_mp_envs.envs.wrappers import ACTION_FRAMES, ACTION_HIGH, ACTION_LOW, tree_view

#: sampler name -> checkpoint kind
RL_SAMPLERS: dict[str, str] = {"rl-ppo": "rl/sb3-ppo", "rl-sac": "rl/sb3-sac", "rl-ppo-torchrl": "rl/torchrl-ppo"}
#: checkpoint kind -> sampler name
SAMPLER_OF_KIND = {kind: name for name, kind in RL_SAMPLERS.items()}


class _Params(nn.Module):
    """``embed -> (loc, scale)`` of a policy, as the head of a ``LearnedSampler``."""

    def __init__(self, policy: RLPolicy) -> None:
        super().__init__()
        self.policy = policy

    def forward(self, embed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.policy.params(embed)


class RLSampler(LearnedSampler):
    """A trained policy as a sampler: view -> encoder -> ``(loc, scale)`` -> action in ``[low, high]``.

    Args:
        low, high, seed: as for every sampler (the task's state bounds).
        policy: an :class:`~agents.models.rl.RLPolicy` (acts in ``[-1, 1]^d``).
        view_nodes: rows of the tree view the policy was trained on.
        uniform_mix: probability of a uniform sample instead of the policy's.
        deterministic: use the policy's mean (no draw).
    """

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, policy: RLPolicy,
                 view_nodes: int, uniform_mix: float = 0.0, deterministic: bool = False,
                 action_frame: str = "absolute", periodic: list[bool] | None = None) -> None:
        head = TensorDictModule(_Params(policy), in_keys=["embed"], out_keys=["loc", "scale"])
        super().__init__(low, high, seed, encoder=EncoderModule(policy.encoder), head=head,
                         uniform_mix=uniform_mix, deterministic=deterministic)
        if policy.action_dim != self.state_dim:
            raise ValueError(f"the policy acts in {policy.action_dim} dimensions, the bounds have {self.state_dim}")
        if action_frame not in ACTION_FRAMES:
            raise ValueError(f"action_frame must be one of {ACTION_FRAMES}, got {action_frame!r}")
        self.policy = policy
        self.view_nodes = int(view_nodes)
        self.squash = policy.squash
        self.action_frame = action_frame
        periodic = [False] * self.state_dim if periodic is None else [bool(p) for p in periodic]
        self.register_buffer("periodic", torch.tensor(periodic, dtype=torch.bool), persistent=False)

    # ------------------------------------------------------------------ distribution
    @staticmethod
    def _target(view: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The active tree's target per observation: the start for tree 1, else the goal."""
        active = view["active_tree"].reshape(*view["start"].shape[:-1], 1)
        return torch.where(active == 1, view["start"], view["goal"])

    def to_box(self, u: torch.Tensor, view: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """``[-1, 1]^d`` -> a state, as ``make_rl_env`` maps actions: ``RescaleAction`` (absolute
        frame) or ``TargetRelativeAction`` (offsets from the active tree's target, periodic
        dimensions wrapped), then clipped to the box."""
        if self.action_frame == "absolute":
            a = self.low + self.span * (u - ACTION_LOW) / (ACTION_HIGH - ACTION_LOW)
        else:
            a = self._target(view).to(u.dtype) + u * self.span
            a = torch.where(self.periodic, self.low + torch.remainder(a - self.low, self.span), a)
        return torch.minimum(torch.maximum(a, self.low), self.high)

    def log_prob(self, loc, scale, action, view=None):
        """Log-density of the mixture at ``action`` (approximate where the box clips or wraps)."""
        if self.action_frame == "target":
            u = ((action - self._target(view)) / self.span).clamp(ACTION_LOW, ACTION_HIGH)
            jac = torch.log(self.span).sum()
        else:
            u = (action - self.low) / self.span * (ACTION_HIGH - ACTION_LOW) + ACTION_LOW
            jac = torch.log(self.span / 2).sum()
        if self.squash == "tanh":
            u = u.clamp(-1 + 1e-6, 1 - 1e-6)
            model = (torch.distributions.Normal(loc, scale).log_prob(torch.atanh(u)) - torch.log1p(-u * u)).sum(-1) - jac
        else:   # "clip": the Normal's density inside the box (the clipped mass on the border is ignored)
            model = torch.distributions.Normal(loc, scale).log_prob(u).sum(-1) - jac
        return self.mix_log_prob(model)

    def sample(self, view: Mapping[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """``(embed, loc, scale, action)`` for viewed observations (a dict of tensors, no TensorDict:
        building one costs more than the encoder on a single observation)."""
        embed = self.policy.encoder(view)[1]
        loc, scale = self.policy.params(embed)
        z = loc if self.deterministic else loc + scale * torch.randn(loc.shape, generator=self.generator)
        u = torch.clamp(z, ACTION_LOW, ACTION_HIGH) if self.squash == "clip" else torch.tanh(z)
        return embed, loc, scale, self.mix_uniform(self.to_box(u, view))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Full observations in; ``"embed"``, ``"loc"``, ``"scale"``, ``"action"`` and the log-prob out."""
        view = self.view(tensordict)
        embed, loc, scale, action = self.sample(view)
        tensordict.set("embed", embed)
        tensordict.set("loc", loc)
        tensordict.set("scale", scale)
        tensordict.set("action", action)
        tensordict.set(self.log_prob_key, self.log_prob(loc, scale, action, view))
        return tensordict

    # ------------------------------------------------------------------ the view
    def view(self, obs: Mapping) -> dict[str, torch.Tensor]:
        """The policy's view of (possibly batched) full observations, as a dict of tensors."""
        shape = batch_shape_of(obs["start"])
        arrays = {k: np.asarray(obs[k].cpu() if isinstance(obs[k], torch.Tensor) else obs[k]) for k in OBSERVATION_KEYS}
        if len(shape) == 0:
            views = tree_view(arrays, self.view_nodes)
        else:
            b = int(np.prod(shape))
            flat = {k: v.reshape(b, *v.shape[len(shape):]) for k, v in arrays.items()}
            items = [tree_view({k: v[i] for k, v in flat.items()}, self.view_nodes) for i in range(b)]
            views = {k: np.stack([it[k] for it in items]).reshape(*shape, *items[0][k].shape) for k in items[0]}
        return {k: torch.as_tensor(v) for k, v in views.items()}

    def propose(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.sample(self.view(obs))[-1]

    def act(self, obs: Mapping) -> np.ndarray:
        with torch.no_grad():
            return np.asarray(self.propose(obs).numpy(), dtype=np.float32)


# ----------------------------------------------------------------------------- files
def save_policy(path: str | Path, policy: RLPolicy, kind: str, ctor_args: Mapping[str, Any], *, task: str,
                view_nodes: int, low: np.ndarray, high: np.ndarray, uniform_mix: float = 0.0,
                action_frame: str = "absolute", periodic: list[bool] | None = None,
                meta: Mapping[str, Any] | None = None) -> Path:
    """Write a policy checkpoint that :func:`load_rl_sampler` turns into a sampler."""
    obs_spec = {"view_nodes": int(view_nodes), "state_dim": int(len(low)), "action_box": [ACTION_LOW, ACTION_HIGH],
                "action_frame": action_frame, "periodic": list(periodic or [False] * len(low)),
                "low": np.asarray(low, np.float64).tolist(), "high": np.asarray(high, np.float64).tolist()}
    full_meta = {"task": task, "view_nodes": int(view_nodes), "sampler": {"uniform_mix": float(uniform_mix)},
                 **dict(meta or {})}
    return save_checkpoint(path, policy, kind, ctor_args, obs_spec=obs_spec, meta=full_meta)


def shipped_checkpoint(name: str, task: str) -> Path:
    """Where the shipped weights of sampler ``name`` for ``task`` live."""
    return SHIPPED_DIR / f"{name}_{task}.pt"


def sampler_from_checkpoint(path: str | Path, low: np.ndarray, high: np.ndarray, *, seed: int | None = None,
                            kind: str | None = None, task: str | None = None, uniform_mix: float | None = None,
                            deterministic: bool = False) -> RLSampler:
    """An :class:`RLSampler` from a policy checkpoint (``uniform_mix=None``: the file's default)."""
    policy, record = load_checkpoint(path, expected_kind=kind or list(POLICY_KINDS))
    meta, spec = record["meta"], record["obs_spec"] or {}
    if task is not None and meta.get("task") not in (None, task):
        raise ValueError(f"{path}: a policy for task {meta.get('task')!r}, not {task!r}")
    if "low" in spec and (len(spec["low"]) != len(low) or not np.allclose(spec["low"], low, atol=1e-5)
                          or not np.allclose(spec["high"], high, atol=1e-5)):
        raise ValueError(f"{path}: trained for bounds {spec['low']}..{spec['high']}, "
                         f"not {np.asarray(low).tolist()}..{np.asarray(high).tolist()}")
    if uniform_mix is None:
        uniform_mix = float(meta.get("sampler", {}).get("uniform_mix", 0.0))
    return RLSampler(low, high, seed, policy=policy, view_nodes=int(meta.get("view_nodes", spec.get("view_nodes"))),
                     uniform_mix=uniform_mix, deterministic=deterministic,
                     action_frame=spec.get("action_frame", "absolute"), periodic=spec.get("periodic")).eval()


def load_rl_sampler(name: str, low: np.ndarray, high: np.ndarray, task: str | None = None, seed: int | None = None,
                    checkpoint: str | Path | None = None, uniform_mix: float | None = None,
                    deterministic: bool = False, threads: int | None = 1) -> RLSampler:
    """The registry factory of ``rl-ppo``, ``rl-sac`` and ``rl-ppo-torchrl``.

    ``threads``: torch threads for the process (``torch.set_num_threads``; None leaves them).
    The policy runs on one small graph per call, where more threads only add contention:
    measured 0.8 ms per ``act`` with 1 thread against 12 ms with 2 on the loaded 2-core machine.
    """
    if threads is not None and torch.get_num_threads() != int(threads):
        torch.set_num_threads(int(threads))
    kind = RL_SAMPLERS[name]
    checkpoint = resolve_checkpoint(name, task, checkpoint, shipped_checkpoint(name, task) if task else None,
                                    f"gnn-mp train rl --task {task}")
    return sampler_from_checkpoint(checkpoint, low, high, seed=seed, kind=kind, task=task,
                                   uniform_mix=uniform_mix, deterministic=deterministic)


__all__ = ["RL_SAMPLERS", "RLSampler", "load_rl_sampler", "sampler_from_checkpoint", "save_policy",
           "shipped_checkpoint"]
