"""The sampler interface and its one base: observation in, next sample out.

Every sampler (uniform, goal-biased, GNN, CVAE, GNN-CVAE, RL policy) is a :class:`Sampler`:

* ``sampler.act(obs)`` serves plain Gymnasium loops: one numpy observation in, a float32
  numpy action out;
* ``sampler.propose(obs)`` does the same for observations with any leading batch shape (numpy
  arrays or tensors in, a ``(*batch, d)`` float32 array out);
* ``sampler.as_module()`` is the sampler as a TorchRL policy: a
  ``tensordict.nn.TensorDictModuleBase`` whose ``in_keys`` are the observation keys
  (:data:`SAMPLER_IN_KEYS`) and ``out_keys`` ``["action"]`` (``env.rollout(n, sampler.as_module())``,
  collectors);
* ``sampler.reset(seed)`` reseeds the sampler's one random stream, ``self.rng`` (the benchmark
  calls it before every problem). All randomness comes from it.

The base is numpy only: the classical samplers run without torch (an environments-only install,
benchmark workers that start in a fraction of a second); torch and tensordict load with a
learned sampler or with ``as_module``.

The learned samplers derive from :class:`ModelSampler`, the one mixture of sample sources::

    with probability uniform_mix       -> uniform over the bounds
    with probability goal_bias         -> the active tree's target (:func:`active_target`)
    otherwise                          -> model_sample(obs), wrapped (periodic coordinates) and clipped

A uniform share never reaches zero unless asked (``uniform_mix=0``), so the planner stays
probabilistically complete. With ``adaptive`` set, the model's share moves per problem between a
floor and ``1 - uniform_mix - goal_bias`` with how useful its samples turn out to be compared with
uniform's (:mod:`agents.samplers.adaptive`: a sampler that cannot be much worse than uniform).
A new learned sampler implements :meth:`ModelSampler.model_sample`.
"""

from __future__ import annotations

import contextlib
import numbers
import time
from typing import TYPE_CHECKING, Mapping

import numpy as np

from agents.samplers.adaptive import MODEL, OTHER, UNIFORM, AdaptiveShare
from agents.samplers.trees import TreeStates
from gnn_mp_envs.envs.observation import OBSERVATION_KEYS

if TYPE_CHECKING:
    from agents.samplers.module import SamplerModule

SAMPLER_IN_KEYS: tuple[str, ...] = OBSERVATION_KEYS
SAMPLER_OUT_KEYS: tuple[str, ...] = ("action",)
#: Threads of torch and of numpy's BLAS in a process that runs a sampler's per-step forward. A
#: step's forward is a few dozen small operations, where a second thread only adds synchronisation:
#: torch's default thread pool costs far more than it saves on one small forward per step, and
#: numpy's BLAS pools of two benchmark workers compete for the same cores (``python -m
#: tools.bench_sampler`` measures a sampler's step with either setting).
#: ``load_sampler`` applies it; ``threads=None`` opts out.
INFERENCE_THREADS = 1


def use_inference_threads(threads: int | None = INFERENCE_THREADS) -> None:
    """The one thread policy: torch and numpy's BLAS (``threadpoolctl``) on ``threads`` threads
    (None: leave them as they are)."""
    if threads is None:
        return
    import torch
    from threadpoolctl import threadpool_limits
    if torch.get_num_threads() != int(threads):
        torch.set_num_threads(int(threads))
    threadpool_limits(limits=int(threads), user_api="blas")


@contextlib.contextmanager
def inference_threads(threads: int | None = INFERENCE_THREADS):
    """:func:`use_inference_threads` for a block (e.g. evaluation inside training), then the thread
    counts as they were."""
    import torch
    from threadpoolctl import threadpool_limits
    before = torch.get_num_threads()
    with threadpool_limits(limits=threads, user_api="blas"):
        use_inference_threads(threads)
        try:
            yield
        finally:
            if torch.get_num_threads() != before:
                torch.set_num_threads(before)


