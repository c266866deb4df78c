"""Samplers over the growing tree: the GNN (node mixture), the GNN sample scorer (the pendulum's
GNN head), the CVAE and the GNN-CVAE of :mod:`agents.tree.models` / :mod:`agents.tree.scorer`.

Each is a :class:`~agents.samplers.base.ModelSampler` (the one uniform / goal / model mixture,
one numpy stream); :meth:`model_sample` is the model's part:

* ``gnn`` (:class:`TreeGNNSampler`): a node of the tree ~ softmax(key . q / temperature), then a
  Gaussian around its learned offset (scale times ``sigma_scale``);
* ``gnn`` on tasks whose ``TaskSpec.gnn_head`` is ``"scorer"`` (:class:`TreeScorerSampler`):
  ``candidates`` uniform states, one drawn with softmax(score / temperature);
* ``cvae`` (:class:`TreeCVAESampler`): decodes ``proposals`` states per forward pass for the
  problem (start, goal, obstacles) and spends them over the next steps; it ignores the tree;
* ``gnn-cvae`` (:class:`TreeGNNCVAESampler`): the causal GNN's tree context and a latent draw,
  decoded into the next sample.

**Inference cost.** The GNN models read the tree through the incremental engines of
:mod:`agents.tree.engine` (each new node embedded once); ``tools/bench_sampler.py`` reports the
cost at 1,000 nodes. The batched TensorDict path (:meth:`propose`) runs ``act`` per
observation with cleared caches (the same distribution).
"""

from __future__ import annotations

import numbers
from pathlib import Path
from typing import Mapping

import numpy as np
import torch

from agents.samplers.base import ModelSampler
from agents.samplers.trees import tree_size
from agents.tree.compiled import assemble_batch, draw_around_nodes, split_batch
from agents.tree.engine import IncrementalTreeGNN, IncrementalTreeScorer
from agents.tree.models import TreeCVAE, TreeGNN, TreeGNNCVAE
from agents.tree.scorer import TreeGNNScorer


_ZERO = np.zeros(1, dtype=np.int64)
#: The mixtures of a batch without model samples (never read), and each tree's row in a batch's
#: mixtures: ``[tree 0's, tree 1's]``, whether tree 0's mixture was computed or not.
_NO_MIXTURE = np.zeros((1, 1))
_MIXTURE_ROWS = {True: np.array([0, 1], dtype=np.int64), False: np.array([0, 0], dtype=np.int64)}


class _EngineSampler(ModelSampler):
    """A sampler that reads the tree through an incremental engine (per-episode caches)."""

    engine: IncrementalTreeGNN | IncrementalTreeScorer

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        if hasattr(self, "engine"):
            self.engine.clear()

    def act_stateless(self, obs: Mapping) -> np.ndarray:
        self.engine.clear()
        if self.adaptive is not None:
            self.adaptive.clear()
        return self.act(obs)

    @staticmethod
    def active(obs: Mapping) -> int:
        return int(np.asarray(obs["active_tree"]).reshape(-1)[0])

    def tree_context(self, obs: Mapping) -> tuple[np.ndarray, int]:
        """Ingest the observation's new nodes; the tree context ``q`` and the active tree (one compiled call)."""
        active = self.active(obs)
        return self.engine.grown_context(obs, self.engine.new_rows(obs), active), active


class _BatchDecoder:
    """A CVAE-style sampler's decoding: ``proposals`` latent draws decoded at once for one condition,
    finished as actions (wrapped, clipped, float32) and handed out one per model sample, last first."""

    def decode(self, obs: Mapping) -> list[np.ndarray]:
        raise NotImplementedError

    def decode_batch(self, condition: torch.Tensor) -> list[np.ndarray]:
        """``proposals`` finished actions for ``condition`` (the latent draws from the sampler's stream)."""
        z = torch.as_tensor(self.rng.standard_normal((self.proposals, self.model.latent_channels)),
                            dtype=torch.float32)
        with torch.inference_mode():
            states = self.model.decode_for_one(z, condition).double().numpy()
        return list(self.finish(states))

    def model_action(self, obs: Mapping) -> np.ndarray:
        return self.refreshed(obs, self.decode).pop()

    def model_sample(self, obs: Mapping) -> np.ndarray:
        """The next decoded state, already an action (wrapped, clipped, float32)."""
        return self.model_action(obs)


