"""Random streams that reproduce torch's CPU generator in numpy.

The classical samplers (since the first benchmark) and the shipped RL policies (since they were
recorded) drew from ``torch.manual_seed(seed)``'s Mersenne Twister through ``torch.rand`` and
``torch.randn``; every counter in ``docs/results.md`` depends on those exact values. A
:class:`TorchCompatibleStream` makes the same draws without torch:

* :meth:`~TorchCompatibleStream.unit` is ``torch.rand(n)`` (float32): a 32-bit draw's low 24
  bits times ``2**-24``;
* :meth:`~TorchCompatibleStream.normal` is ``torch.randn(n)`` (float32) for the small sizes
  samplers draw (torch's serial path below 16 values): Box-Muller on two 53-bit uniforms, each
  from two 32-bit draws, the sine half kept for the next value as torch keeps it.

The 32-bit draws are taken from the Mersenne Twister a block at a time (:data:`BLOCK`) and handed
out in order (:meth:`~TorchCompatibleStream.raw`): a classical sampler's ``d`` draws per step cost
a slice instead of a generator call, and the values and their order are the generator's own, however
the calls are interleaved. ``tests/test_samplers.py`` checks both against torch itself.
"""

from __future__ import annotations

import math

import numpy as np

_MASK24 = np.uint64(0xFFFFFF)
_UNIT24 = np.float32(2.0 ** -24)
_MASK53 = (1 << 53) - 1
#: 32-bit draws taken from the generator at a time (a few KiB; the state advances a block ahead).
BLOCK = 512


def torch_compatible_stream(previous: object, seed: int | None) -> "TorchCompatibleStream":
    """A sampler's stream for ``reset(seed)``: its ``previous`` one reseeded where it is a
    :class:`TorchCompatibleStream` (the same draws as a new one, without building a generator), else a new one."""
    if isinstance(previous, TorchCompatibleStream):
        previous.reseed(seed)
        return previous
    return TorchCompatibleStream(seed)


class TorchCompatibleStream:
    """The draws ``torch.Generator().manual_seed(seed)`` gives, made in numpy (``seed=None``: fresh entropy)."""

    def __init__(self, seed: int | None) -> None:
        self.bits = np.random.MT19937()
        self.reseed(seed)

    def reseed(self, seed: int | None) -> None:
        """Start again as a new stream of ``seed`` would, on this stream's generator: a sampler's reset
        need not build a new one (numpy builds each Mersenne Twister from fresh OS entropy before any
        seeding, most of a new stream's cost)."""
        # torch's manual_seed state: the legacy seeding of ``bits`` in place (RandomState's own)
        np.random.RandomState(self.bits).seed(None if seed is None else int(seed) & 0xFFFFFFFF)
        self._normal: float | None = None     # torch's cached second Box-Muller value
        self._raw = np.zeros(0, dtype=np.uint64)     # the block's 32-bit draws ...
        self._low24 = np.zeros(0, dtype=np.float32)  # ... their low 24 bits as float32 (exact)
        self._next = 0                               # the next draw not handed out

    def _refill(self, n: int) -> None:
        """Keep the draws not handed out and append a block (at least ``n`` draws in all)."""
        rest = self._raw[self._next:]
        self._raw = np.concatenate([rest, self.bits.random_raw(max(BLOCK, n - len(rest)))])
        self._low24 = (self._raw & _MASK24).astype(np.float32)
        self._raw.flags.writeable = self._low24.flags.writeable = False     # handed out as views
        self._next = 0

    def _take(self, n: int) -> int:
        """Hand out the next ``n`` draws of the block: the index of the first (refilling when short)."""
        i = self._next
        if i + n > len(self._raw):
            self._refill(n)
            i = 0
        self._next = i + n
        return i

    def raw(self, n: int) -> np.ndarray:
        """The next ``n`` 32-bit draws (uint64), as ``bits.random_raw(n)`` would give them."""
        i = self._take(n)
        return self._raw[i:i + n]

    def low24(self, n: int) -> np.ndarray:
        """The next ``n`` draws' low 24 bits as float32 (``unit(n)`` is these times ``2**-24``), a view."""
        i = self._take(n)
        return self._low24[i:i + n]

    def unit(self, n: int) -> np.ndarray:
        """``n`` float32 uniforms in ``[0, 1)``: ``torch.rand(n)``."""
        return self.low24(n) * _UNIT24

    def normal(self, n: int) -> np.ndarray:
        """``n`` float32 standard normals: ``torch.randn(n)`` for ``n < 16``."""
        if n >= 16:
            raise ValueError("torch draws 16 or more normals with another algorithm; draw fewer per call")
        out = np.empty(n, dtype=np.float32)      # each value rounded to float32 as np.array(values, float32) would
        i = 0
        if n and self._normal is not None:
            out[0] = self._normal
            self._normal = None
            i = 1
        while i < n:
            hi1, lo1, hi2, lo2 = self.raw(4).tolist()     # two 53-bit uniforms, as torch draws them
            u1 = ((hi1 << 32 | lo1) & _MASK53) * 2.0 ** -53
            u2 = ((hi2 << 32 | lo2) & _MASK53) * 2.0 ** -53
            r = math.sqrt(-2.0 * math.log1p(-u2))
            theta = 2.0 * math.pi * u1
            out[i] = r * math.cos(theta)
            i += 1
            if i < n:
                out[i] = r * math.sin(theta)     # the pair's second value, used at once ...
                i += 1
            else:
                self._normal = r * math.sin(theta)   # ... or kept for the next call, as torch keeps it
        return out

__all__ = ["TorchCompatibleStream"]
