"""Which tree an observation shows: a sampler's per-tree state, keyed on the tree's content.

A learned sampler keeps state from step to step of an episode: the adaptive share's statistics
(:mod:`agents.samplers.adaptive`), a forward reused over ``proposals`` samples
(:meth:`~agents.samplers.base.ModelSampler.refreshed`). Observations of several trees can reach
one sampler: two envs planning the same problem (the same start and goal, even the same node
count), a new episode, the rows of a batch. :class:`TreeStates` keeps one state per tree and
hands each observation its own tree's.

A tree is recognised by its content, cheaply: tree rows are append-only, so the tree of a later
observation of the same episode, grown further, still holds the last row read before; another
tree of the same problem does not (its nodes came from other samples). Per lookup that is one
row compared per kept tree, never the whole tree. A tree not recognised (a new episode, the
first observation of another env) gets a new state; the least recently used one beyond ``keep``
is forgotten.
"""

from __future__ import annotations

from typing import Callable, Generic, Mapping, TypeVar

import numpy as np

State = TypeVar("State")


def tree_size(obs: Mapping) -> int:
    """The observation's node count (``num_nodes``, a scalar or a one-element array)."""
    num = obs["num_nodes"]
    return int(num.item() if type(num) is np.ndarray and num.size == 1 else np.asarray(num).reshape(-1)[0])


class TreeStates(Generic[State]):
    """One ``State`` per tree, made by ``new()`` the first time a tree is seen; at most ``keep`` kept."""

    def __init__(self, new: Callable[[], State], keep: int = 8) -> None:
        self.new, self.keep = new, int(keep)
        self.clear()

    def clear(self) -> None:
        """Forget every tree."""
        #: Most recently used first: ``(start + goal bytes, node count, last row's bytes)`` and the state.
        self._marks: list[tuple[bytes, int, bytes]] = []
        self._states: list[State] = []

    def __len__(self) -> int:
        return len(self._states)

    def of(self, obs: Mapping) -> State:
        """The state of the observation's tree (a new one for a tree not seen before)."""
        n = tree_size(obs)
        start, goal, nodes = obs["start"], obs["goal"], obs["nodes"]
        episode = start.tobytes() + goal.tobytes() if type(start) is np.ndarray else \
            np.asarray(start).tobytes() + np.asarray(goal).tobytes()
        last = (nodes[n - 1].tobytes() if type(nodes) is np.ndarray else np.asarray(nodes[n - 1]).tobytes()) if n else b""
        marks = self._marks
        for i, (known, m, row) in enumerate(marks):
            # the same episode, grown (or not), and still holding the row read last
            if known == episode and m <= n and (row == last if m == n else
                                                m == 0 or np.asarray(nodes[m - 1]).tobytes() == row):
                if i == 0:
                    if m != n:
                        marks[0] = (episode, n, last)
                    return self._states[0]
                del marks[i]
                state = self._states.pop(i)
                break
        else:
            state = self.new()
        marks.insert(0, (episode, n, last))
        self._states.insert(0, state)
        if len(marks) > self.keep:
            del marks[self.keep:], self._states[self.keep:]
        return state


__all__ = ["TreeStates", "tree_size"]