class TreeGNNSampler(_EngineSampler):
    """The GNN sampler (Algorithm 1): a node ~ softmax(key . q / temperature), then a Gaussian
    around its learned offset (scale times ``sigma_scale``). With ``proposals`` > 1 the tree is
    read and the mixture computed once per ``proposals`` samples (the nodes added since are not
    candidates until the next refresh).

    ``refresh_growth`` (batches, without the adaptive share): a forward's mixture serves the batches
    after it until the tree has grown by more than that fraction of the nodes it had (0: a forward
    whenever the tree has grown). A forward costs in proportion to the tree (the node mixture is over
    every node), while a batch's new nodes change the mixture of a large tree little: with 0.02 a tree
    of 4,000 nodes is read again once more than 80 nodes were added, one of 40 after each batch that adds
    one. Only with fixed shares and ``proposals=1`` (refused otherwise)."""

    settings = ("uniform_mix", "goal_bias", "temperature", "sigma_scale", "proposals", "adaptive", "samples_per_step",
                "refresh_growth")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeGNN,
                 uniform_mix: float = 0.25, goal_bias: float = 0.0, temperature: float = 1.0,
                 sigma_scale: float = 1.0, proposals: int = 1, adaptive: bool | Mapping = False,
                 samples_per_step: int = 1, refresh_growth: float = 0.0) -> None:
        if not (np.isfinite(temperature) and temperature > 0 and np.isfinite(sigma_scale) and sigma_scale > 0):
            raise ValueError(f"temperature and sigma_scale must be finite and > 0, got {temperature}, {sigma_scale}")
        if isinstance(refresh_growth, (bool, np.bool_)) or not (isinstance(refresh_growth, numbers.Real)
                                                                and np.isfinite(refresh_growth) and refresh_growth >= 0):
            raise ValueError(f"refresh_growth must be a finite number >= 0, got {refresh_growth!r}")
        if refresh_growth > 0 and (adaptive or proposals != 1):
            raise ValueError("refresh_growth applies to batches with fixed shares and proposals=1 (the adaptive share "
                             "and proposals > 1 read the tree their own way); set it to 0 or adaptive=False, "
                             "proposals=1")
        self.refresh_growth = float(refresh_growth)
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.periodic.numpy(), proposals=proposals, adaptive=adaptive,
                         samples_per_step=samples_per_step)
        self.model = model.eval()
        self.engine = IncrementalTreeGNN(model)
        self.temperature, self.sigma_scale = float(temperature), float(sigma_scale)

    def mixture(self, obs: Mapping) -> tuple:
        """The forward: ``(active tree, cumulative node probabilities, component shift)``.

        It draws nothing, so while the tree is the one of the last forward (the extensions since were
        blocked: about half of them on maze2d) its result is that forward's, returned as it is.
        """
        e = self.engine
        rows = e.new_rows(obs)
        active = self.active(obs)
        tree = (e.generation, rows[1], active)
        if tree != self._mixture_of:
            # the new rows' embeddings, the context and the mixture: one compiled call
            _, cumulative, shift = e.grown_mixture(obs, rows, active, self.temperature)
            self._mixture, self._mixture_of = (active, cumulative, shift), tree
        return self._mixture

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._mixture_of: tuple | None = None
        #: The batches' last forward: ``(engine generation, nodes, trees)`` and its ``(cumulative, shifts)``.
        self._batch_mixture_of: tuple | None = None

    def act(self, obs: Mapping) -> np.ndarray:
        if self.adaptive is not None or self.proposals != 1:
            return super().act(obs)
        return self.act_batch(obs, 1)[0]

    def act_batch(self, obs: Mapping, k: int) -> np.ndarray:
        """:meth:`ModelSampler.act_batch <agents.samplers.base.ModelSampler.act_batch>`'s draws and floats,
        with the choices, the forward and the samples in three compiled calls (:func:`split_batch`,
        :meth:`IncrementalTreeGNN.grown_mixtures`, :func:`assemble_batch`) instead of a few dozen numpy
        operations: after the planner's loop has run, the interpreter's and numpy's code and data are out of
        the caches and each operation costs several microseconds. The adaptive share and ``proposals`` > 1
        take the general path."""
        if self.adaptive is not None or self.proposals != 1:
            return super().act_batch(obs, k)
        d = self.state_dim
        start, goal = obs["start"], obs["goal"]
        if np.shape(start)[-1] != d:
            self.check_observation(obs)
        k = int(k)
        n = tree_size(obs)
        two_trees = n >= 2 and obs["node_features"][1, -1] == 1
        kinds, trees = np.empty(k, dtype=np.int64), np.empty(k, dtype=np.int64)
        nu, nm, need0, need1 = split_batch(self.rng.random(k), self.uniform_mix, self.goal_bias, self.active(obs),
                                           two_trees, kinds, trees)
        uniform = self.rng.random((nu, d))
        e = self.engine
        cumulative = shifts = _NO_MIXTURE
        if nm:
            rows = e.new_rows(obs)
            needed = (0, 1) if need0 and need1 else ((0,) if need0 else (1,))
            last = self._batch_mixture_of
            if (last is None or last[0] != e.generation or last[2] != needed or rows[1] < last[1]
                    or rows[1] > last[1] * (1.0 + self.refresh_growth)):
                self._batch_mixture = self.timed(lambda o: self.mixtures(o, np.array(needed, dtype=np.int64)), obs)
                self._batch_mixture_of = (e.generation, rows[1], needed)
            cumulative, shifts = self._batch_mixture
        r = self.rng.random(nm)
        z = self.rng.standard_normal((nm, e.d))
        out = np.empty((k, d), dtype=np.float32)
        assemble_batch(kinds, trees, uniform, r, z, cumulative, shifts, _MIXTURE_ROWS[need0], e.states, e.offsets,
                       e.log_sigma, self.sigma_scale, self.low, self._range, self.high, self.periodic,
                       np.asarray(start, np.float32), np.asarray(goal, np.float32), out)
        return out

    def model_sample(self, obs: Mapping) -> np.ndarray:
        active, cumulative, shift = self.refreshed(obs, self.mixture)
        e = self.engine
        if self.proposals > 1 and (len(cumulative) > e.n or not e.same_tree(obs)):
            # a forward of this tree reused after the engine read another one (one sampler, several envs):
            # its rows again (append-only and causal: the values the forward drew on)
            e.ingest(obs)
        r = self.rng.random(1)
        x = np.empty((1, e.d))
        draw_around_nodes(cumulative[None], shift[None], _ZERO, np.full(1, active), r,
                          self.rng.standard_normal((1, e.d)), e.states, e.offsets, e.log_sigma, self.sigma_scale, x)
        return x[0]

    def mixtures(self, obs: Mapping, trees: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A batch's forward: the new rows embedded once, the node mixture of each tree of ``trees``
        (running sums ``(len(trees), n)``, shifts ``(len(trees), d)``), in one compiled call."""
        e = self.engine
        return e.grown_mixtures(obs, e.new_rows(obs), trees, self.temperature)

    def model_batch(self, obs: Mapping, trees: np.ndarray) -> np.ndarray:
        """The batch's model samples from one forward (:meth:`mixtures`) over the tree as it stands: per
        sample a node of its tree's mixture, then the Gaussian around its offset. Draws: the ``m`` node
        choices (``rng.random(m)``), then the ``m`` Gaussians' normals (``(m, d)``); for one sample those
        of :meth:`model_sample`, with the same floats."""
        e = self.engine
        trees = np.asarray(trees, dtype=np.int64)
        needed = np.flatnonzero(np.bincount(trees, minlength=2))
        cumulative, shifts = self.timed(lambda o: self.mixtures(o, needed), obs)
        m = len(trees)
        r = self.rng.random(m)
        z = self.rng.standard_normal((m, e.d))
        x = np.empty((m, e.d))
        rows = needed.searchsorted(trees)           # each sample's mixture
        draw_around_nodes(cumulative, shifts, rows, trees, r, z, e.states, e.offsets, e.log_sigma, self.sigma_scale, x)
        return self.finish(x)


class TreeScorerSampler(_EngineSampler):
    """``candidates`` uniform states, one drawn with ``softmax(score / temperature)`` of the
    :class:`TreeGNNScorer` (each candidate scored with its nearest node of the active tree under
    the planner's metric: the node the planner would extend)."""

    settings = ("uniform_mix", "goal_bias", "candidates", "temperature", "adaptive", "samples_per_step")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeGNNScorer,
                 uniform_mix: float = 0.2, goal_bias: float = 0.05, candidates: int = 16,
                 temperature: float = 1.0, adaptive: bool | Mapping = False, samples_per_step: int = 1) -> None:
        if int(candidates) < 1 or not (np.isfinite(temperature) and temperature > 0):
            raise ValueError(f"candidates must be >= 1 and temperature finite and > 0, got {candidates}, {temperature}")
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.periodic.numpy(), adaptive=adaptive, samples_per_step=samples_per_step)
        self.model = model.eval()
        self.engine = IncrementalTreeScorer(model)
        self.candidates, self.temperature = int(candidates), float(temperature)

    def model_sample(self, obs: Mapping) -> np.ndarray:
        return self.timed(self.score_and_draw, obs)

    def score_and_draw(self, obs: Mapping) -> np.ndarray:
        """The forward: ingest the new nodes, score ``candidates`` uniform states, draw one."""
        e = self.engine
        e.ingest(obs)
        # rng.uniform(low, high, (M, d))'s values, without its broadcasting cost
        cands = self.low + (self.high - self.low) * self.rng.random((self.candidates, e.d))
        logits = e.candidate_logits(cands, self.active(obs)) / self.temperature
        p = np.exp(logits - logits.max())
        c = np.cumsum(p)
        i = min(int(c.searchsorted(self.rng.random() * c[-1], "right")), self.candidates - 1)
        return cands[i]


