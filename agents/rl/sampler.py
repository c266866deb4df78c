"""Trained RL policies as samplers of the shared interface (``rl-ppo``, ``rl-sac``, ``rl-ppo-torchrl``).

:class:`RLSampler` is a :class:`~agents.samplers.base.ModelSampler` (the one uniform / goal /
model mixture, one numpy stream) around a policy of :mod:`agents.rl.policies`. It applies what
training applied: the bounded view of the tree (:func:`gnn_mp_envs.envs.wrappers.tree_view`,
``view_nodes`` rows, read from the checkpoint) and the action map of
:func:`~gnn_mp_envs.envs.wrappers.make_rl_env`
(:func:`~gnn_mp_envs.envs.wrappers.policy_action_to_state`: offsets from the active tree's
target in box spans, ``action_frame="target"``, or the box rescaled, ``"absolute"``), in
float32. Randomness comes from the sampler's one stream (never ``model.predict``), so the
benchmark's ``reset(seed)`` reproduces every action.

**Draw order.** The shipped policies' benchmark runs were recorded with torch's generator in
this order per step: the policy's Normal (``d`` normals), then, with ``uniform_mix > 0``, a
uniform state (``d`` uniforms) and the choice (one uniform). The sampler keeps exactly those
draws (a :class:`~agents.samplers.streams.TorchCompatibleStream`), so its counters are the
recorded ones; the tree samplers' mixture draws the choice first instead
(:class:`~agents.samplers.base.ModelSampler`). A retrained policy could move to that order.

    sampler = load_sampler("rl-ppo", task="maze2d", seed=0)                         # shipped weights
    sampler = load_sampler("rl-ppo", task="maze2d", checkpoint="runs/.../policy.pt")

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

from agents.checkpoints import check_trained_for, load_checkpoint, resolve_checkpoint, save_checkpoint
from agents.rl.policies import POLICY_KINDS, RLPolicy
from agents.samplers.base import ModelSampler, active_target
from agents.samplers.streams import TorchCompatibleStream
from gnn_mp_envs.envs.wrappers import ACTION_FRAMES, ACTION_HIGH, ACTION_LOW, policy_action_to_state, tree_view
from gnn_mp_envs.registration import same_bounds

#: sampler name -> checkpoint kind
RL_SAMPLERS: dict[str, str] = {"rl-ppo": "rl/sb3-ppo", "rl-sac": "rl/sb3-sac", "rl-ppo-torchrl": "rl/torchrl-ppo"}
#: checkpoint kind -> sampler name
SAMPLER_OF_KIND = {kind: name for name, kind in RL_SAMPLERS.items()}


class RLSampler(ModelSampler):
    """A trained policy as a sampler: view -> encoder -> ``(loc, scale)`` -> a draw -> a state.

    Args:
        low, high, seed: as for every sampler (the task's state bounds).
        policy: an :class:`~agents.rl.policies.RLPolicy` (acts in ``[-1, 1]^d``).
        view_nodes: rows of the tree view the policy was trained on.
        uniform_mix: probability of a uniform sample instead of the policy's.
        deterministic: the policy's mean, every step (no draw, no mixing).
        action_frame: ``"absolute"`` or ``"target"`` (see the module docstring).
        periodic: ``(d,)`` bool, the coordinates the task wraps.
    """

    settings = ("uniform_mix", "deterministic", "proposals")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, policy: RLPolicy,
                 view_nodes: int, uniform_mix: float = 0.0, deterministic: bool = False,
                 action_frame: str = "absolute", periodic: list[bool] | None = None, proposals: int = 1) -> None:
        super().__init__(low, high, seed, uniform_mix=uniform_mix, periodic=periodic, proposals=proposals)
        if policy.action_dim != self.state_dim:
            raise ValueError(f"the policy acts in {policy.action_dim} dimensions, the bounds have {self.state_dim}")
        if action_frame not in ACTION_FRAMES:
            raise ValueError(f"action_frame must be one of {ACTION_FRAMES}, got {action_frame!r}")
        self.policy = policy.eval()
        self.view_nodes = int(view_nodes)
        self.deterministic = bool(deterministic)
        self.action_frame = action_frame
        self._mix32 = np.float32(self.uniform_mix)
        self._periodic_or_none = self.periodic if self._wraps else None

    def make_stream(self, seed: int | None) -> TorchCompatibleStream:
        return TorchCompatibleStream(seed)

    def params(self, obs: Mapping) -> tuple[np.ndarray, np.ndarray]:
        """The policy's ``(loc, scale)`` ``(d,)`` float32 for one full observation (through its view)."""
        view = {k: torch.as_tensor(v) for k, v in tree_view(obs, self.view_nodes).items()}
        with torch.inference_mode():
            loc, scale = self.policy(view)
        return loc.numpy(), scale.numpy()

    def act(self, obs: Mapping) -> np.ndarray:
        """The policy's draw, mapped to a state, then (``uniform_mix > 0``) a uniform state taken
        instead with probability ``uniform_mix`` (see the module docstring for the draw order)."""
        if np.shape(obs["start"])[-1] != self.state_dim:
            self.check_observation(obs)
        x = self.model_sample(obs)
        if self.uniform_mix == 0.0 or self.deterministic:
            return x
        d = self.state_dim
        draws = self.rng.unit(d + 1)          # a uniform state's d values, then the choice: one call
        return self.low32 + draws[:d] * self.span32 if draws[d] < self._mix32 else x

    def model_sample(self, obs: Mapping) -> np.ndarray:
        """The policy's state for one observation (float32, in the bounds); the policy's forward runs
        once per ``proposals`` samples (its Gaussian is reused in between)."""
        loc, scale = self.refreshed(obs, self.params)
        # float32 elementwise, as torch computed it; tanh through torch (numpy's differs in the last bit)
        z = loc if self.deterministic else loc + scale * self.rng.normal(self.state_dim)
        u = np.minimum(np.maximum(z, ACTION_LOW), ACTION_HIGH) if self.policy.squash == "clip" else \
            self.policy.squash_action(torch.from_numpy(z)).numpy()
        x = policy_action_to_state(u, self.action_frame, self.low32, self.high32,
                                   np.asarray(active_target(obs), np.float32), self._periodic_or_none)
        return np.minimum(np.maximum(x, self.low32), self.high32)


# ----------------------------------------------------------------------------- files
def policy_record(*, task: str, view_nodes: int, low: np.ndarray, high: np.ndarray, uniform_mix: float = 0.0,
                  action_frame: str = "absolute", periodic: list[bool] | None = None,
                  meta: Mapping[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(obs_spec, meta)`` of a policy checkpoint: what :func:`sampler_from_checkpoint` reads back."""
    obs_spec = {"view_nodes": int(view_nodes), "state_dim": int(len(low)), "action_box": [ACTION_LOW, ACTION_HIGH],
                "action_frame": action_frame, "periodic": list(periodic or [False] * len(low)),
                "low": np.asarray(low, np.float64).tolist(), "high": np.asarray(high, np.float64).tolist()}
    full_meta = {"task": task, "view_nodes": int(view_nodes), "sampler": {"uniform_mix": float(uniform_mix)},
                 **dict(meta or {})}
    return obs_spec, full_meta


def save_policy(path: str | Path, policy: RLPolicy, kind: str, ctor_args: Mapping[str, Any], **record: Any) -> Path:
    """Write a policy checkpoint that :func:`load_rl_sampler` turns into a sampler (``record``: the
    keywords of :func:`policy_record`)."""
    obs_spec, meta = policy_record(**record)
    return save_checkpoint(path, policy, kind, ctor_args, obs_spec=obs_spec, meta=meta)


def sampler_from_checkpoint(path: str | Path, low: np.ndarray, high: np.ndarray, *, seed: int | None = None,
                            kind: str | None = None, task: str | None = None, uniform_mix: float | None = None,
                            deterministic: bool = False, proposals: int | None = None) -> RLSampler:
    """An :class:`RLSampler` from a policy checkpoint (``uniform_mix`` / ``proposals`` None: the file's)."""
    policy, record = load_checkpoint(path, expected_kind=kind or list(POLICY_KINDS))
    meta, spec = record["meta"], record["obs_spec"] or {}
    check_trained_for(path, meta.get("task"), task)
    if "low" in spec and not same_bounds((spec["low"], spec["high"]), (low, high)):
        raise ValueError(f"{path}: trained for bounds {spec['low']}..{spec['high']}, "
                         f"not {np.asarray(low).tolist()}..{np.asarray(high).tolist()}")
    stored = meta.get("sampler", {})
    uniform_mix = float(stored.get("uniform_mix", 0.0)) if uniform_mix is None else uniform_mix
    proposals = int(stored.get("proposals", 1)) if proposals is None else proposals
    return RLSampler(low, high, seed, policy=policy, view_nodes=int(meta.get("view_nodes", spec.get("view_nodes"))),
                     uniform_mix=uniform_mix, deterministic=deterministic, proposals=proposals,
                     action_frame=spec.get("action_frame", "absolute"), periodic=spec.get("periodic"))


def load_rl_sampler(name: str, low: np.ndarray, high: np.ndarray, task: str | None = None, seed: int | None = None,
                    checkpoint: str | Path | None = None, uniform_mix: float | None = None,
                    deterministic: bool = False, proposals: int | None = None) -> RLSampler:
    """The registry factory of ``rl-ppo``, ``rl-sac`` and ``rl-ppo-torchrl`` (the registry applies the
    thread policy: measured 0.8 ms per ``act`` with 1 thread against 12 ms with 2)."""
    path = resolve_checkpoint(name, task, checkpoint, f"gnn-mp train rl --task {task}")
    return sampler_from_checkpoint(path, low, high, seed=seed, kind=RL_SAMPLERS[name], task=task,
                                   uniform_mix=uniform_mix, deterministic=deterministic, proposals=proposals)


__all__ = ["RL_SAMPLERS", "RLSampler", "load_rl_sampler", "policy_record", "sampler_from_checkpoint", "save_policy"]
