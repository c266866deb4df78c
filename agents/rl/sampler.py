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
from functools import partial
from typing import Any, Callable, Mapping

import numpy as np
import torch
from torch import nn

from agents.checkpoints import check_trained_for, load_checkpoint, resolve_checkpoint, save_checkpoint
from agents.nn.encoders import PRIOR_KIND, TreeEncoder, plain_mean_sage
from agents.nn.priors import candidate_prior, supervised_prior
from agents.nn.twins import NUMPY_ACTS, numpy_layers, numpy_linear, numpy_mlp
from agents.rl.policies import PICK_KINDS, POLICY_KINDS, PickPolicy, RLPolicy, SB3PPOPolicy
from agents.samplers.base import ModelSampler, active_target
from agents.samplers.streams import TorchCompatibleStream, torch_compatible_stream
from gnn_mp_envs.envs.candidates import CandidateSet, wrap_into_box
from gnn_mp_envs.envs.wrappers import ACTION_FRAMES, ACTION_HIGH, ACTION_LOW, policy_action_to_state, tree_view
from gnn_mp_envs.registration import same_bounds
from gnn_mp_envs.utils.compiled import jit

#: sampler name -> the checkpoint kinds it loads (continuous actions; candidate selection)
RL_SAMPLERS: dict[str, tuple[str, ...]] = {"rl-ppo": ("rl/sb3-ppo", "rl/sb3-ppo-pick"), "rl-sac": ("rl/sb3-sac",),
                                           "rl-ppo-torchrl": ("rl/torchrl-ppo", "rl/torchrl-ppo-pick")}
#: sampler name -> the ``gnn-mp train rl`` flags that train its kind (what a missing checkpoint's error names)
TRAIN_FLAGS: dict[str, str] = {"rl-ppo": "", "rl-sac": " --algo sac --action box", "rl-ppo-torchrl": " --lib torchrl"}
#: checkpoint kind -> sampler name
SAMPLER_OF_KIND = {kind: name for name, kinds in RL_SAMPLERS.items() for kind in kinds}
#: prior-only sampler -> the picker whose candidates and supervised prior it uses (no weights of its own)
PRIOR_OF = {"gnn-pick": "rl-ppo"}


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
        self.deterministic = boolean_setting("deterministic", deterministic)
        self.action_frame = action_frame
        self._mix32 = np.float32(self.uniform_mix)
        self._periodic_or_none = self.periodic if self._wraps else None
        self._twin = numpy_tree_policy(self.policy)
        #: A clipped policy in the target frame: its drawn state comes from one compiled call.
        self._compiled_map = self.policy.squash == "clip" and action_frame == "target"

    def make_stream(self, seed: int | None) -> TorchCompatibleStream:
        return torch_compatible_stream(getattr(self, "rng", None), seed)

    def params(self, obs: Mapping) -> tuple[np.ndarray, np.ndarray]:
        """The policy's ``(loc, scale)`` ``(d,)`` float32 for one full observation (through its view;
        a policy :func:`numpy_tree_policy` supports runs as its numpy twin)."""
        if self._twin is not None:
            return numpy_tree_params(self._twin, tree_view(obs, self.view_nodes))
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
        if self._compiled_map and not self.deterministic and loc.dtype == scale.dtype == np.float32:
            return _clipped_target_map(loc, scale, self.rng.normal(self.state_dim),
                                       np.asarray(active_target(obs), np.float32), self.span32, self.low32,
                                       self.high32, self.periodic, _ACTION_LOW32, _ACTION_HIGH32)
        # float32 elementwise, as torch computed it; tanh through torch (numpy's differs in the last bit)
        z = loc if self.deterministic else loc + scale * self.rng.normal(self.state_dim)
        u = np.minimum(np.maximum(z, ACTION_LOW), ACTION_HIGH) if self.policy.squash == "clip" else \
            self.policy.squash_action(torch.from_numpy(z)).numpy()
        if self.action_frame == "target":
            # policy_action_to_state's target map, in float32: u is already in [-1, 1]
            x = np.asarray(active_target(obs), np.float32) + u * self.span32
            if self._periodic_or_none is not None:    # ... and its wrap, without its checks and copies
                x = wrap_into_box(x, self.low32, self.span32, self._periodic_or_none)
        else:
            x = policy_action_to_state(u, self.action_frame, self.low32, self.high32,
                                       np.asarray(active_target(obs), np.float32), self._periodic_or_none)
        return np.minimum(np.maximum(x, self.low32), self.high32)


