"""Classical samplers: uniform and goal-biased.

Their random streams are part of the benchmark's contract (same seed, same samples, same
counters since the first benchmark): ``torch.rand``'s values from ``torch.manual_seed(seed)``,
drawn in numpy (:class:`~agents.samplers.streams.TorchCompatibleStream`): uniform takes ``d``
per call (``low + u * (high - low)`` in float32), goal-bias takes those, then one for the choice.
``tests/test_samplers.py`` pins both against ``torch.rand`` itself.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from agents.samplers.base import Sampler, active_target, as_arrays, batch_tree_rule
from agents.samplers.streams import _UNIT24, TorchCompatibleStream, torch_compatible_stream
from gnn_mp_envs.utils.compiled import jit

class _TorchCompatible(Sampler):
    """Draws float32 uniforms exactly as ``torch.rand`` does from the same seed."""

    def make_stream(self, seed: int | None) -> TorchCompatibleStream:
        return torch_compatible_stream(getattr(self, "rng", None), seed)

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None) -> None:
        super().__init__(low, high, seed)
        self._scale32 = self.span32 * _UNIT24
        self._one = (self.state_dim,)       # the shape of one observation's states

    def uniform(self, batch_shape: tuple = ()) -> np.ndarray:
        """``(*batch_shape, d)`` float32 uniform states in the bounds: ``low + unit * span`` in float32, drawn in one
        compiled call (``(m * 2**-24) * span == m * (span * 2**-24)``: scaling by a power of two is exact)."""
        n = int(np.prod(batch_shape, dtype=np.int64))
        return self.rng.uniform(n, self.low32, self._scale32).reshape(*batch_shape, self.state_dim)

    def batch_shape(self, obs: Mapping) -> tuple:
        shape = np.shape(obs["start"])
        if shape[-1] != self.state_dim:
            self.check_observation(obs)
        return tuple(shape[:-1])


#: The batch the classical samplers ask the benchmark to plan with: one compiled call per 64 samples.
CLASSICAL_BATCH = 64


class UniformSampler(_TorchCompatible):
    """Uniform over the sampling bounds: the RRT/BiRRT default."""

    reads = ("start",)
    samples_per_step = CLASSICAL_BATCH

    def act_batch(self, obs: Mapping, k: int) -> np.ndarray:
        """``k`` uniform states in one draw: the values of ``k`` calls of :meth:`act`."""
        return self.rng.uniform(k, self.low32, self._scale32).reshape(k, self.state_dim)

    def act(self, obs: Mapping) -> np.ndarray:
        if np.shape(obs["start"]) == self._one:     # one observation: uniform(()) without its shape arithmetic
            return self.rng.uniform(1, self.low32, self._scale32)
        return self.uniform(self.batch_shape(obs))

    def propose(self, obs: Mapping) -> np.ndarray:
        return self.uniform(self.batch_shape(obs))


@jit
def _goal_bias_batch(draws, low32, scale32, goal_bias32, active, alternates, start, goal, out):
    """``out[j]``: sample ``j`` of a goal-bias batch from its ``d + 1`` draws (``draws[j]``, low 24 bits as
    float32): its tree's target where the last draw times ``2**-24`` is below ``goal_bias32`` (tree ``(active +
    j) % 2`` where BiRRT ``alternates``, else 0; tree 1's target is the start, float32), else ``low32 + draws[j,
    :d] * scale32``, in float32 as numpy computes it."""
    k, d = out.shape
    for j in range(k):
        if draws[j, d] * _UNIT24 < goal_bias32:
            tree = (active + j) % 2 if alternates else 0
            target = start if tree == 1 else goal
            for c in range(d):
                out[j, c] = np.float32(target[c])
        else:
            for c in range(d):
                out[j, c] = low32[c] + draws[j, c] * scale32[c]


class GoalBiasSampler(_TorchCompatible):
    """Uniform, but with probability ``goal_bias`` the target of the active tree.

    For RRT (and BiRRT's start tree) the target is the goal; for BiRRT's goal tree it is
    the start, so both trees are pulled toward each other as in OMPL's goal biasing.
    """

    reads = ("start", "goal", "active_tree")
    settings = ("goal_bias",)
    samples_per_step = CLASSICAL_BATCH

    def __init__(self, low: np.ndarray, high: np.ndarray, seed: int | None = None,
                 goal_bias: float = 0.05) -> None:
        if not 0.0 <= goal_bias <= 1.0:
            raise ValueError(f"goal_bias must be in [0, 1], got {goal_bias}")
        super().__init__(low, high, seed)
        # The choice compares float32 draws with the float32-rounded rate, as torch did.
        self.goal_bias = float(goal_bias)
        self._goal_bias32 = np.float32(goal_bias)

    def act(self, obs: Mapping) -> np.ndarray:
        shape = self.batch_shape(obs)
        if shape:
            return self.propose(obs)
        # uniform(()) then the choice: d + 1 draws of the stream, in that order
        low24 = self.rng.low24(self.state_dim + 1)
        if low24[-1] * _UNIT24 < self._goal_bias32:
            return np.array(active_target(obs), dtype=np.float32)   # a copy: obs may be live views
        return self.low32 + low24[:-1] * self._scale32

    def act_batch(self, obs: Mapping, k: int) -> np.ndarray:
        """The ``k`` samples of ``k`` calls of :meth:`act` (the state's draws, then the choice's, per
        sample), each aimed at the target of the tree it extends; assembled in one compiled call
        (:func:`_goal_bias_batch`: a batch costs about what uniform's does)."""
        d = self.state_dim
        start, goal = np.asarray(obs["start"]), np.asarray(obs["goal"])
        if start.shape != self._one or goal.shape != self._one:
            self.check_observation(obs)
            raise ValueError(f"act_batch takes one observation (start and goal of shape {self._one}), got start "
                             f"{start.shape} and goal {goal.shape}: batches of observations go through propose")
        draws = self.rng.low24(k * (d + 1)).reshape(k, d + 1)
        active, alternates = batch_tree_rule(obs)
        out = np.empty((k, d), dtype=np.float32)
        _goal_bias_batch(draws, self.low32, self._scale32, self._goal_bias32, active, alternates, start, goal, out)
        return out

    def propose(self, obs: Mapping) -> np.ndarray:
        """All uniform states of the batch first, then all the choices (one ``unit`` call each)."""
        shape = self.batch_shape(obs)
        sample = self.uniform(shape)
        arrays = as_arrays(obs)
        target = np.where(arrays["active_tree"].reshape(*shape, 1) == 1, arrays["start"].astype(np.float32),
                          arrays["goal"].astype(np.float32))
        pick = self.rng.unit(int(np.prod(shape, dtype=np.int64))).reshape(*shape, 1) < self._goal_bias32
        return np.where(pick, target, sample).astype(np.float32)


class HaltonSampler(Sampler):
    """A scrambled Halton sequence over the sampling bounds (scipy's ``qmc.Halton``), restarted from the
    seed at every :meth:`reset`: low-discrepancy samples, the default of VAMP's planners. It does not read
    the tree, so a batch is the sequence's next points."""

    reads = ("start",)
    samples_per_step = CLASSICAL_BATCH

    def make_stream(self, seed: int | None):
        from scipy.stats import qmc
        return qmc.Halton(d=len(self.low), scramble=True, seed=None if seed is None else int(seed))

    def act_batch(self, obs: Mapping, k: int) -> np.ndarray:
        if np.shape(obs["start"])[-1] != self.state_dim:
            self.check_observation(obs)
        return (self.low + self.rng.random(k) * (self.high - self.low)).astype(np.float32)

    def act(self, obs: Mapping) -> np.ndarray:
        return self.act_batch(obs, 1)[0]