def active_target(obs: Mapping) -> np.ndarray:
    """The active tree's target of one observation: the start for BiRRT's goal tree (tree 1),
    the goal otherwise (RRT, BiRRT's start tree). The one place this rule is written."""
    return obs["start"] if int(np.asarray(obs["active_tree"]).reshape(-1)[0]) == 1 else obs["goal"]


def batch_tree_rule(obs: Mapping) -> tuple[int, bool]:
    """``(active tree, alternates)`` of one observation: sample ``j`` of the next batch extends tree
    ``(active + j) % 2`` where BiRRT alternates (the goal tree's root is node 1: it swaps trees after every
    sample), else tree 0 (RRT). The one place this rule is written (``gym.make(id, samples_per_step=K)``
    consumes a batch this way; :func:`batch_active_trees` spells it out)."""
    active = int(np.asarray(obs["active_tree"]).reshape(-1)[0])
    features, n = np.asarray(obs["node_features"]), int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
    return active, bool(n >= 2 and features[1, -1] == 1)


def batch_active_trees(obs: Mapping, k: int) -> np.ndarray:
    """The tree each of the next ``k`` samples extends, from one observation (:func:`batch_tree_rule`)."""
    active, alternates = batch_tree_rule(obs)
    if alternates:
        return (active + np.arange(k)) % 2
    return np.zeros(k, dtype=np.int64)


_TWO_PI = 2 * np.pi
#: Below this many values numpy's float modulo is cheaper than :func:`wrap_pi`'s extra passes.
_WRAP_BY_PASSES = 64


def wrap_pi(v: np.ndarray) -> np.ndarray:
    """``(v + pi) % (2 pi) - pi``, bit for bit (signed zeros included), as a new array.

    numpy's float modulo costs about 16 ns per value (a branchy ``fmod``); for ``v + pi`` in
    ``[-2 pi, 4 pi)`` (differences of two wrapped angles, the engines' case) it is one exact
    step instead: minus ``2 pi`` from ``[2 pi, 4 pi)`` (exact, by Sterbenz's lemma, as ``fmod``
    is) and plus ``2 pi`` below 0 (the rounded addition numpy's modulo makes there). Other
    values, NaN or infinite ones, float32 and small arrays take the modulo itself.
    """
    a = np.add(v, np.pi)
    if a.size < _WRAP_BY_PASSES or a.dtype != np.float64 or not (a.min() >= -_TWO_PI and a.max() < 2 * _TWO_PI):
        a %= _TWO_PI
    else:
        a -= (a >= _TWO_PI) * _TWO_PI
        a += (a < 0.0) * _TWO_PI
    a -= np.pi
    return a