_ACTION_LOW32, _ACTION_HIGH32 = np.float32(ACTION_LOW), np.float32(ACTION_HIGH)


@jit
def _clipped_target_map(loc, scale, noise, target, span, low, high, periodic, action_low, action_high):
    """:meth:`RLSampler.model_sample`'s state for a clipped policy in the target frame, in one
    compiled call instead of about a dozen numpy operations on ``(d,)`` float32 vectors (~15 us of a
    pendulum step): ``loc + scale * noise`` clipped to the action box, ``target + u * span``, the
    periodic coordinates wrapped into ``[low, low + span)`` (:func:`wrap_into_box`), then clipped to
    ``[low, high]``. The same float32 operations in the same order, so the same values
    (``tests/test_rl.py`` holds the two paths bit for bit)."""
    d = loc.shape[0]
    out = np.empty(d, dtype=np.float32)
    for c in range(d):
        u = np.minimum(np.maximum(loc[c] + scale[c] * noise[c], action_low), action_high)
        x = target[c] + u * span[c]
        if periodic[c]:
            x = np.remainder(x - low[c], span[c]) + low[c]
        out[c] = np.minimum(np.maximum(x, low[c]), high[c])
    return out


def boolean_setting(name: str, value) -> bool:
    """A sampler flag as given: true or false (``--setting rl-ppo.deterministic=3`` is refused, not taken as true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be true or false, got {value!r}")
    return bool(value)


def numpy_pick_layers(policy: PickPolicy) -> dict[str, Any]:
    """A :class:`PickPolicy` without a tree context as numpy arrays (float32): the per-candidate MLP,
    the body and the logits layer, for :func:`numpy_pick_logits` (a forward of ~10 us instead of
    torch's ~300 us of per-call overhead on one step's ``(K, F)`` features)."""
    twin = {"candidate": numpy_layers(policy.encoder.net), "body": numpy_layers(policy.body),
            "prior": policy.encoder.prior_model is not None, "shared": policy.head == "shared"}
    if twin["shared"]:
        head = policy.logits
        twin.update(score=head.score.weight.detach().numpy()[0].copy(), bias=head.score.bias.detach().numpy().copy(),
                    slot_bias=head.slot_bias.detach().numpy().copy(),
                    prior_scale=None if head.prior_scale is None else head.prior_scale.detach().numpy().copy())
    else:
        twin["logits"] = numpy_layers(nn.Sequential(policy.logits))[0]
    return twin


def numpy_tree_policy(policy: RLPolicy) -> dict[str, Any] | None:
    """An SB3 PPO actor over a :class:`~agents.nn.encoders.TreeEncoder` as numpy arrays (float32), for
    :func:`numpy_tree_params`; ``None`` for any other policy (it runs in torch).

    Supported: tree edges only (``knn=0``), plain mean-aggregation ``SAGEConv`` layers, ReLU/Tanh
    (the shipped ``rl-ppo`` policies of maze2d and the pendulum). Torch spends ~0.5 ms of per-op
    overhead on the ~100 operations of one forward over a 64-node view; the twin makes the same
    products in a fraction of that. It is the torch model's math in float32, in another order of
    summation (``tests/test_rl.py`` compares the two to 1e-5).
    """
    enc = policy.encoder
    if type(policy) is not SB3PPOPolicy or type(enc) is not TreeEncoder or enc.knn or type(enc.act) not in NUMPY_ACTS \
            or not all(plain_mean_sage(conv) for conv in enc.tree_convs):
        return None
    try:
        return {"act": NUMPY_ACTS[type(enc.act)], "feature_scale": enc.feature_scale.numpy().copy(),
                "center": enc.state_center.numpy().copy(), "half_span": enc.state_half_span.numpy().copy(),
                "input": numpy_linear(enc.input),
                "convs": [(numpy_linear(c.lin_l), numpy_linear(c.lin_r)) for c in enc.tree_convs],
                "context": numpy_layers(enc.context), "readout": numpy_layers(enc.readout),
                "body": numpy_layers(nn.Sequential(*policy.body, policy.mu)),
                "scale": policy.log_std.detach().exp().numpy().copy()}
    except ValueError:
        return None


def numpy_tree_params(twin: Mapping[str, Any], view: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``policy(view)``'s ``(loc, scale)`` ``(d,)`` in numpy for one (unbatched) tree view: what
    :class:`TreeEncoder` computes (input layer, residual mean-SAGE layers over the tree edges in
    both directions, mean / max pooling, the start-goal context, the readout), then the actor."""
    act = twin["act"]
    n = int(np.asarray(view["num_nodes"]).reshape(-1)[0])
    if n <= 0:
        n = int(np.asarray(view["mask"]).sum())
    w, b, _ = twin["input"]
    h = act(np.asarray(view["node_features"][:n], np.float32) / twin["feature_scale"] @ w + b)
    parent = np.asarray(view["parent"][:n]).astype(np.int64)
    child = np.flatnonzero((parent >= 0) & (parent < n))
    src = parent[child]
    # each tree edge in both directions, the order of tree_edge_index: sender -> receiver
    senders = np.stack([src, child], 1).reshape(-1)
    receivers = np.stack([child, src], 1).reshape(-1)
    count = np.maximum(np.bincount(receivers, minlength=n), 1).astype(np.float32)[:, None]
    for (wl, bl, _), (wr, br, _) in twin["convs"]:
        total = np.zeros_like(h)
        np.add.at(total, receivers, h[senders])
        h = h + act((total / count) @ wl + bl + (h @ wr + br))
    center, half = twin["center"], twin["half_span"]
    ends = [(np.asarray(view[k], np.float32).reshape(-1) - center) / half for k in ("start", "goal")]
    active = np.asarray(view["active_tree"], np.float32).reshape(1)
    ctx = numpy_mlp(twin["context"], np.concatenate([*ends, active]))
    embed = numpy_mlp(twin["readout"], np.concatenate([h.sum(0) / np.float32(n), h.max(0), ctx]))
    return numpy_mlp(twin["body"], embed), twin["scale"]


