"""The sampler registry: every sampler is built by name through :func:`load_sampler`.

    sampler = load_sampler("goal-bias", task="maze2d", seed=0)            # bounds from the TaskSpec
    sampler = load_sampler("gnn", task="arm")                              # the shipped weights
    sampler = load_sampler("gnn", task="arm", checkpoint="runs/.../model.pt")
    sampler = load_sampler("uniform", bounds=(low, high))                  # a box of your own
    sampler = load_sampler(sampler_for_checkpoint(path), checkpoint=path)  # whichever sampler runs the file

A factory receives ``(low, high, task, seed, checkpoint, **settings)``; the registry refuses,
in one line each, an unknown name, an unknown task, bounds that are not the task's, a setting
the sampler does not take (a typo such as ``goal_bais``) and a checkpoint of another task.
Learned samplers load on first use (listing the registry, ``gnn-mp samplers``, imports no
torch_geometric).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

if TYPE_CHECKING:
    from agents.samplers.base import Sampler


@dataclass(frozen=True)
class SamplerEntry:
    """A registered sampler: how to build it and what it accepts."""

    factory: Callable[..., "Sampler"]
    description: str = ""
    #: Keyword settings the factory accepts besides checkpoint (None: decided by the checkpoint).
    settings: tuple[str, ...] | None = ()
    #: Whether it needs weights (then ``task=`` or ``checkpoint=``).
    learned: bool = False
    #: The checkpoint kinds it loads (:func:`sampler_for_checkpoint`: a file's sampler from its kind).
    kinds: tuple[str, ...] = ()


SAMPLERS: dict[str, SamplerEntry] = {}


def register_sampler(name: str, factory: Callable[..., "Sampler"], description: str = "", *,
                     settings: tuple[str, ...] | None = (), learned: bool = False,
                     kinds: tuple[str, ...] = ()) -> None:
    """Add a sampler to the registry (names are unique); ``kinds``: the checkpoint kinds it loads, so
    that a file of one of them runs as this sampler under a name of its own
    (``gnn-mp benchmark --checkpoint NAME=PATH``, :func:`sampler_for_checkpoint`)."""
    if name in SAMPLERS:
        raise ValueError(f"sampler {name!r} is already registered")
    SAMPLERS[name] = SamplerEntry(factory, description, settings, learned, tuple(kinds))


def sampler_for_checkpoint(checkpoint: str | Path) -> str:
    """The registered sampler that runs ``checkpoint``, from the kind the file holds (the first sampler
    registered with that kind: ``rl/torchrl-ppo-pick`` -> ``rl-ppo-torchrl``, ``tree/gnn`` -> ``gnn``;
    an SB3 ``.zip`` of a ``gnn-mp train rl`` run reads as its policy's kind). One-line ``ValueError``
    (a :class:`~agents.checkpoints.CheckpointError` for a file that is no checkpoint)."""
    missing = missing_learned_modules()
    if missing:
        raise ValueError(missing_extra_message(f"checkpoint {checkpoint}", missing))
    from agents.checkpoints import read_checkpoint
    kind = read_checkpoint(checkpoint)["kind"]
    for name, entry in SAMPLERS.items():
        if kind in entry.kinds:
            return name
    runs = sorted({k for entry in SAMPLERS.values() for k in entry.kinds})
    raise ValueError(f"{checkpoint}: a {kind!r} checkpoint, which no registered sampler runs (samplers run "
                     f"{', '.join(runs)})")


def available_samplers() -> list[str]:
    return sorted(SAMPLERS)


def descriptions() -> dict[str, str]:
    return {name: entry.description for name, entry in SAMPLERS.items()}


def _bounds_for(name: str, task: str | None, bounds: tuple[Any, Any] | None) -> tuple[np.ndarray, np.ndarray]:
    from gnn_mp_envs.registration import same_bounds, task_spec
    if task is None:
        if bounds is None:
            raise ValueError(f"sampler {name!r} needs task=NAME (bounds from its TaskSpec) or bounds=(low, high)")
        low, high = (np.asarray(b, dtype=np.float64) for b in bounds)
        return low, high
    spec_low, spec_high = task_spec(task).state_bounds()
    if bounds is not None:
        low, high = (np.asarray(b, dtype=np.float64) for b in bounds)
        if not same_bounds((low, high), (spec_low, spec_high)):
            raise ValueError(f"bounds {low.tolist()}..{high.tolist()} are not task {task!r}'s "
                             f"({spec_low.tolist()}..{spec_high.tolist()})")
    return spec_low, spec_high


#: Modules the learned samplers import, all from the ``agents`` extra.
LEARNED_MODULES = ("torch", "tensordict", "torch_geometric", "threadpoolctl")
#: What an environments-only install runs to get them.
AGENTS_EXTRA_HINT = "pip install 'gnn-mp-envs[agents]'"


def missing_learned_modules() -> list[str]:
    """The modules of :data:`LEARNED_MODULES` this interpreter cannot import (an environments-only
    install lacks all of them); found without importing them."""
    import importlib.util

    def missing(module: str) -> bool:
        try:
            return importlib.util.find_spec(module) is None
        except (ImportError, ValueError):
            return True
    return [m for m in LEARNED_MODULES if missing(m)]


def missing_extra_message(what: str, missing: list[str]) -> str:
    """One line: ``what`` needs the agents extra (``missing`` modules), and the command that installs it."""
    return f"{what} needs the 'agents' extra ({', '.join(missing)} not installed): {AGENTS_EXTRA_HINT}"


def load_sampler(name: str, task: str | None = None, *, seed: int | None = None,
                 checkpoint: str | Path | None = None, bounds: tuple[Any, Any] | None = None,
                 threads: int | None = 1, **settings: Any) -> "Sampler":
    """Build the sampler ``name`` for ``task`` (its sampling bounds from the task's
    :class:`~gnn_mp_envs.registration.TaskSpec`), or for ``bounds=(low, high)`` without a task.

    A learned sampler runs a small forward every step: loading one sets torch to ``threads``
    threads for the process (:data:`agents.samplers.base.INFERENCE_THREADS`, the one thread
    policy; ``threads=None`` leaves torch as it is)."""
    try:
        entry = SAMPLERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown sampler {name!r}; known: {', '.join(available_samplers())}") from None
    if task is not None and not isinstance(task, str):
        raise ValueError(f"task must be a task name, got {type(task).__name__} (bounds go in bounds=(low, high))")
    if entry.settings is not None:
        unknown = sorted(set(settings) - set(entry.settings))
        if unknown:
            takes = ", ".join(entry.settings) or "no settings"
            raise ValueError(f"sampler {name!r} takes {takes}; unknown: {', '.join(unknown)}")
    if checkpoint is not None and not entry.learned:
        raise ValueError(f"sampler {name!r} has no weights (checkpoint= is for learned samplers)")
    if entry.learned:
        missing = missing_learned_modules()
        if missing:
            raise ValueError(missing_extra_message(f"sampler {name!r}", missing))
    if entry.learned and task is None and checkpoint is None:
        raise ValueError(f"sampler {name!r} needs task= (its shipped weights are per task) or checkpoint=PATH")
    if entry.learned and task is None:
        task = _checkpoint_task(checkpoint)
    low, high = _bounds_for(name, task, bounds)
    extra = {"checkpoint": checkpoint} if entry.learned else {}
    if entry.learned:
        from agents.samplers.base import use_inference_threads
        use_inference_threads(threads)
    return entry.factory(low=low, high=high, task=task, seed=seed, **extra, **settings)


def _checkpoint_task(checkpoint: str | Path) -> str:
    """The task a checkpoint's weights were trained for (``meta["task"]``)."""
    from agents.checkpoints import read_checkpoint
    task = (read_checkpoint(checkpoint).get("meta") or {}).get("task")
    if not isinstance(task, str):
        raise ValueError(f"{checkpoint}: names no task (meta['task']); pass task=")
    return task


# ---------------------------------------------------------------------------- built-in samplers
def _uniform(low, high, task=None, seed=None):
    from agents.samplers.baselines import UniformSampler
    return UniformSampler(low, high, seed)


def _goal_bias(low, high, task=None, seed=None, goal_bias=0.05):
    from agents.samplers.baselines import GoalBiasSampler
    return GoalBiasSampler(low, high, seed, goal_bias)


def _halton(low, high, task=None, seed=None):
    from agents.samplers.baselines import HaltonSampler
    return HaltonSampler(low, high, seed)


def _lazy(module: str, function: str, name: str) -> Callable[..., "Sampler"]:
    """A factory that imports ``module`` (torch_geometric and friends) only when a sampler is built."""
    def factory(**kwargs):
        return getattr(importlib.import_module(module), function)(name, **kwargs)
    return factory


register_sampler("uniform", _uniform, "uniform over the state bounds")
register_sampler("goal-bias", _goal_bias, "uniform with 5% samples at the active tree's target",
                 settings=("goal_bias",))
register_sampler("halton", _halton, "a scrambled Halton sequence over the state bounds (VAMP's default)")
#: The checkpoint kinds of the built-in learned samplers (``agents.tree.samplers.NAME_KINDS``,
#: ``agents.rl.sampler.RL_SAMPLERS``; written out so that listing the registry imports no torch).
BUILTIN_KINDS: dict[str, tuple[str, ...]] = {
    "gnn": ("tree/gnn", "tree/gnn-scorer"), "cvae": ("tree/cvae",), "gnn-cvae": ("tree/gnn-cvae",),
    "rl-ppo": ("rl/sb3-ppo", "rl/sb3-ppo-pick"), "rl-sac": ("rl/sb3-sac",),
    "rl-ppo-torchrl": ("rl/torchrl-ppo", "rl/torchrl-ppo-pick")}
register_sampler("gnn", _lazy("agents.tree.samplers", "load_tree_sampler", "gnn"),
                 "learned (Algorithm 1): causal tree GNN, a node-mixture over the tree (pendulum: a scorer of "
                 "16 uniform candidates); shipped weights per task with their uniform/goal mix",
                 settings=None, learned=True, kinds=BUILTIN_KINDS["gnn"])
register_sampler("cvae", _lazy("agents.tree.samplers", "load_tree_sampler", "cvae"),
                 "learned baseline (Ichter et al. 2018): CVAE on start, goal and obstacles; ignores the tree",
                 settings=None, learned=True, kinds=BUILTIN_KINDS["cvae"])
register_sampler("gnn-cvae", _lazy("agents.tree.samplers", "load_tree_sampler", "gnn-cvae"),
                 "learned baseline: CVAE conditioned on the causal GNN's tree context", settings=None, learned=True,
                 kinds=BUILTIN_KINDS["gnn-cvae"])
for _name, _what, _ships in (("rl-ppo", "SB3 PPO", "shipped for maze2d, pendulum, arm and panda-mbm"),
                             ("rl-sac", "SB3 SAC", "no shipped weights"),
                             ("rl-ppo-torchrl", "TorchRL PPO", "shipped for pendulum and arm")):
    register_sampler(_name, _lazy("agents.rl.sampler", "load_rl_sampler", _name),
                     f"{_what} policy over the tree view (gnn-mp train rl; {_ships})",
                     settings=("uniform_mix", "deterministic", "proposals"), learned=True, kinds=BUILTIN_KINDS[_name])
register_sampler("gnn-pick", _lazy("agents.rl.sampler", "load_rl_sampler", "gnn-pick"),
                 "the shipped rl-ppo picker's candidates, picked by the supervised model alone (what RL adds over "
                 "it): the picker's own scorer prior, or the task's gnn mixture density",
                 settings=("uniform_mix", "deterministic", "proposals"), learned=True)


__all__ = ["BUILTIN_KINDS", "SAMPLERS", "SamplerEntry", "available_samplers", "descriptions", "load_sampler",
           "register_sampler", "sampler_for_checkpoint"]
