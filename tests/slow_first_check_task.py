"""The tiny task (``tests/tiny_task.py``) with a first check that takes seconds in each process, as a checker
that builds or compiles itself on first use does: the OMPL runner must not count it as planning time."""

from __future__ import annotations

import time

import numpy as np

from gnn_mp_envs.registration import TaskSpec, register_task
from tests.tiny_task import TinyProblem, TinyTask

#: How long the first check of a process takes (s).
FIRST_CHECK_S = 3.0
_CHECKED: list[bool] = []


class SlowFirstCheckProblem(TinyProblem):
    task = "tiny-slow-first-check"

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        if not _CHECKED:
            _CHECKED.append(True)
            time.sleep(FIRST_CHECK_S)
        return super().is_state_valid(states)


class SlowFirstCheckTask(TinyTask):
    name = "tiny-slow-first-check"

    def sample_problem(self, rng: np.random.Generator) -> SlowFirstCheckProblem:
        return SlowFirstCheckProblem(rng.uniform(0.05, 0.4, 2), rng.uniform(1.6, 1.95, 2))


SPEC = register_task(TaskSpec("tiny-slow-first-check", SlowFirstCheckTask,
                              envs={"Tiny/TinySlowFirstCheckRRT-v0": {"planner": "rrt"}},
                              max_nodes=400, ompl_planners=("rrtconnect",)))
