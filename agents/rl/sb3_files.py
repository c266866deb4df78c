"""Stable-Baselines3 ``.zip`` files, read weights only: never an unpickled byte.

An SB3 ``model.save`` zip holds the networks' state dicts (``policy.pth``,
``policy.optimizer.pth``, ``pytorch_variables.pth``: read here with
``torch.load(weights_only=True)``) and a JSON member ``data`` whose entries that are not plain
JSON (policy keywords, spaces, schedules) are cloudpickled; ``PPO.load`` unpickles them, which
runs whatever code a crafted file carries. Here they are never decoded: the model is rebuilt from
what the caller trusts and only the tensors (and the plain step count) are taken.

- :func:`read_sb3_zip`: the zip's tensors and plain JSON; ``gnn-mp train rl --resume`` continues a
  model built from the run's checked flags with it (``train.rl.sb3.load_weights_only``).
- :func:`sb3_zip_record`: a zip written by ``gnn-mp train rl`` (``model.zip``, ``best_model.zip``)
  as a checkpoint record, the model rebuilt from the run's ``config.json`` beside it (the
  architecture's flags, :mod:`agents.rl.run_config`) and exported as the policy
  ``policy.pt`` would hold. :mod:`agents.checkpoints` reads such a zip through it, so it is taken
  wherever a checkpoint is (``load_sampler(..., checkpoint="run/model.zip")``, ``gnn-mp benchmark
  --checkpoint rl-ppo=run/model.zip``, ``--init-from``); a zip without a readable ``config.json``
  beside it is refused in one line, and one of another task by the sampler's task check.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import torch

from agents.checkpoints import CheckpointError, checkpoint_record

#: The flags of a run's ``config.json`` the model is rebuilt from (fields of ``train.rl.args.RLArgs``).
CONFIG_KEYS = ("lib", "algo", "task", "planner", "view_nodes", "action", "candidates", "local_scale", "target_scale",
               "action_frame", "uniform_mix", "progress_reward", "gamma", "reward_scale", "max_episode_steps",
               "hidden_channels", "num_layers", "out_channels", "conv", "knn", "net_arch", "pi_arch", "pick_head",
               "candidate_hidden", "candidate_embed", "tree_context", "prior", "prior_temperature", "encoder",
               "log_std_init")
#: (lib, algo) of a run -> the sampler its policy becomes
SB3_SAMPLERS = {"ppo": "rl-ppo", "sac": "rl-sac"}


@dataclass
class SB3Zip:
    """The weights-only contents of an SB3 zip."""

    #: state dicts by member name without ``.pth``: ``policy``, ``policy.optimizer``, (SAC) ``actor.optimizer``, ...
    params: dict[str, dict[str, torch.Tensor]]
    #: ``pytorch_variables.pth`` (SAC: ``log_ent_coef``), or None
    variables: dict[str, torch.Tensor] | None
    #: the ``data`` member as JSON; its serialized entries are left as the strings they are
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def num_timesteps(self) -> int | None:
        steps = self.data.get("num_timesteps")
        return steps if isinstance(steps, int) and not isinstance(steps, bool) and steps >= 0 else None


def read_sb3_zip(path: str | Path, device: str | torch.device = "cpu") -> SB3Zip:
    """The tensors and the plain JSON of an SB3 zip; a one-line :class:`CheckpointError` for anything
    else (not a zip, no ``policy.pth``, members that hold more than tensors and plain values)."""
    path = Path(path)
    params: dict[str, Any] = {}
    variables = None
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
            if "policy.pth" not in names or "data" not in names:
                raise CheckpointError(f"{path}: not a Stable-Baselines3 zip (no data and policy.pth members)")
            data = json.loads(archive.read("data"))
            for name in names:
                if not name.endswith(".pth"):
                    continue
                with archive.open(name) as member:
                    value = torch.load(member, map_location=device, weights_only=True)
                if name in ("pytorch_variables.pth", "tensors.pth"):
                    variables = value
                else:
                    params[name[: -len(".pth")]] = value
    except CheckpointError:
        raise
    except pickle.UnpicklingError:
        raise CheckpointError(f"{path}: refused, a member holds more than weights and plain values (loading would "
                              "import or run code)") from None
    except (OSError, ValueError, RuntimeError, EOFError, KeyError, zipfile.BadZipFile, UnicodeDecodeError) as exc:
        detail = str(exc).strip().splitlines()[0][:100] if str(exc).strip() else ""
        raise CheckpointError(f"{path}: not a readable Stable-Baselines3 zip ({type(exc).__name__}"
                              f"{': ' + detail if detail else ''})") from None
    if not isinstance(data, dict):
        raise CheckpointError(f"{path}: not a Stable-Baselines3 zip (its data member is not a JSON object)")
    if not all(isinstance(v, dict) for v in params.values()) or not isinstance(variables, (dict, type(None))):
        raise CheckpointError(f"{path}: not a Stable-Baselines3 zip (a .pth member is not a state dict)")
    return SB3Zip(params, variables, data)


def sb3_policy_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    """SB3's ``policy_kwargs`` of a run: the candidate extractor with the picker's head (``pick``,
    :class:`~agents.rl.sb3.CandidatePickPolicy`) or the tree encoder with a Gaussian head (``box``)."""
    from agents.rl.run_config import candidate_kwargs, encoder_kwargs
    from agents.rl.sb3 import CandidateFeaturesExtractor, TreeFeaturesExtractor
    if config["action"] == "pick":
        return {"features_extractor_class": CandidateFeaturesExtractor,
                "features_extractor_kwargs": candidate_kwargs(config), "pick_head": config["pick_head"],
                "net_arch": {"pi": list(config["pi_arch"]), "vf": list(config["net_arch"])}}
    kwargs = {"features_extractor_class": TreeFeaturesExtractor, "features_extractor_kwargs": encoder_kwargs(config),
              "net_arch": list(config["net_arch"])}
    if config["algo"] == "ppo":
        kwargs["log_std_init"] = config["log_std_init"]
    return kwargs


def run_config_of(path: Path) -> dict[str, Any]:
    """The ``config.json`` of the run that wrote the zip ``path`` (beside it), checked to describe an
    SB3 run of ``gnn-mp train rl``."""
    source = path.parent / "config.json"
    try:
        config = json.loads(source.read_text())
    except FileNotFoundError:
        raise CheckpointError(f"{path}: an SB3 zip is read with its run's config.json beside it (gnn-mp train rl "
                              f"writes one; its pickled entries are never loaded), and {source} does not exist"
                              ) from None
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{path}: its run's {source} is unreadable ({type(exc).__name__})") from None
    if not isinstance(config, dict):
        raise CheckpointError(f"{path}: its run's {source} is not a gnn-mp train rl config (not a JSON object)")
    missing = [k for k in CONFIG_KEYS if k not in config]
    if missing:
        raise CheckpointError(f"{path}: its run's {source} is not a gnn-mp train rl config (missing: "
                              f"{', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''})")
    if config["lib"] != "sb3" or config["algo"] not in SB3_SAMPLERS:
        raise CheckpointError(f"{path}: its run's {source} describes a {config['lib']} {config['algo']} run, not an "
                              "SB3 PPO or SAC one")
    from gnn_mp_envs.registration import TASK_SPECS
    if config["task"] not in TASK_SPECS:
        raise CheckpointError(f"{path}: its run trained on task {config['task']!r}, which is not registered here "
                              "(--import the module that registers it)")
    return config


def _rebuilt(path: Path, config: Mapping[str, Any], state: Mapping[str, torch.Tensor]) -> tuple:
    """The run's SB3 model rebuilt from its flags, the zip's policy weights in, exported as the policy
    ``policy.pt`` holds: ``(policy, kind, ctor_args)``."""
    from stable_baselines3 import PPO, SAC

    from agents.rl.policies import policy_from_sb3
    from agents.rl.run_config import env_kwargs
    from agents.rl.sb3 import CandidatePickPolicy
    from gnn_mp_envs.envs.wrappers import make_rl_env
    env = make_rl_env(config["task"], split="train", **env_kwargs(config))
    try:
        kwargs = {"policy_kwargs": sb3_policy_kwargs(config), "device": "cpu", "seed": 0, "verbose": 0}
        if config["algo"] == "ppo":
            policy = CandidatePickPolicy if config["action"] == "pick" else "MultiInputPolicy"
            model = PPO(policy, env, n_steps=2, batch_size=2, **kwargs)   # a 2-step buffer: only the networks matter
        else:
            model = SAC("MultiInputPolicy", env, buffer_size=1, **kwargs)
    finally:
        env.close()
    try:
        model.policy.load_state_dict(dict(state))
    except RuntimeError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        detail = (lines[1] if len(lines) > 1 else lines[0] if lines else "")[:120]
        raise CheckpointError(f"{path}: its weights do not fit the model its run's config.json describes "
                              f"({detail})") from None
    return policy_from_sb3(model)


def sb3_zip_record(path: str | Path) -> dict[str, Any]:
    """A zip of a ``gnn-mp train rl`` SB3 run as the checkpoint record of its policy (what the run's
    ``policy.pt`` holds for the same weights): kind ``rl/sb3-ppo``, ``rl/sb3-ppo-pick`` or
    ``rl/sb3-sac``, the sampler settings of the run (its uniform mixture, candidates), ``meta["task"]``
    the run's task. Weights only; one-line :class:`CheckpointError` for anything unusable."""
    from agents.rl.run_config import candidate_settings, sampler_uniform_mix
    from agents.rl.sampler import policy_record
    from gnn_mp_envs.registration import task_spec
    path = Path(path)
    contents = read_sb3_zip(path)
    config = run_config_of(path)
    try:
        policy, kind, ctor_args = _rebuilt(path, config, contents.params["policy"])
        spec = task_spec(config["task"])
        low, high = spec.state_bounds()
        pick = config["action"] == "pick"
        obs_spec, meta = policy_record(
            task=config["task"], view_nodes=config["view_nodes"], low=low, high=high,
            uniform_mix=sampler_uniform_mix(config), action_frame=config["action_frame"],
            periodic=spec.periodic_mask(len(low)).tolist(), candidates=candidate_settings(config) if pick else None,
            meta={"sampler_name": SB3_SAMPLERS[config["algo"]], "planner": config["planner"], "train_config": config,
                  "sb3_zip": {"path": str(path), "steps": contents.num_timesteps}})
        return checkpoint_record(policy, kind, ctor_args, obs_spec=obs_spec, meta=meta)
    except CheckpointError:
        raise
    except (ValueError, TypeError, KeyError, RuntimeError, OSError, AssertionError, IndexError) as exc:
        text = str(exc).strip().splitlines()
        detail = f": {text[0][:120]}" if text else ""
        raise CheckpointError(f"{path}: its model cannot be rebuilt from its run's config.json "
                              f"({type(exc).__name__}{detail})") from None


__all__ = ["CONFIG_KEYS", "SB3Zip", "read_sb3_zip", "run_config_of", "sb3_policy_kwargs", "sb3_zip_record"]