class TreeCVAESampler(_BatchDecoder, ModelSampler):
    """Ichter et al.'s CVAE: decodes ``proposals`` states per forward pass for the problem
    (start, goal, obstacles) and spends them over the next steps; it does not read the tree."""

    settings = ("uniform_mix", "goal_bias", "proposals", "adaptive", "samples_per_step")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeCVAE,
                 uniform_mix: float = 0.25, goal_bias: float = 0.0, proposals: int = 32,
                 adaptive: bool | Mapping = False, samples_per_step: int = 1) -> None:
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.periodic.numpy(), proposals=proposals, adaptive=adaptive,
                         samples_per_step=samples_per_step)
        self.model = model.eval()

    def refresh_key(self, obs: Mapping):
        return None        # the condition is the problem's, whichever tree is active

    def decode(self, obs: Mapping) -> list[np.ndarray]:
        """The forward: ``proposals`` actions for the problem."""
        return self.decode_batch(cvae_condition(self.model, obs))


class TreeGNNCVAESampler(_BatchDecoder, _EngineSampler):
    """The GNN-CVAE: the causal GNN summarises the tree (incrementally, as the GNN sampler),
    the decoder turns latent draws and that context into the next samples: ``proposals`` of
    them per forward, handed out one per step."""

    settings = ("uniform_mix", "goal_bias", "proposals", "adaptive", "samples_per_step")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, model: TreeGNNCVAE,
                 uniform_mix: float = 0.25, goal_bias: float = 0.0, proposals: int = 1,
                 adaptive: bool | Mapping = False, samples_per_step: int = 1) -> None:
        super().__init__(low, high, seed, uniform_mix=uniform_mix, goal_bias=goal_bias,
                         periodic=model.gnn.periodic.numpy(), proposals=proposals, adaptive=adaptive,
                         samples_per_step=samples_per_step)
        self.model = model.eval()
        self.engine = IncrementalTreeGNN(model.gnn, heads=False)     # it reads the tree sums only

    def decode(self, obs: Mapping) -> list[np.ndarray]:
        """The forward: the tree context, then ``proposals`` actions for it."""
        q, _ = self.tree_context(obs)
        return self.decode_batch(torch.as_tensor(q, dtype=torch.float32))


