"""Candidate priors by the checkpoint kind of the model they read.

A candidate picker (:mod:`agents.rl`) can rank its candidates by a supervised model's
:class:`~gnn_mp_envs.envs.candidates.CandidatePrior`; the method that owns the model (the tree
samplers: :mod:`agents.tree.prior`) provides the prior class. The picker asks this registry by the
model's kind and never imports the other method:

    prior = candidate_prior("tree/gnn-scorer", scorer_model, temperature=0.5)
    prior = supervised_prior("pendulum")            # the task's shipped ``gnn``, its stored settings

A prior class takes ``(model, **settings)`` and has ``model_class`` (the model it reads) and
``settings`` (the names of its settings, read from a checkpoint's ``meta["sampler"]``, 1.0 when
absent). :data:`CANDIDATE_PRIORS` names the built-in ones as ``"module:attribute"``, imported when
first asked for (as the checkpoint kinds' modules are); :func:`register_candidate_prior` adds one.
"""

from __future__ import annotations

from typing import Any, Mapping

from gnn_mp_envs.utils.imports import resolved

#: Checkpoint kind -> the prior class of a model of that kind (or its ``"module:attribute"``).
CANDIDATE_PRIORS: dict[str, Any] = {"tree/gnn-scorer": "agents.tree.prior:ScorerPrior",
                                    "tree/gnn": "agents.tree.prior:MixturePrior"}


def register_candidate_prior(kind: str, prior: Any) -> None:
    """Add the prior class (or its ``"module:attribute"``) of models of checkpoint kind ``kind``."""
    if kind in CANDIDATE_PRIORS:
        raise ValueError(f"a candidate prior for kind {kind!r} is already registered")
    CANDIDATE_PRIORS[kind] = prior


def prior_class(kind: str) -> Any:
    """The prior class of checkpoint kind ``kind`` (ValueError: no prior reads that kind)."""
    if kind not in CANDIDATE_PRIORS:
        raise ValueError(f"no candidate prior reads models of kind {kind!r}; known: {', '.join(CANDIDATE_PRIORS)}")
    return resolved(CANDIDATE_PRIORS, kind)


def prior_model(kind: str, ctor_args: Mapping[str, Any]) -> Any:
    """A fresh (untrained) model of kind ``kind`` built from its constructor arguments."""
    return prior_class(kind).model_class(**ctor_args)


def candidate_prior(kind: str, model: Any, **settings: Any) -> Any:
    """The candidate prior over ``model`` (a model of checkpoint kind ``kind``)."""
    return prior_class(kind)(model, **settings)


def supervised_prior(task: str | None, sampler: str = "gnn") -> Any:
    """The candidate prior of the task's shipped supervised ``sampler`` (``gnn-pick`` of a picker trained
    without one: a ``tree/gnn-scorer``'s scores, or a ``tree/gnn`` mixture's log-density), with the
    settings stored beside its weights."""
    from agents.checkpoints import load_checkpoint, resolve_checkpoint
    path = resolve_checkpoint(sampler, task, None, f"gnn-mp train sampler --task {task} --model {sampler}")
    model, record = load_checkpoint(path, expected_kind=list(CANDIDATE_PRIORS))
    cls = prior_class(record["kind"])
    stored = record["meta"].get("sampler", {})
    return cls(model, **{name: float(stored.get(name, 1.0)) for name in cls.settings})


__all__ = ["CANDIDATE_PRIORS", "candidate_prior", "prior_class", "prior_model", "register_candidate_prior",
           "supervised_prior"]
