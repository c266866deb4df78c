"""Your own RL agent as a sampler checkpoint: :func:`save_rl_checkpoint`.

An agent trained with your own SB3 script or TorchRL loop on an RL env of this package
(``gym.make("GNNMP/Maze2DRRT-RLPick-v0")``, :func:`gnn_mp_envs.envs.wrappers.make_rl_env`, or
TorchRL's ``GymEnv`` of one) becomes a file in the one checkpoint format (:mod:`agents.checkpoints`,
``weights_only``) that the benchmark runs as a row of its own::

    from agents.rl.export import save_rl_checkpoint
    save_rl_checkpoint("my_picker.pt", model, env)         # an SB3 PPO/SAC model, or a TorchRL actor

    gnn-mp benchmark --task maze2d --samplers uniform,rl-ppo,mine --checkpoint mine=my_picker.pt

Everything the sampler must repeat is read from the env the agent trained on, not retyped: the
task, the tree view's rows, a picker's candidate set (count, scales, the task's step), the uniform
mixture and a box policy's action frame. The policy is copied out of the library's objects
(:func:`~agents.rl.policies.policy_from_sb3`, :func:`~agents.rl.policies.policy_from_torchrl`), and
the file is loaded back once before this returns, so a file it writes is one the benchmark reads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from torch import nn

from agents.rl.pick import PickPolicy


class ExportError(ValueError):
    """An agent or env that :func:`save_rl_checkpoint` cannot turn into a checkpoint (one line)."""


def _gym_env(env: Any) -> Any:
    """The gymnasium env inside a TorchRL ``GymEnv``/``GymWrapper`` or an SB3 ``DummyVecEnv`` (its first)."""
    import gymnasium as gym
    if isinstance(env, gym.Env):
        return env
    inner = getattr(env, "_env", None)             # TorchRL's GymWrapper / GymEnv
    if isinstance(inner, gym.Env):
        return inner
    envs = getattr(env, "envs", None)              # SB3's DummyVecEnv (and VecEnv wrappers of one)
    if envs is None and hasattr(env, "venv"):
        return _gym_env(env.venv)
    if isinstance(envs, (list, tuple)) and envs and isinstance(envs[0], gym.Env):
        return envs[0]
    raise ExportError(f"env: a {type(env).__name__}; pass the gymnasium env the agent trained on (gym.make(id) or "
                      "make_rl_env(...)), a TorchRL GymEnv/GymWrapper of one, or an SB3 DummyVecEnv (one env of a "
                      "batched or subprocess set: make one with the same arguments)")


def _task_of(base: Any) -> str:
    """The registered task of a planning env, from its env id (the base id or an RL id)."""
    from gnn_mp_envs.registration import TASK_SPECS, rl_env_id
    env_id = getattr(getattr(base, "spec", None), "id", None)
    for name, spec in TASK_SPECS.items():
        for base_id in spec.envs:
            if env_id in (base_id, rl_env_id(base_id, "pick"), rl_env_id(base_id, "box")):
                return name
    raise ExportError(f"env: {env_id or type(base).__name__} is not an env id of a registered task; make the env with "
                      "gym.make(id) or make_rl_env(task)")


def env_settings(env: Any) -> dict[str, Any]:
    """What a policy trained on ``env`` needs to act as a sampler, read from its wrappers: ``task``,
    ``planner``, ``action`` (pick or box), ``view_nodes``, ``candidates`` (a picker's ``CandidateSet``
    configuration), ``prior`` (whether the candidates carry a prior column), ``uniform_mix`` and
    ``action_frame``."""
    from gymnasium.wrappers import RescaleAction

    from gnn_mp_envs.envs.candidates import CandidatePickWrapper
    from gnn_mp_envs.envs.tree_env import TreePlanningEnv
    from gnn_mp_envs.envs.wrappers import TargetRelativeAction, TreeViewWrapper, UniformMixAction
    found: dict[str, Any] = {"view_nodes": None, "candidates": None, "prior": False, "uniform_mix": 0.0,
                             "action_frame": "absolute"}
    layer = _gym_env(env)
    while True:
        if isinstance(layer, CandidatePickWrapper):
            found.update(candidates=layer.candidate_set.config(), prior=layer.candidate_set.prior is not None,
                         uniform_mix=layer.uniform_mix)
        elif isinstance(layer, TreeViewWrapper):
            found["view_nodes"] = layer.view_nodes
        elif isinstance(layer, TargetRelativeAction):
            found["action_frame"] = "target"
        elif isinstance(layer, RescaleAction):
            found["action_frame"] = "absolute"
        elif isinstance(layer, UniformMixAction):
            found["uniform_mix"] = layer.p
        if not hasattr(layer, "env"):
            break
        layer = layer.env
    if not isinstance(layer, TreePlanningEnv):
        raise ExportError(f"env: a {type(layer).__name__} underneath, not a planning env of this package "
                          "(gym.make('GNNMP/...') or make_rl_env(task))")
    found.update(task=_task_of(layer), planner=layer.planner_name,
                 action="pick" if found["candidates"] is not None else "box",
                 view_nodes=found["view_nodes"] or layer.max_nodes)   # no view: the full padded tree
    return found


def export_policy(agent: Any) -> tuple[nn.Module, str, dict[str, Any]]:
    """``(policy, kind, ctor_args)`` of an SB3 model (PPO, SAC) or a TorchRL actor of
    :mod:`agents.rl.torchrl` (``make_actor``, ``make_pick_actor``)."""
    from agents.rl.policies import policy_from_sb3, policy_from_torchrl
    try:
        from stable_baselines3.common.base_class import BaseAlgorithm
    except ImportError:                               # pragma: no cover - the agents extra ships SB3
        BaseAlgorithm = ()
    try:
        if BaseAlgorithm and isinstance(agent, BaseAlgorithm):
            return policy_from_sb3(agent)
        if isinstance(agent, nn.Module):
            return policy_from_torchrl(agent)
    except (TypeError, AttributeError, IndexError, ValueError) as exc:
        raise ExportError(f"agent: cannot copy the policy out of this {type(agent).__name__} ({str(exc).splitlines()[0]}); "
                          "supported: SB3 PPO/SAC with this package's extractors, TorchRL actors of agents.rl.torchrl "
                          "(make_actor, make_pick_actor)") from None
    raise ExportError(f"agent: a {type(agent).__name__}; pass an SB3 model (PPO, SAC) or a TorchRL actor of "
                      "agents.rl.torchrl (make_actor, make_pick_actor)")


def save_rl_checkpoint(path: str | Path, agent: Any, env: Any, *, uniform_mix: float | None = None,
                       meta: Mapping[str, Any] | None = None) -> Path:
    """Write ``agent``'s policy, trained on ``env``, as a sampler checkpoint; returns the path.

    ``agent``: an SB3 ``PPO``/``SAC`` model or a TorchRL actor of :mod:`agents.rl.torchrl`; ``env``:
    the env it trained on (a gymnasium env, a TorchRL ``GymEnv``/``GymWrapper`` of one, or an SB3
    ``DummyVecEnv``); ``uniform_mix``: the sampler's uniform mixture (default: the env's);
    ``meta``: anything to keep beside (plain values). The kind comes from the agent
    (``rl/sb3-ppo-pick``, ``rl/torchrl-ppo-pick``, ``rl/sb3-ppo``, ...), and with it the sampler
    that runs it: ``load_sampler(name, task=..., checkpoint=path)``, or any row name of
    ``gnn-mp benchmark --checkpoint NAME=PATH``. A mismatch between agent and env (a picker and a
    box env, another candidate count) or a file that would not load is one :class:`ExportError`.
    """
    from agents.checkpoints import plain
    from agents.rl.sampler import SAMPLER_OF_KIND, sampler_from_checkpoint, save_policy
    from gnn_mp_envs.registration import task_spec
    settings = env_settings(env)
    policy, kind, ctor_args = export_policy(agent)
    picker = isinstance(policy, PickPolicy)
    if picker != (settings["action"] == "pick"):
        raise ExportError(f"agent and env disagree: a {'candidate picker' if picker else 'continuous policy'} and an "
                          f"env of {'candidate' if settings['action'] == 'pick' else 'box'} actions")
    if picker:
        count = settings["candidates"]["count"]
        if policy.count != count:
            raise ExportError(f"agent and env disagree: the policy scores {policy.count} candidates, the env offers "
                              f"{count}")
        if settings["prior"] and policy.encoder.prior_model is None:
            raise ExportError("env: its candidates carry a prior's column, whose model the policy does not hold, so "
                              "a sampler could not compute it (gnn-mp train rl --prior trains such a picker)")
    spec = task_spec(settings["task"])
    low, high = spec.state_bounds()
    if uniform_mix is None:
        uniform_mix = settings["uniform_mix"]
    if not (isinstance(uniform_mix, (int, float)) and 0.0 <= uniform_mix <= 1.0):
        raise ExportError(f"uniform_mix must be a number in [0, 1], got {uniform_mix!r}")
    extra = plain(dict(meta or {}), "meta")
    path = save_policy(path, policy, kind, ctor_args, task=settings["task"], view_nodes=settings["view_nodes"],
                       low=low, high=high, uniform_mix=float(uniform_mix), action_frame=settings["action_frame"],
                       periodic=spec.periodic_mask(len(low)).tolist(), candidates=settings["candidates"],
                       meta={"sampler_name": SAMPLER_OF_KIND[kind], "planner": settings["planner"],
                             "saved_by": "agents.rl.export.save_rl_checkpoint", **extra})
    sampler_from_checkpoint(path, low, high, seed=0, task=settings["task"])     # it loads, or this raises
    return Path(path)


__all__ = ["ExportError", "env_settings", "export_policy", "save_rl_checkpoint"]