@jit
def _shared_head_logits(h, x, score, bias, slot_bias, prior_scale, has_prior):
    """:class:`~agents.rl.pick.SharedCandidateHead` over the candidates' embeddings ``h (K, E)``,
    compiled: ``logit_k = score . [h_k, mean h, max h] + bias + slot_bias_k (+ prior_scale x_k,-1)``
    (the per-candidate MLP stays in numpy: its matrix products and vector tanh are faster there)."""
    K, E = h.shape
    shared = bias
    for j in range(E):
        total, top = np.float32(0.0), h[0, j]
        for k in range(K):
            total += h[k, j]
            top = max(top, h[k, j])
        shared += total / np.float32(K) * score[E + j] + top * score[2 * E + j]
    logits = np.empty(K, np.float32)
    for k in range(K):
        acc = shared + slot_bias[k]
        for j in range(E):
            acc += h[k, j] * score[j]
        if has_prior:
            acc += prior_scale * x[k, x.shape[1] - 1]
        logits[k] = acc
    return logits


def numpy_pick_logits(twin: Mapping[str, Any], features: np.ndarray) -> np.ndarray:
    """:class:`PickPolicy`'s logits ``(K,)`` in numpy for one step's features ``(K, F)``."""
    features = np.asarray(features, np.float32)
    h = numpy_mlp(twin["candidate"], features)
    if twin["shared"]:           # SharedCandidateHead: w . [e_k, mean, max] + b + bias_k (+ scale * prior_k)
        prior_scale = np.float32(twin["prior_scale"][0]) if twin["prior"] else np.float32(0.0)
        return _shared_head_logits(np.ascontiguousarray(h, np.float32), features, twin["score"],
                                   np.float32(twin["bias"][0]), twin["slot_bias"], prior_scale, bool(twin["prior"]))
    parts = [h.reshape(-1), h.mean(0), h.max(0)] + ([features[:, -1]] if twin["prior"] else [])
    x = numpy_mlp(twin["body"], np.concatenate(parts))
    return numpy_mlp([twin["logits"]], x)


