"""Task families: seeded generators of planning problems with a fixed held-out split."""

from __future__ import annotations

from typing import Any

import numpy as np

from gnn_mp_envs.core.problem import InvalidProblemError, Problem

#: Seed-sequence roots of the problem splits. ``Task.problem("test", i)`` is the i-th
#: held-out problem on every machine; training never draws from the test stream.
SPLIT_SEEDS = {"train": 0, "val": 1, "test": 2}


def check_keys(spec: dict, known: tuple[str, ...], what: str) -> None:
    """Refuse a problem dict with keys a task does not read (a typo such as ``"wals"`` would
    otherwise plan another problem than the one meant)."""
    unknown = sorted(set(spec) - set(known))
    if unknown:
        raise InvalidProblemError(f"unknown key(s) {unknown} in {what}; known: {', '.join(known)}")


class Task:
    """A family of problems; one instance per environment (it may own a simulator).

    Facts that tools need without building the task (environment ids, node budget, scenes,
    OMPL planners) live in its :class:`~gnn_mp_envs.registration.TaskSpec`.
    """

    name = "task"
    #: Which planners make sense for the task (kinodynamic tasks cannot run BiRRT).
    planners: tuple[str, ...] = ("rrt", "birrt")
    #: Features per obstacle row and the most rows a problem has (0: the task has no obstacles).
    obstacle_width: int = 0
    max_obstacles: int = 0

    def sample_problem(self, rng: np.random.Generator) -> Problem:
        """Draw a problem from the family's distribution."""
        raise NotImplementedError

    def problem(self, split: str, index: int) -> Problem:
        """The ``index``-th problem of ``split`` (``train``, ``val`` or ``test``), reproducibly."""
        if split not in SPLIT_SEEDS:
            raise ValueError(f"unknown split {split!r}; known: {sorted(SPLIT_SEEDS)}")
        if index < 0:
            raise ValueError(f"problem index must be >= 0, got {index}")
        return self.sample_problem(np.random.default_rng([SPLIT_SEEDS[split], int(index)]))

    def num_problems(self, split: str) -> int | None:
        """How many problems ``split`` holds; None (the default): unbounded, a generator's stream.
        A task with a fixed problem set (MotionBenchMaker) bounds it: indices beyond are refused,
        and a reset without an index draws below it."""
        return None

    def state_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Sampling bounds shared by every problem of the family (default: from a probe problem)."""
        probe = self.problem("test", 0)
        return probe.low.copy(), probe.high.copy()

    def test_problems(self, n: int) -> list[Problem]:
        """The first ``n`` held-out test problems."""
        return [self.problem("test", i) for i in range(n)]

    def make_problem(self, spec: Any) -> Problem:
        """Turn a user-supplied problem (a Problem or a dict of fields) into a validated Problem."""
        if isinstance(spec, Problem):
            spec.validate()
            return spec
        raise TypeError(f"options['problem'] must be a Problem for task {self.name!r}, "
                        f"got {type(spec).__name__}")

    def obstacle_rows(self, problem: Problem) -> np.ndarray:
        """The problem's obstacles as rows of ``obstacle_width`` numbers (at most
        ``max_obstacles``); what the observation's ``obstacles`` entry shows."""
        return np.zeros((0, self.obstacle_width))

    def render_rgb(self, problem: Problem, tree: Any, path: np.ndarray | None) -> np.ndarray:
        """An RGB image of the problem, tree and path."""
        raise NotImplementedError

    def close(self) -> None:
        """Release simulator resources."""

    def __del__(self) -> None:
        """A task that owns a simulator (the arm's, panda-mbm's pybullet client) releases it when
        collected, also if nobody called :meth:`close`."""
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter teardown, or a half-built task
            pass
