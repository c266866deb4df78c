"""Random streams that reproduce torch's CPU generator without torch.

The classical samplers (since the first benchmark) and the shipped RL policies (since they were
recorded) drew from ``torch.manual_seed(seed)``'s Mersenne Twister through ``torch.rand`` and
``torch.randn``; every counter in ``docs/results.md`` depends on those exact values. A
:class:`TorchCompatibleStream` makes the same draws without torch:

* :meth:`~TorchCompatibleStream.unit` is ``torch.rand(n)`` (float32): a 32-bit draw's low 24
  bits times ``2**-24``;
* :meth:`~TorchCompatibleStream.normal` is ``torch.randn(n)`` (float32) for the small sizes
  samplers draw (torch's serial path below 16 values): Box-Muller on two 53-bit uniforms, each
  from two 32-bit draws, the sine half kept for the next value as torch keeps it.

The generator is the Mersenne Twister (MT19937, Matsumoto and Nishimura 1998) that both torch and
numpy implement, seeded as both seed it from an integer; its state and draws live in compiled code
(numba), so a classical sampler's batch of ``k * d`` draws, scaled into the bounds, is one compiled
call (:meth:`~TorchCompatibleStream.uniform`) instead of a generator call and a few numpy operations.
``tests/test_samplers.py`` checks the draws against torch itself and the raw words against numpy's
``MT19937``.
"""

from __future__ import annotations

import math

import numpy as np

from gnn_mp_envs.utils.compiled import jit

_UNIT24 = np.float32(2.0 ** -24)
#: The bounds under which :func:`_fill_uniform` hands out the draws' low 24 bits themselves (``0 + m * 1``: exact).
_AS_IS = (np.zeros(1, dtype=np.float32), np.ones(1, dtype=np.float32))
_MASK53 = (1 << 53) - 1
#: Words of the generator's state: one twist of the state makes this many draws (the last entry of a
#: stream's ``state`` array is the index of the next word to hand out).
WORDS = 624
_SHIFT, _MATRIX, _UPPER, _LOWER, _MASK32, _MASK24 = 397, 0x9908B0DF, 0x80000000, 0x7FFFFFFF, 0xFFFFFFFF, 0xFFFFFF


@jit
def _seed_state(state, seed):
    """The state that seeding with the 32-bit ``seed`` makes (``init_genrand``: torch's ``manual_seed``,
    numpy's ``RandomState.seed`` of an integer), its next word to be drawn after a twist."""
    x = seed & _MASK32
    for i in range(WORDS):
        state[i] = x
        x = (1812433253 * (x ^ (x >> 30)) + i + 1) & _MASK32
    state[WORDS] = WORDS


@jit(inline=True)
def _next_word(state):
    """The next 32-bit draw (tempered), twisting the state when its words are used up."""
    i = state[WORDS]
    if i >= WORDS:
        for k in range(WORDS):
            y = (state[k] & _UPPER) | (state[(k + 1) % WORDS] & _LOWER)
            v = state[(k + _SHIFT) % WORDS] ^ (y >> 1)
            if y & 1:
                v ^= _MATRIX
            state[k] = v
        i = 0
    y = state[i]
    state[WORDS] = i + 1
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y


@jit
def _fill_raw(state, out):
    """``out[i]``: the next draws, in order."""
    for i in range(out.shape[0]):
        out[i] = _next_word(state)


@jit
def _fill_uniform(state, low32, scale32, out):
    """``out[i]`` (flat, states of ``d`` values in a row): ``low32[c] + m * scale32[c]`` in float32 for the next
    draw's low 24 bits ``m`` and the state's coordinate ``c``, the operations numpy makes of ``low24``."""
    d = low32.shape[0]
    c = 0
    for i in range(out.shape[0]):
        out[i] = np.float32(_next_word(state) & _MASK24) * scale32[c] + low32[c]
        c += 1
        if c == d:
            c = 0


def torch_compatible_stream(previous: object, seed: int | None) -> "TorchCompatibleStream":
    """A sampler's stream for ``reset(seed)``: its ``previous`` one reseeded where it is a
    :class:`TorchCompatibleStream`, else a new one."""
    if isinstance(previous, TorchCompatibleStream):
        previous.reseed(seed)
        return previous
    return TorchCompatibleStream(seed)


class TorchCompatibleStream:
    """The draws ``torch.Generator().manual_seed(seed)`` gives (``seed=None``: fresh entropy)."""

    def __init__(self, seed: int | None) -> None:
        #: The generator's words and, last, the index of the next one to hand out (int64, 32-bit values).
        self.state = np.zeros(WORDS + 1, dtype=np.int64)
        self.reseed(seed)

    def reseed(self, seed: int | None) -> None:
        """Start again as a new stream of ``seed`` would."""
        if seed is None:                      # numpy's generator seeded from the OS's entropy: its state
            fresh = np.random.MT19937().state["state"]
            self.state[:WORDS], self.state[WORDS] = fresh["key"], fresh["pos"]
        else:
            _seed_state(self.state, int(seed) & _MASK32)
        self._normal: float | None = None     # torch's cached second Box-Muller value

    def raw(self, n: int) -> np.ndarray:
        """The next ``n`` 32-bit draws (uint64), as numpy's ``MT19937.random_raw(n)`` would give them."""
        out = np.empty(n, dtype=np.uint64)
        _fill_raw(self.state, out)
        return out

    def low24(self, n: int) -> np.ndarray:
        """The next ``n`` draws' low 24 bits as float32 (``unit(n)`` is these times ``2**-24``)."""
        out = np.empty(n, dtype=np.float32)
        _fill_uniform(self.state, *_AS_IS, out)
        return out

    def unit(self, n: int) -> np.ndarray:
        """``n`` float32 uniforms in ``[0, 1)``: ``torch.rand(n)``."""
        return self.low24(n) * _UNIT24

    def uniform(self, n: int, low32: np.ndarray, scale32: np.ndarray) -> np.ndarray:
        """``n`` states (flat, ``n * d`` float32) ``low32 + low24(n * d) * scale32`` in one compiled call, the
        floats of those numpy operations (``scale32``: the bounds' span times ``2**-24``, exact)."""
        out = np.empty(n * low32.shape[0], dtype=np.float32)
        _fill_uniform(self.state, low32, scale32, out)
        return out

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


__all__ = ["TorchCompatibleStream", "WORDS"]