class PickSampler(ModelSampler):
    """A trained candidate picker as a sampler: ``K`` candidates -> the policy's categorical -> one of them.

    Each model sample draws the step's candidates from the sampler's stream with the
    :class:`~gnn_mp_envs.envs.candidates.CandidateSet` the policy was trained with (the same
    draws and features as the training env's :class:`CandidatePickWrapper`), scores them and
    draws one (``deterministic=True``: the best); a policy trained with a candidate prior gets
    the same prior, rebuilt from the scorer weights it carries. The one mixture of :class:`ModelSampler` puts
    ``uniform_mix`` / ``goal_bias`` samples in between; every sample sent is recorded, so the
    tree statistics (blocked extensions per node) are those the training env kept.

    Args:
        low, high, seed: as for every sampler (the task's state bounds).
        policy: a :class:`~agents.rl.policies.PickPolicy`.
        view_nodes: rows of the tree view (read when the policy has a tree context).
        candidates: keyword arguments of the ``CandidateSet`` (``count``, ``step_scale``,
            ``periodic``, ``metric_weights``, ``local_scale``), from the checkpoint.
    """

    settings = ("uniform_mix", "goal_bias", "deterministic", "proposals")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, policy: PickPolicy,
                 view_nodes: int, candidates: Mapping[str, Any], uniform_mix: float = 0.0, goal_bias: float = 0.0,
                 deterministic: bool = False, proposals: int = 1, prior_only: bool = False,
                 prior: Any = None) -> None:
        config = dict(candidates)
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=config.get("periodic"), proposals=proposals)
        self.policy = policy.eval()
        # ``prior`` (a CandidatePrior): scores candidates in place of the policy's own prior (``gnn-pick``
        # on a picker trained without one: the task's supervised ``gnn``); only with ``prior_only``.
        if prior is not None and not prior_only:
            raise ValueError("an outside candidate prior is only read with prior_only=True (the policy was not trained on it)")
        self.candidate_set = CandidateSet(low, high, prior=self.new_prior() if prior is None else prior, **config)
        if self.candidate_set.count != policy.count:
            raise ValueError(f"the policy picks among {policy.count} candidates, the candidate set has "
                             f"{self.candidate_set.count}")
        self.view_nodes = int(view_nodes)
        self.deterministic = boolean_setting("deterministic", deterministic)
        self._picked: int | None = None
        self._twin = None if policy.reads_tree else numpy_pick_layers(policy)
        #: Pick by the candidate prior's logits alone (the ``gnn-pick`` row: what RL adds over its prior).
        self.prior_only = bool(prior_only)
        if self.prior_only and self.candidate_set.prior is None:
            raise ValueError("this picker was trained without a candidate prior: there is no prior to pick by")

    def new_prior(self):
        """A fresh copy of the candidate prior the policy was trained with (its own caches), rebuilt from
        the scorer weights the policy carries; None for a policy without one."""
        encoder = self.policy.encoder
        if encoder.prior_model is None:
            return None
        return candidate_prior(PRIOR_KIND, encoder.prior_model, temperature=encoder.prior_config["temperature"])

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        if hasattr(self, "candidate_set"):
            self.candidate_set.reset()

    def act_stateless(self, obs: Mapping) -> np.ndarray:
        self.candidate_set.reset()
        return self.act(obs)

    def act(self, obs: Mapping) -> np.ndarray:
        self._picked = None
        x = super().act(obs)
        self.candidate_set.record(obs, x, self._picked)
        return x

    def logits(self, obs: Mapping, features: np.ndarray) -> np.ndarray:
        """The policy's logits ``(K,)`` for one full observation and its candidates' features (a
        policy without a tree context runs as its numpy twin, :func:`numpy_pick_logits`; with
        ``prior_only``, the prior's logits, the features' last column)."""
        if self.prior_only:
            return features[:, -1].copy()
        if self._twin is not None:
            return numpy_pick_logits(self._twin, features)
        inputs = {"candidate_features": torch.from_numpy(features)}
        if self.policy.reads_tree:
            inputs.update({k: torch.as_tensor(v) for k, v in tree_view(obs, self.view_nodes).items()})
        with torch.inference_mode():
            return self.policy(inputs).numpy()

    def scored(self, obs: Mapping) -> tuple[np.ndarray, np.ndarray, int]:
        """The forward: the step's candidates, the running sums of the policy's pick probabilities
        over them, and the likeliest one."""
        cands, feats = self.candidate_set.propose(obs, self.rng)
        logits = self.logits(obs, feats).astype(np.float64)
        return cands, np.cumsum(np.exp(logits - logits.max())), int(np.argmax(logits))

    def model_sample(self, obs: Mapping) -> np.ndarray:
        """A pick among the candidates of the last forward (one per ``proposals`` model samples:
        ``proposals=1``, the training env's, scores a fresh set every time)."""
        calls = self.forward_calls
        cands, cumulative, best = self.refreshed(obs, self.scored)
        k = best if self.deterministic else \
            min(int(cumulative.searchsorted(self.rng.random() * cumulative[-1], "right")), len(cumulative) - 1)
        # a reused set's nearest nodes are stale: the sample's own nearest node is looked up when recorded
        self._picked = k if self.forward_calls != calls else None
        return cands[k]


