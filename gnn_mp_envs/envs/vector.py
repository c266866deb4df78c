"""Several copies of an environment stepped together: Gymnasium's ``make_vec`` (sync or async).

Gymnasium batches each info key into one array per key, shaped by the first copy that reports it.
The info of a solved step holds the returned path (``path``, ``path_controls``, ``path_nodes``),
whose length differs from problem to problem: when two copies solve on the same step with paths of
different lengths, Gymnasium's vector env fails ("could not broadcast input array from shape (29,2)
into shape (27,2)"). :class:`VectorInfo` leaves those keys out of the info (every other key stays);
:func:`make_vec` is ``gymnasium.make_vec`` with it. A finished copy's path and tree are there until
its next step resets it: ``envs.call("export_tree")`` (see ``TreePlanningEnv.export_tree``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

#: The info keys whose values vary in length between episodes (only on the step that solves).
RAGGED_INFO = ("path", "path_controls", "path_nodes")


class VectorInfo(gym.Wrapper):
    """The env with the info's variable-length arrays (:data:`RAGGED_INFO`) left out, so that a
    Gymnasium vector env can batch every info key."""

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        return obs, _fixed(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, _fixed(info)


def _fixed(info: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in info.items() if k not in RAGGED_INFO}


def make_vec(env_id: str, num_envs: int = 1, vectorization_mode: str = "sync", **kwargs: Any) -> gym.vector.VectorEnv:
    """``gymnasium.make_vec(env_id, num_envs, vectorization_mode, **kwargs)`` with every copy wrapped
    in :class:`VectorInfo` (``kwargs`` go to each copy's ``gym.make``, e.g. ``split="test"``)."""
    wrappers = [VectorInfo, *kwargs.pop("wrappers", ())]
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=vectorization_mode, wrappers=wrappers,
                        **kwargs)


__all__ = ["RAGGED_INFO", "VectorInfo", "make_vec"]