def wrap_periodic(x: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """``x`` with the periodic coordinates (a bool mask) wrapped into ``[-pi, pi)``."""
    if not periodic.any():
        return x
    if x.size < _WRAP_BY_PASSES or x.dtype != np.float64:
        return np.where(periodic, (x + np.pi) % (2 * np.pi) - np.pi, x)
    out = x.copy()                      # the same values; only the periodic columns are wrapped
    out[..., periodic] = wrap_pi(x[..., periodic])
    return out


class Sampler:
    """Base class: the sampling bounds and one seeded numpy stream, ``self.rng``.

    Subclasses implement :meth:`act` (one observation) and may override :meth:`propose`
    (a batch; the default calls ``act`` per observation in batch order) and
    :meth:`make_stream` (the generator ``reset`` builds).
    """

    #: Observation keys the sampler reads.
    reads: tuple[str, ...] = SAMPLER_IN_KEYS
    #: The TensorDict keys of :meth:`as_module`.
    in_keys: tuple[str, ...] = SAMPLER_IN_KEYS
    out_keys: tuple[str, ...] = SAMPLER_OUT_KEYS
    #: Samples per environment step the benchmark plans this sampler with (``gym.make(id,
    #: samples_per_step=K)``, :meth:`act_batch`): samplers that do not read the tree draw a batch at once.
    samples_per_step: int = 1

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None) -> None:
        low64, high64 = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
        if low64.shape != high64.shape or low64.ndim != 1 or not np.all(high64 > low64):
            raise ValueError(f"sampler bounds must be 1-D with high > low, got {low64} and {high64}")
        self.low, self.high = low64, high64
        #: ``d``, the state dimension (an attribute: samplers read it every step)
        self.state_dim = int(low64.shape[0])
        self.low32, self.high32 = low64.astype(np.float32), high64.astype(np.float32)
        self.span32 = self.high32 - self.low32
        # a subclass that overrides act below a class's own act_batch: its batches must call its act (one
        # sample at a time, and the benchmark plans it so)
        mro = type(self).__mro__
        act_at = next(c for c in mro if "act" in vars(c))
        batch_at = next(c for c in mro if "act_batch" in vars(c))
        if batch_at is not Sampler and act_at is not batch_at and issubclass(act_at, batch_at):
            self.act_batch = lambda obs, k: Sampler.act_batch(self, obs, k)
            self.samples_per_step = 1
        self.reset(seed)

    def make_stream(self, seed: int | None) -> np.random.Generator:
        """The random stream ``reset(seed)`` starts (None: fresh entropy from the OS)."""
        return np.random.default_rng(None if seed is None else int(seed))

    def reset(self, seed: int | None = None) -> None:
        """Reseed the sampler's random stream and forget per-episode state."""
        self.rng = self.make_stream(seed)

    def check_observation(self, obs: Mapping) -> None:
        """Refuse an observation of another state dimension (a sampler built for another task)."""
        d = np.shape(obs["start"])[-1]
        if d != self.state_dim:
            raise ValueError(f"this sampler samples {self.state_dim}-D states (bounds {self.low.tolist()}.."
                             f"{self.high.tolist()}); the observation has {d}-D states (another task?)")

    # ------------------------------------------------------------------ the core
    def act(self, obs: Mapping) -> np.ndarray:
        """Next sample ``(d,)`` float32 for one (unbatched) numpy observation."""
        raise NotImplementedError

    def act_batch(self, obs: Mapping, k: int) -> np.ndarray:
        """The next ``k`` samples ``(k, d)`` float32 for one observation, to be consumed in order (an
        env with ``samples_per_step=k``): what ``k`` calls of :meth:`act` would draw if the tree did not
        change in between, each for the tree it extends (:func:`batch_active_trees`). A sampler that does
        not read the tree draws exactly the samples of ``k`` steps; one that does sees the tree as it
        stood before the batch."""
        trees = batch_active_trees(obs, k)
        view = dict(obs)
        out = np.empty((k, self.state_dim), dtype=np.float32)
        for j in range(k):
            view["active_tree"] = trees[j:j + 1]
            out[j] = self.act(view)
        return out

    def propose(self, obs: Mapping) -> np.ndarray:
        """Next samples ``(*batch, d)`` float32 for observations with leading batch shape ``batch``
        (numpy arrays or tensors): one :meth:`act` per observation, in batch order, from the same stream."""
        arrays = as_arrays(obs)
        shape = arrays["start"].shape[:-1]
        flat = {k: v.reshape(-1, *v.shape[len(shape):]) for k, v in arrays.items()}
        out = [self.act_stateless({k: v[i] for k, v in flat.items()}) for i in range(int(np.prod(shape)))]
        return (np.stack(out).reshape(*shape, self.state_dim) if out
                else np.zeros((*shape, self.state_dim), np.float32))

    def act_stateless(self, obs: Mapping) -> np.ndarray:
        """:meth:`act` on an observation unrelated to the previous one (the batched path; samplers
        with per-episode caches clear them first)."""
        return self.act(obs)

    def as_module(self) -> "SamplerModule":
        """The sampler as a TorchRL policy (a ``TensorDictModuleBase``: observation keys in,
        ``"action"`` out, any batch size), drawing from this sampler's stream."""
        from agents.samplers.module import SamplerModule
        return SamplerModule(self)