# ----------------------------------------------------------------------------- files
def policy_record(*, task: str, view_nodes: int, low: np.ndarray, high: np.ndarray, uniform_mix: float = 0.0,
                  action_frame: str = "absolute", periodic: list[bool] | None = None,
                  candidates: Mapping[str, Any] | None = None,
                  meta: Mapping[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(obs_spec, meta)`` of a policy checkpoint: what :func:`sampler_from_checkpoint` reads back
    (``candidates``: a picker's ``CandidateSet`` configuration)."""
    obs_spec = {"view_nodes": int(view_nodes), "state_dim": int(len(low)), "action_box": [ACTION_LOW, ACTION_HIGH],
                "action_frame": action_frame, "periodic": list(periodic or [False] * len(low)),
                "low": np.asarray(low, np.float64).tolist(), "high": np.asarray(high, np.float64).tolist()}
    if candidates is not None:
        obs_spec.update(action="pick", candidates=dict(candidates))
    full_meta = {"task": task, "view_nodes": int(view_nodes), "sampler": {"uniform_mix": float(uniform_mix)},
                 **dict(meta or {})}
    return obs_spec, full_meta


def save_policy(path: str | Path, policy: RLPolicy, kind: str, ctor_args: Mapping[str, Any], **record: Any) -> Path:
    """Write a policy checkpoint that :func:`load_rl_sampler` turns into a sampler (``record``: the
    keywords of :func:`policy_record`)."""
    obs_spec, meta = policy_record(**record)
    return save_checkpoint(path, policy, kind, ctor_args, obs_spec=obs_spec, meta=meta)


def sampler_from_checkpoint(path: str | Path, low: np.ndarray, high: np.ndarray, *, seed: int | None = None,
                            kind: str | tuple[str, ...] | None = None, task: str | None = None,
                            uniform_mix: float | None = None, deterministic: bool = False,
                            proposals: int | None = None, goal_bias: float | None = None,
                            prior_only: bool = False, prior_source: Callable[[], Any] | None = None
                            ) -> RLSampler | PickSampler:
    """The sampler of a policy checkpoint: an :class:`RLSampler` (continuous actions) or a
    :class:`PickSampler` (candidate selection; ``prior_only``: picking by its candidate prior alone,
    or, for a picker trained without one, by the prior ``prior_source()`` makes); settings None: the file's."""
    policy, record = load_checkpoint(path, expected_kind=kind or [*POLICY_KINDS, *PICK_KINDS])
    meta, spec = record["meta"], record["obs_spec"] or {}
    check_trained_for(path, meta.get("task"), task)
    if "low" in spec and not same_bounds((spec["low"], spec["high"]), (low, high)):
        raise ValueError(f"{path}: trained for bounds {spec['low']}..{spec['high']}, "
                         f"not {np.asarray(low).tolist()}..{np.asarray(high).tolist()}")
    stored = meta.get("sampler", {})
    uniform_mix = float(stored.get("uniform_mix", 0.0)) if uniform_mix is None else uniform_mix
    proposals = int(stored.get("proposals", 1)) if proposals is None else proposals
    if record["kind"] in PICK_KINDS:
        goal_bias = float(stored.get("goal_bias", 0.0)) if goal_bias is None else goal_bias
        outside = None
        if prior_only and policy.encoder.prior_model is None and prior_source is not None:
            outside = prior_source()
        return PickSampler(low, high, seed, policy=policy, view_nodes=int(meta.get("view_nodes", spec.get("view_nodes"))),
                           candidates=spec["candidates"], uniform_mix=uniform_mix, goal_bias=goal_bias,
                           deterministic=deterministic, proposals=proposals, prior_only=prior_only, prior=outside)
    if prior_only:
        raise ValueError(f"{path}: a continuous policy has no candidate prior (a picker's checkpoint is needed)")
    if goal_bias not in (None, 0.0):
        raise ValueError("goal_bias is a setting of candidate pickers; a continuous policy has uniform_mix")
    return RLSampler(low, high, seed, policy=policy, view_nodes=int(meta.get("view_nodes", spec.get("view_nodes"))),
                     uniform_mix=uniform_mix, deterministic=deterministic, proposals=proposals,
                     action_frame=spec.get("action_frame", "absolute"), periodic=spec.get("periodic"))


def load_rl_sampler(name: str, low: np.ndarray, high: np.ndarray, task: str | None = None, seed: int | None = None,
                    checkpoint: str | Path | None = None, uniform_mix: float | None = None,
                    deterministic: bool = False, proposals: int | None = None,
                    goal_bias: float | None = None) -> RLSampler | PickSampler:
    """The registry factory of ``rl-ppo``, ``rl-sac`` and ``rl-ppo-torchrl`` (the registry applies the
    thread policy: measured 0.8 ms per ``act`` with 1 thread against 12 ms with 2)."""
    source = PRIOR_OF.get(name, name)           # gnn-pick: the shipped rl-ppo picker's candidates and prior
    path = resolve_checkpoint(source, task, checkpoint, f"gnn-mp train rl{TRAIN_FLAGS[source]} --task {task}")
    kinds = tuple(k for k in RL_SAMPLERS[source] if k in PICK_KINDS) if name in PRIOR_OF else RL_SAMPLERS[name]
    return sampler_from_checkpoint(path, low, high, seed=seed, kind=kinds, task=task,
                                   uniform_mix=uniform_mix, deterministic=deterministic, proposals=proposals,
                                   goal_bias=goal_bias, prior_only=name in PRIOR_OF,
                                   prior_source=partial(supervised_prior, task) if name in PRIOR_OF else None)


__all__ = ["PRIOR_OF", "PickSampler", "RL_SAMPLERS", "RLSampler", "load_rl_sampler", "policy_record", "sampler_from_checkpoint",
           "save_policy", "supervised_prior"]
