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

**Per tree.** The statistics are those of the observation's tree (:class:`~agents.samplers.trees.TreeStates`,
keyed on the tree's content): a sampler fed two envs planning the same problem keeps each tree's
statistics apart and scores each sample against the tree it was drawn for, as one sampler per env would.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from agents.samplers.trees import TreeStates, tree_size

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
        self._trees: TreeStates[_TreeStats] = TreeStates(lambda: _TreeStats(self))
        self.clear()

    def clear(self) -> None:
        """Forget the episode (every tree's)."""
        self._trees.clear()
        self._tree = _TreeStats(self)

    # the statistics of the tree of the last observation
    #: Per source (uniform, model), discounted pulls and useful steps.
    pulls = property(lambda self: self._tree.pulls)
    useful = property(lambda self: self._tree.useful)
    #: Coverage cells reached, rows already scored, the source of the last sample until its outcome is read.
    visited = property(lambda self: self._tree.visited)
    seen = property(lambda self: self._tree.seen)
    pending = property(lambda self: self._tree.pending)
    #: The model's share for the next sample.
    share = property(lambda self: self._tree.share)
    #: Samples drawn from each source this episode (uniform, model, other): what the sampler did.
    drawn = property(lambda self: self._tree.drawn)

    # ------------------------------------------------------------------ per step
    def observe(self, obs: Mapping) -> float:
        """Score the last sample drawn for the observation's tree from ``obs`` and return the model's
        share for the next one."""
        tree = self._tree = self._trees.of(obs)
        n = tree_size(obs)
        source = tree.pending
        if type(source) is tuple:                 # a batch's samples (chose_batch): each scored in turn
            self._score_batch(obs, n, *source)
            tree.pending = None
            return tree.share
        useful = self._new_cells(obs, n)
        if source is not None and source != OTHER:
            self._pull(source, useful)
            self._update_share()
        tree.pending = None
        return tree.share

    def _pull(self, source: int, useful: bool) -> None:
        """One scored sample of the current tree: both sources' statistics decay, the pulled one gains
        a pull and its outcome (plain floats)."""
        tree = self._tree
        pulls, hits, discount = tree.pulls, tree.useful, self.discount
        pulls[0] *= discount
        pulls[1] *= discount
        hits[0] *= discount
        hits[1] *= discount
        pulls[source] += 1.0
        hits[source] += float(useful)

    def _update_share(self) -> None:
        """The model's share of the current tree from its sources' discounted success rates."""
        tree = self._tree
        hits, pulls = tree.useful, tree.pulls
        rate_model, rate_uniform = hits[MODEL] / pulls[MODEL], hits[UNIFORM] / pulls[UNIFORM]
        relative = 1.0 if rate_model >= rate_uniform else rate_model / max(rate_uniform, 1e-12)
        tree.share = self.floor + (self.top - self.floor) * relative ** self.power

    def chose(self, source: int) -> None:
        """The source of the sample just handed out (scored at the next :meth:`observe` of its tree)."""
        self._tree.pending = source
        self._tree.drawn[source] += 1

    def chose_batch(self, sources: np.ndarray, samples: np.ndarray) -> None:
        """The sources of a batch of samples just handed out, in the order the planner consumes them
        (``samples`` ``(k, d)``): scored at the next :meth:`observe` of their tree, one step each."""
        sources = np.asarray(sources, dtype=np.int64)
        self._tree.pending = (sources, np.asarray(samples, dtype=np.float64))
        self._tree.drawn += np.bincount(sources, minlength=3)[:3]

    def _score_batch(self, obs: Mapping, n: int, sources: np.ndarray, samples: np.ndarray) -> None:
        """Score a batch's samples from the observation after it: each new row that reached a new cell
        counts for the sample nearest to it (in cells; the node an extension makes lies between its
        nearest node and the sample, and the connect nodes of BiRRT follow it); then, sample by sample in
        order, the update of :meth:`observe` (a goal sample is not scored). One sample: exactly
        :meth:`observe`'s scoring of one step."""
        tree = self._tree
        first = tree.seen
        new = self._new_cell_rows(obs, n)
        useful = np.zeros(len(sources), dtype=bool)
        if any(new):
            rows = np.asarray(obs["nodes"][first:n], np.float64)[np.array(new)]
            if len(sources) == 1:
                useful[0] = True
            else:
                scale = np.array([a[1] for a in self.axes])
                diff = (rows[:, None, :] - samples[None, :, :]) * scale
                useful[np.unique(np.argmin((diff * diff).sum(-1), axis=1))] = True
        scored = [(source, hit) for source, hit in zip(sources.tolist(), useful.tolist()) if source != OTHER]
        for source, hit in scored:
            self._pull(source, hit)
        if scored:
            self._update_share()

    def _new_cell_rows(self, obs: Mapping, n: int) -> list[bool]:
        """:meth:`_new_cells` row by row: for rows ``seen..n-1``, whether each reached a cell not reached
        before (by an earlier row too)."""
        stats = self._tree
        if n <= stats.seen:
            return []
        # float32 rows as Python floats: the same values as a float64 copy, without the copy
        rows = np.asarray(obs["nodes"][stats.seen:n]).tolist()
        trees = np.asarray(obs["node_features"][stats.seen:n, -1]).tolist()
        cells, top, floor, visited = self.cells, self.cells - 1, math.floor, stats.visited
        out = [False] * len(rows)
        for r, (tree, row) in enumerate(zip(trees, rows)):
            key = [tree]
            for x, (low, scale, periodic) in zip(row, self.axes):
                i = floor((x - low) * scale)          # numpy's (rows - low) * scale, floored: the same floats
                key.append(i % cells if periodic else (0 if i < 0 else top if i > top else i))
            size = len(visited)
            visited.add(tuple(key))
            out[r] = len(visited) > size
        stats.seen = n
        return out

    def _new_cells(self, obs: Mapping, n: int) -> bool:
        """Mark the cells of rows ``seen..n-1`` of the current tree; whether any was new."""
        return any(self._new_cell_rows(obs, n))


class _TreeStats:
    """One tree's statistics (:class:`AdaptiveShare`), from the prior."""

    __slots__ = ("pulls", "useful", "visited", "seen", "pending", "share", "drawn")

    def __init__(self, owner: AdaptiveShare) -> None:
        # per source (uniform, model), plain floats: a step updates two numbers of each
        self.pulls = [owner.prior_weight, owner.prior_weight]
        self.useful = [owner.prior, owner.prior]
        self.visited: set[tuple] = set()
        self.seen = 0                       # observation rows already scored
        self.pending: int | None = None     # the source of the last sample, until its outcome is read
        self.share = owner.top
        self.drawn = np.zeros(3, dtype=np.int64)


__all__ = ["DEFAULTS", "GUARANTEE_FACTOR", "MODEL", "OTHER", "UNIFORM", "AdaptiveShare"]
