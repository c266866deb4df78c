"""What a ``gnn-mp train rl`` run's flags (its ``config.json``) say about the networks and the MDP.

One reading of the flags, shared by the training scripts (``train.rl.args.RLArgs`` delegates
here) and by whatever rebuilds a run's model from its ``config.json`` alone (an SB3 ``.zip``
benchmarked as a checkpoint, :mod:`agents.rl.sb3_files`). ``config`` is a mapping of field names
of ``RLArgs`` to values (``dataclasses.asdict(args)`` or the parsed ``config.json``)::

    env = make_rl_env(config["task"], split="train", **env_kwargs(config))
    policy_kwargs = sb3_policy_kwargs(config)          # agents.rl.sb3_files
"""

from __future__ import annotations

from typing import Any, Mapping

#: The supervised GNN sampler's shipped backbone (``train.tree.adapters.GNNAdapter`` trains it):
#: what ``--encoder tree-gnn`` builds, so that ``--init-from gnn`` fits.
TREE_GNN_ARCH = {"hidden_channels": 64, "num_layers": 2, "knn": 6}

#: Reward flags passed to the env only when set (else the task's ``TaskSpec.rl_reward``).
_REWARD_FLAGS = ("step_penalty", "node_cost", "collision_check_cost", "success_reward")


def env_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :func:`gnn_mp_envs.envs.wrappers.make_rl_env` (besides task, split)."""
    c = config
    kw: dict[str, Any] = {"view_nodes": c["view_nodes"], "planner": c["planner"], "action": c["action"],
                          "candidates": c["candidates"], "local_scale": c["local_scale"],
                          "target_scale": c["target_scale"], "action_frame": c["action_frame"],
                          "uniform_mix": c["uniform_mix"], "progress_reward": c["progress_reward"],
                          "gamma": c["gamma"], "reward_scale": c["reward_scale"],
                          "max_episode_steps": c["max_episode_steps"]}
    for name in _REWARD_FLAGS:
        if c.get(name) is not None:
            kw[name] = c[name]
    if c.get("max_nodes") is not None:
        kw["max_nodes"] = c["max_nodes"]
    if c.get("prior") is not None:
        from functools import partial

        from agents.nn.encoders import PRIOR_KIND
        from agents.nn.priors import prior_class
        kw["candidate_prior"] = partial(prior_class(PRIOR_KIND).from_checkpoint, str(c["prior"]),
                                        c["prior_temperature"])
    return kw


def sampler_uniform_mix(config: Mapping[str, Any]) -> float:
    """The uniform mixture of the run's sampler (the flag, else the action's default)."""
    from gnn_mp_envs.envs.wrappers import DEFAULT_UNIFORM_MIX
    mix = config.get("uniform_mix")
    return DEFAULT_UNIFORM_MIX[config["action"]] if mix is None else float(mix)


def candidate_settings(config: Mapping[str, Any]) -> dict[str, Any]:
    """The run's ``CandidateSet`` configuration (pick): what its env and its sampler use."""
    from gnn_mp_envs.envs.wrappers import candidate_settings as settings
    return settings(config["task"], config["candidates"], config["local_scale"], config["target_scale"])


def encoder_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of ``agents.rl.backbones.encoder_from_space``."""
    c = config
    if c["encoder"] == "tree-gnn":   # the supervised GNN sampler's architecture, so its weights fit
        from gnn_mp_envs.registration import task_spec
        spec = task_spec(c["task"])
        return {"backbone": "tree-gnn", **TREE_GNN_ARCH, "step_scale": task_step_scale(c["task"]),
                "periodic": list(spec.periodic), "num_trees": spec.num_trees(spec.env_id_for(c["planner"]))}
    return {"hidden_channels": c["hidden_channels"], "num_layers": c["num_layers"],
            "out_channels": c["out_channels"], "conv": c["conv"], "knn": c["knn"]}


def candidate_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    """Keyword arguments of the pick policy's ``CandidateEncoder.from_space``."""
    c = config
    kw: dict[str, Any] = {"hidden": c["candidate_hidden"], "embed": c["candidate_embed"],
                          "tree_context": c["tree_context"]}
    if c["tree_context"]:
        kw["tree_kwargs"] = encoder_kwargs(c)
    if c.get("prior") is not None:
        kw.update(prior_checkpoint=str(c["prior"]), prior_temperature=c["prior_temperature"])
    return kw


def task_step_scale(task: str) -> float:
    """The task's extension scale: its ``TaskSpec.step_scale``, else the step size of its first
    training problem (what ``train.tree.adapters.task_scales`` measures)."""
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401  (registers the built-in ids)
    from gnn_mp_envs.registration import task_spec
    spec = task_spec(task)
    if spec.step_scale is not None:
        return float(spec.step_scale)
    env = gym.make(spec.env_id, max_nodes=2, disable_env_checker=True)
    try:
        env.reset(seed=0, options={"index": 0})
        return float(env.unwrapped.problem.step_size)
    finally:
        env.close()


__all__ = ["TREE_GNN_ARCH", "candidate_kwargs", "candidate_settings", "encoder_kwargs", "env_kwargs",
           "sampler_uniform_mix", "task_step_scale"]