def cvae_condition(model: TreeCVAE, obs: Mapping) -> torch.Tensor:
    """``[start, goal, obstacle rows]`` of one observation, states scaled as the model's."""
    center, scale = model.state_center.numpy(), model.state_scale.numpy()
    start = (np.asarray(obs["start"], np.float32) - center) / scale
    goal = (np.asarray(obs["goal"], np.float32) - center) / scale
    obstacles = np.asarray(obs["obstacles"], np.float32).reshape(-1)
    width = 2 * len(start) + len(obstacles)
    if width != model.condition_dim:
        rows = np.shape(obs["obstacles"])
        raise ValueError(f"this CVAE was trained on conditions of {model.condition_dim} values (start, goal and the "
                         f"obstacle rows of its task); the observation gives {width} (obstacles {rows}): "
                         "a map with another number or width of obstacle rows needs a CVAE trained for it")
    return torch.as_tensor(np.concatenate([start, goal, obstacles]), dtype=torch.float32)


# ---------------------------------------------------------------------------- loading
#: Checkpoint kind -> sampler class.
KIND_SAMPLERS: dict[str, type[ModelSampler]] = {
    "tree/gnn": TreeGNNSampler, "tree/gnn-scorer": TreeScorerSampler,
    "tree/cvae": TreeCVAESampler, "tree/gnn-cvae": TreeGNNCVAESampler,
}
#: Sampler name -> the checkpoint kinds it accepts (a task ships the GNN head its TaskSpec names:
#: the node mixture ``tree/gnn``, or the sample scorer ``tree/gnn-scorer``).
NAME_KINDS: dict[str, tuple[str, ...]] = {"gnn": ("tree/gnn", "tree/gnn-scorer"), "cvae": ("tree/cvae",),
                                          "gnn-cvae": ("tree/gnn-cvae",)}


