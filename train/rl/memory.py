"""Buffer memory of SB3 agents over the tree observations (the figures of ``docs/rl.md``).

:func:`sb3_buffer_bytes` computes what SB3 2.9 allocates for a Dict-observation buffer from the
observation space (nothing allocated), :func:`sb3_buffer_nbytes` measures a real buffer; a test
checks the one against the other.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def sb3_buffer_nbytes(buffer: Any) -> int:
    """Bytes of every numpy array an SB3 rollout/replay buffer holds (what it asked for)."""
    total = 0
    for value in vars(buffer).values():
        if isinstance(value, np.ndarray):
            total += value.nbytes
        elif isinstance(value, dict):
            total += sum(v.nbytes for v in value.values() if isinstance(v, np.ndarray))
    return total


def sb3_buffer_bytes(observation_space: Any, action_dim: int, size: int, n_envs: int, kind: str) -> int:
    """Bytes SB3 2.9 allocates for a Dict-observation buffer, computed from the space (nothing
    allocated): observations in the space's dtypes (float32, int64 ``parent``, int8 ``mask``, ...)
    and float32 actions, plus ``kind="rollout"`` (PPO's ``DictRolloutBuffer``, ``size`` steps per
    env: six float32 per-step arrays) or ``kind="replay"`` (SAC's ``DictReplayBuffer``, ``size``
    transitions in all: next observations too, rewards, dones, timeouts). Checked against real
    buffers in ``tests/test_rl.py``."""
    steps = size * n_envs if kind == "rollout" else max(size // n_envs, 1) * n_envs
    obs = sum(int(np.prod(sub.shape)) * np.dtype(sub.dtype).itemsize for sub in observation_space.spaces.values())
    if kind == "rollout":
        return steps * (obs + 4 * action_dim + 6 * 4)
    return steps * (2 * obs + 4 * action_dim + 3 * 4)


__all__ = ["sb3_buffer_bytes", "sb3_buffer_nbytes"]