def as_arrays(obs: Mapping) -> dict[str, np.ndarray]:
    """The observation keys of ``obs`` (a dict or a TensorDict of arrays or tensors) as numpy arrays."""
    out = {}
    for k in SAMPLER_IN_KEYS:
        if k in obs.keys():
            v = obs[k]
            out[k] = np.asarray(v.detach().cpu() if hasattr(v, "detach") else v)
    return out


class ModelSampler(Sampler):
    """The one uniform / goal / model mixture (see the module docstring).

    Args:
        low: the lower sampling bounds, as for every :class:`Sampler`.
        high: the upper sampling bounds, as for every :class:`Sampler`.
        seed: the seed of ``self.rng``, as for every :class:`Sampler`.
        uniform_mix: probability of a uniform sample.
        goal_bias: probability of the active tree's target.
        periodic: ``(d,)`` bool, coordinates wrapped into ``[-pi, pi)`` before clipping.
        adaptive: False (fixed shares), True (the model's share adapts per problem, the settings of
            :data:`agents.samplers.adaptive.DEFAULTS`) or a dict overriding some of them
            (:class:`~agents.samplers.adaptive.AdaptiveShare`); ``uniform_mix`` stays the least uniform share.

    Per call, ``act`` draws one ``rng.random()`` (the choice), then either ``rng.uniform(low,
    high)`` or whatever :meth:`model_sample` draws from ``self.rng``.

    **Proposals per forward.** A model's forward pass costs more than a planner step, so a
    sampler may run it once for ``proposals`` model samples (:meth:`refreshed`): the GNN and the
    RL policies reuse the distribution they computed, the CVAEs decode ``proposals`` states at
    once and hand them out one per step while the tree grows. ``proposals=1`` is a forward per
    sample (and exactly the draws of one). The shipped value is a setting of each checkpoint,
    chosen on split ``val`` for time to solution (``docs/learned_samplers.md``).
    """

    #: Sampling settings a checkpoint's ``meta["sampler"]`` may carry (the constructor's keywords).
    settings: tuple[str, ...] = ("uniform_mix", "goal_bias", "adaptive")

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None, *, uniform_mix: float = 0.25,
                 goal_bias: float = 0.0, periodic: np.ndarray | None = None, proposals: int = 1,
                 adaptive: bool | Mapping = False, samples_per_step: int = 1) -> None:
        if not all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in (uniform_mix, goal_bias)):
            raise ValueError(f"uniform_mix and goal_bias must be numbers, got {uniform_mix!r}, {goal_bias!r}")
        if not (0.0 <= uniform_mix <= 1.0 and 0.0 <= goal_bias <= 1.0 and uniform_mix + goal_bias <= 1.0):
            raise ValueError(f"uniform_mix and goal_bias must be in [0, 1] with a sum <= 1, got {uniform_mix}, "
                             f"{goal_bias}")
        if isinstance(proposals, bool) or int(proposals) != proposals or proposals < 1:
            raise ValueError(f"proposals must be an integer >= 1, got {proposals!r}")
        if isinstance(samples_per_step, bool) or samples_per_step != 1:
            from gnn_mp_envs.envs.tree_env import MAX_SAMPLES_PER_STEP     # the env's bound (its module is heavier)
            if (not isinstance(samples_per_step, numbers.Integral) or isinstance(samples_per_step, bool)
                    or not 1 <= samples_per_step <= MAX_SAMPLES_PER_STEP):
                raise ValueError(f"samples_per_step must be an integer in [1, {MAX_SAMPLES_PER_STEP}], got "
                                 f"{samples_per_step!r}")
        self.uniform_mix, self.goal_bias, self.proposals = float(uniform_mix), float(goal_bias), int(proposals)
        super().__init__(low, high, seed)
        if "act_batch" not in vars(self):     # (a subclass that only overrides act is planned one sample a step)
            self.samples_per_step = int(samples_per_step)
        self.periodic = np.zeros(self.state_dim, dtype=bool) if periodic is None else np.asarray(periodic, dtype=bool)
        if self.periodic.shape != (self.state_dim,):
            raise ValueError(f"periodic must have {self.state_dim} entries, got {self.periodic.shape}")
        self._wraps = bool(self.periodic.any())
        self._range = self.high - self.low
        if isinstance(adaptive, (bool, np.bool_)) or adaptive is None:
            options = {} if adaptive else None
        elif isinstance(adaptive, Mapping):
            options = dict(adaptive)
        else:
            raise ValueError(f"adaptive must be true, false or a dict of its settings, got {adaptive!r}")
        #: The adaptive share of the model (None: fixed shares).
        self.adaptive: AdaptiveShare | None = None
        if options is not None:
            try:
                self.adaptive = AdaptiveShare(self.low, self.high, self.periodic,
                                              1.0 - self.uniform_mix - self.goal_bias, **options)
            except TypeError as exc:
                raise ValueError(f"unknown adaptive setting ({exc})") from None

    def act(self, obs: Mapping) -> np.ndarray:
        if np.shape(obs["start"])[-1] != self.state_dim:
            self.check_observation(obs)
        u = self.rng.random()
        if self.adaptive is not None:
            return self._act_adaptive(obs, u)
        if u < self.uniform_mix:
            # rng.uniform(low, high)'s values (low + (high - low) * next_double), without its broadcasting cost
            return (self.low + self._range * self.rng.random(self.state_dim)).astype(np.float32)
        if u < self.uniform_mix + self.goal_bias:
            return np.asarray(active_target(obs), dtype=np.float32).copy()   # a copy: obs may be live views
        return self.model_action(obs)

    def act_batch(self, obs: Mapping, k: int) -> np.ndarray:
        """The next ``k`` samples ``(k, d)`` float32 from the one mixture, for the trees they extend
        (:func:`batch_active_trees`), the model's from one forward over the tree as it stands
        (:meth:`model_batch`). The draws: ``k`` choices (``rng.random(k)``), the uniform samples'
        values (``rng.random((u, d))``), then the model's; so ``act_batch(obs, 1)`` draws exactly
        what ``act(obs)`` draws. With the adaptive share, one share for the batch (read from ``obs``),
        and each sample is scored at the next observation (:meth:`AdaptiveShare.chose_batch`)."""
        if np.shape(obs["start"])[-1] != self.state_dim:
            self.check_observation(obs)
        k = int(k)
        trees = batch_active_trees(obs, k)
        u = self.rng.random(k)
        adaptive = self.adaptive
        p_uniform = self.uniform_mix if adaptive is None else 1.0 - self.goal_bias - adaptive.observe(obs)
        uniform = u < p_uniform
        model = u >= p_uniform + self.goal_bias
        out = np.empty((k, self.state_dim), dtype=np.float32)
        nu = int(np.count_nonzero(uniform))
        if nu:
            out[uniform] = (self.low + self._range * self.rng.random((nu, self.state_dim))).astype(np.float32)
        goal = ~(uniform | model)
        if goal.any():
            ends = np.stack([np.asarray(obs["goal"], np.float32), np.asarray(obs["start"], np.float32)])
            out[goal] = ends[trees[goal]]
        if model.any():
            out[model] = self.model_batch(obs, trees[model])
        if adaptive is not None:
            adaptive.chose_batch(np.where(uniform, UNIFORM, np.where(model, MODEL, OTHER)), out)
        return out

    def model_batch(self, obs: Mapping, trees: np.ndarray) -> np.ndarray:
        """The model's samples ``(m, d)`` float32 (finished: wrapped, clipped) for the trees ``trees``
        ``(m,)`` of one observation, in order. This default calls :meth:`model_action` per sample, each
        with its tree active; a model that draws a batch from one forward overrides it (drawing, for one
        sample, what :meth:`model_action` draws)."""
        view = dict(obs)
        out = np.empty((len(trees), self.state_dim), dtype=np.float32)
        for j in range(len(trees)):
            view["active_tree"] = trees[j:j + 1]
            out[j] = self.model_action(view)
        return out

    def _act_adaptive(self, obs: Mapping, u: float) -> np.ndarray:
        """:meth:`act` with the model's share from :class:`AdaptiveShare` (the same draws)."""
        adaptive = self.adaptive
        p_uniform = 1.0 - self.goal_bias - adaptive.observe(obs)
        if u < p_uniform:
            adaptive.chose(UNIFORM)
            return (self.low + self._range * self.rng.random(self.state_dim)).astype(np.float32)
        if u < p_uniform + self.goal_bias:
            adaptive.chose(OTHER)
            return np.asarray(active_target(obs), dtype=np.float32).copy()
        adaptive.chose(MODEL)
        return self.model_action(obs)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        if getattr(self, "adaptive", None) is not None:
            self.adaptive.clear()
        #: Per tree (keyed on its content: two envs of one problem are two trees): refresh key ->
        #: [forward's value, model samples left].
        self._forwards: TreeStates[dict] = TreeStates(dict)
        if not hasattr(self, "forward_time_s"):
            #: Seconds spent in the model's forward passes, and their count, since construction
            #: (resets keep them): the inference share of a step, which ``tools/tune_proposals`` reports.
            self.forward_time_s, self.forward_calls = 0.0, 0

    def timed(self, forward, obs: Mapping):
        """``forward(obs)``, its time added to :attr:`forward_time_s`."""
        t0 = time.perf_counter()
        out = forward(obs)
        self.forward_time_s += time.perf_counter() - t0
        self.forward_calls += 1
        return out

    def refresh_key(self, obs: Mapping):
        """What a reused forward must share besides the episode: the active tree (BiRRT grows
        two, each with its own context)."""
        return int(np.asarray(obs["active_tree"]).reshape(-1)[0])

    def refreshed(self, obs: Mapping, forward):
        """``forward(obs)``, run once per ``proposals`` model samples of the same tree and
        :meth:`refresh_key` (every time for ``proposals=1``)."""
        if self.proposals == 1:
            return self.timed(forward, obs)
        forwards = self._forwards.of(obs)      # the observation's tree's (another episode, another env: another)
        key = self.refresh_key(obs)
        entry = forwards.get(key)
        if entry is None or entry[1] <= 0:
            entry = forwards[key] = [self.timed(forward, obs), self.proposals]
        entry[1] -= 1
        return entry[0]

    def model_action(self, obs: Mapping) -> np.ndarray:
        """The model's next sample as an action: :meth:`finish` of :meth:`model_sample` (a sampler
        that decodes a batch per forward finishes the batch at once and overrides this)."""
        return self.finish(self.model_sample(obs))

    def finish(self, x: np.ndarray) -> np.ndarray:
        """A model's state as an action: periodic coordinates wrapped, clipped to the bounds, float32
        (elementwise, so a batch ``(k, d)`` gives each row's own result)."""
        x = np.asarray(x, np.float64)
        if self._wraps:
            x = wrap_periodic(x, self.periodic)
        return np.minimum(np.maximum(x, self.low), self.high).astype(np.float32)   # np.clip, without its overhead

    def model_sample(self, obs: Mapping) -> np.ndarray:
        """The model's next state ``(d,)`` for one observation (random draws from ``self.rng``)."""
        raise NotImplementedError
