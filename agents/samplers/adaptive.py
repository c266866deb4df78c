"""The adaptive share of the one mixture: how much a learned sampler trusts its model, per problem.

A learned sampler trained on one family of problems can be worse than uniform sampling on
problems of kinds it never saw (a trap facing the start, a spiral): its samples push the tree
into dead ends. :class:`AdaptiveShare` watches, step by step, what each source's sample did to
the tree and moves the model's share of the mixture between a floor and its stored value,
a two-armed bandit over the sources ``uniform`` and ``model``:

* **Outcome of a step** (read from the next observation, which carries the tree): the step's
  sample was *useful* when it added a node in a cell of the state space the tree had not
  reached before (the box cut into ``cells`` equal slices per coordinate, per tree). A
  blocked extension adds no node; a node that lands among older ones (a sample inside or
  behind an obstacle the tree has already reached, the tree walking into a dead end) adds
  no new cell. For BiRRT the connect nodes of the step count for the sample that started it.
* **Estimates**: per source, the discounted rate of useful steps (discount ``discount`` per
  step, both sources), starting from ``prior`` useful steps in ``prior_weight`` pulls.
* **Share**: ``p_model = floor + (top - floor) * min(1, rate_model / rate_uniform) ** power``,
  ``top`` the stored model share (``1 - uniform_mix - goal_bias``). A model at least as useful
  as uniform keeps its whole share; one half as useful keeps ``2 ** -power`` of it above the floor.

**Guarantee.** The uniform share never drops below ``uniform_mix`` (the planner stays
probabilistically complete) and the model's never below ``floor`` (the model is re-tried when
the tree moves on). When the model's samples are useless (they add no new cell) while
uniform's are not, ``rate_model / rate_uniform`` decays by ``discount`` per step, so after a
transient of a few dozen steps the sampler is uniform sampling diluted by a ``floor`` share of
wasted steps: its counts are within ``1 / (1 - floor - goal_bias)`` of uniform's plus that
transient. ``tests/test_samplers.py`` holds it to ``GUARANTEE_FACTOR`` on 20 maze2d problems with
a model that always proposes a point inside a wall.

Deterministic: the share is a function of the observations seen; the only draw is the mixture's
one ``rng.random()`` per step (:class:`~agents.samplers.base.ModelSampler`). Numpy only.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

#: Sources the bandit tells apart (a goal-bias sample is neither and is not scored).
UNIFORM, MODEL, OTHER = 0, 1, 2
#: The documented bound of the guarantee test: a useless model's median counts over uniform's.
GUARANTEE_FACTOR = 1.3
#: Default settings (chosen on the validation kinds of each task, see docs/learned_samplers.md).
DEFAULTS = {"floor": 0.05, "discount": 0.97, "power": 2.0, "cells": 20, "prior": 1.0, "prior_weight": 2.0}


class AdaptiveShare:
    """Per-episode state of the adaptive mixture (see the module docstring).

    Args:
        low, high: the sampler's state box; ``periodic`` its wrapped coordinates.
        top: the model's share when it is at least as useful as uniform sampling.
        floor: the model's share when it is useless (``0 <= floor <= top``).
        discount: per-step discount of both sources' statistics.
        power: how fast the share falls with the model's relative rate.
        cells: slices per coordinate of the coverage grid.
        prior, prior_weight: ``prior`` useful steps in ``prior_weight`` pulls per source at the start.
    """

    def __init__(self, low: np.ndarray, high: np.ndarray, periodic: np.ndarray, top: float, *,
                 floor: float = DEFAULTS["floor"], discount: float = DEFAULTS["discount"],
                 power: float = DEFAULTS["power"], cells: int = DEFAULTS["cells"], prior: float = DEFAULTS["prior"],
                 prior_weight: float = DEFAULTS["prior_weight"]) -> None:
        if not 0.0 <= floor <= top <= 1.0:
            raise ValueError(f"the adaptive floor must be in [0, {top}] (the model's stored share), got {floor}")
        if not 0.0 < discount <= 1.0 or not power > 0 or int(cells) < 1 or not 0 <= prior <= prior_weight:
            raise ValueError(f"adaptive settings out of range: discount {discount} (0, 1], power {power} > 0, "
                             f"cells {cells} >= 1, 0 <= prior {prior} <= prior_weight {prior_weight}")
        low = np.asarray(low, np.float64)
        scale = float(cells) / (np.asarray(high, np.float64) - low)
        self.cells = int(cells)
        #: Per coordinate, as plain floats: ``(low, cells per unit, periodic)``, what a row's cell is made of.
        self.axes = list(zip(low.tolist(), scale.tolist(), np.asarray(periodic, bool).tolist()))
        self.top, self.floor, self.discount, self.power = float(top), float(floor), float(discount), float(power)
        self.prior, self.prior_weight = float(prior), float(prior_weight)
        self.clear()

    def clear(self) -> None:
        """Forget the episode."""
        # per source (uniform, model), plain floats: a step updates two numbers of each
        self.pulls = [self.prior_weight, self.prior_weight]
        self.useful = [self.prior, self.prior]
        self.visited: set[tuple] = set()
        self.seen = 0                       # observation rows already scored
        self.pending: int | None = None     # the source of the last sample, until its outcome is read
        self.episode: tuple | None = None
        self.share = self.top
        #: Samples drawn from each source this episode (uniform, model, other): what the sampler did.
        self.drawn = np.zeros(3, dtype=np.int64)

    # ------------------------------------------------------------------ per step
    def observe(self, obs: Mapping) -> float:
        """Score the last sample's outcome from ``obs`` and return the model's share for the next one."""
        n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
        episode = (np.asarray(obs["start"]).tobytes(), np.asarray(obs["goal"]).tobytes())
        if episode != self.episode or n < self.seen:
            self.clear()
            self.episode = episode
        useful = self._new_cells(obs, n)
        source = self.pending
        if source is not None and source != OTHER:
            # both sources' statistics decay; the pulled one gains a pull and its outcome (plain floats)
            pulls, hits, discount = self.pulls, self.useful, self.discount
            pulls[0] *= discount
            pulls[1] *= discount
            hits[0] *= discount
            hits[1] *= discount
            pulls[source] += 1.0
            hits[source] += float(useful)
            rate_model, rate_uniform = hits[MODEL] / pulls[MODEL], hits[UNIFORM] / pulls[UNIFORM]
            relative = 1.0 if rate_model >= rate_uniform else rate_model / max(rate_uniform, 1e-12)
            self.share = self.floor + (self.top - self.floor) * relative ** self.power
        self.pending = None
        return self.share

    def chose(self, source: int) -> None:
        """The source of the sample just handed out (scored at the next :meth:`observe`)."""
        self.pending = source
        self.drawn[source] += 1

    def _new_cells(self, obs: Mapping, n: int) -> bool:
        """Mark the cells of rows ``seen..n-1``; whether any was new."""
        if n <= self.seen:
            return False
        # float32 rows as Python floats: the same values as a float64 copy, without the copy
        rows = np.asarray(obs["nodes"][self.seen:n]).tolist()
        trees = np.asarray(obs["node_features"][self.seen:n, -1]).tolist()
        cells, top, floor, visited = self.cells, self.cells - 1, math.floor, self.visited
        size = len(visited)
        for tree, row in zip(trees, rows):
            key = [tree]
            for x, (low, scale, periodic) in zip(row, self.axes):
                i = floor((x - low) * scale)          # numpy's (rows - low) * scale, floored: the same floats
                key.append(i % cells if periodic else (0 if i < 0 else top if i > top else i))
            visited.add(tuple(key))
        self.seen = n
        return len(visited) > size


__all__ = ["DEFAULTS", "GUARANTEE_FACTOR", "MODEL", "OTHER", "UNIFORM", "AdaptiveShare"]