def load_tree_sampler(name: str, low: np.ndarray, high: np.ndarray, task: str | None = None,
                      seed: int | None = None, checkpoint: str | Path | None = None, **settings) -> ModelSampler:
    """A tree sampler with its weights (``checkpoint`` or the shipped file for ``task``) and the
    sampling settings stored with them (``meta["sampler"]``), which ``settings`` override."""
    from agents.checkpoints import check_trained_for, load_checkpoint, resolve_checkpoint
    path = resolve_checkpoint(name, task, checkpoint, f"gnn-mp train sampler --task {task} --model {name}")
    model, record = load_checkpoint(path, expected_kind=NAME_KINDS[name])
    cls = KIND_SAMPLERS[record["kind"]]
    meta = record.get("meta") or {}
    unknown = sorted(set(settings) - set(cls.settings))
    if unknown:
        raise ValueError(f"sampler {name!r} ({record['kind']}) takes {', '.join(cls.settings)}; "
                         f"unknown: {', '.join(unknown)}")
    check_trained_for(path, meta.get("task"), task)
    chosen = {k: v for k, v in dict(meta.get("sampler") or {}).items() if k in cls.settings}
    chosen.update(settings)
    return cls(low, high, seed, model=model, **chosen)


__all__ = ["KIND_SAMPLERS", "NAME_KINDS", "TreeCVAESampler", "TreeGNNCVAESampler", "TreeGNNSampler",
           "TreeScorerSampler", "cvae_condition", "load_tree_sampler"]
