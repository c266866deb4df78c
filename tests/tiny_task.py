"""A task defined outside the package, as a user would: a point in an empty square.

Imported by ``tests/test_registration.py`` directly and by the CLI with ``--import tests.tiny_task``.
"""

from __future__ import annotations

import numpy as np

from gnn_mp_envs.core.problem import Problem
from gnn_mp_envs.registration import TaskSpec, register_task
from gnn_mp_envs.tasks.base import Task


class TinyProblem(Problem):
    task = "tiny"

    def __init__(self, start: np.ndarray, goal: np.ndarray) -> None:
        super().__init__(start, goal, low=np.zeros(2), high=np.full(2, 2.0), step_size=0.3, resolution=0.1)

    def is_state_valid(self, states: np.ndarray) -> np.ndarray:
        s = np.asarray(states).reshape(-1, 2)
        return np.all((s >= 0.0) & (s <= 2.0), axis=1) & ~np.all(np.abs(s - 1.0) < 0.3, axis=1)


class TinyTask(Task):
    name = "tiny"

    def sample_problem(self, rng: np.random.Generator) -> TinyProblem:
        return TinyProblem(rng.uniform(0.05, 0.4, 2), rng.uniform(1.6, 1.95, 2))

    def render_rgb(self, problem, tree, path) -> np.ndarray:
        return np.zeros((8, 8, 3), dtype=np.uint8)


SPEC = register_task(TaskSpec("tiny", TinyTask, envs={"Tiny/TinyRRT-v0": {"planner": "rrt"},
                                                      "Tiny/TinyBiRRT-v0": {"planner": "birrt"}},
                              max_nodes=400, ompl_planners=("rrtconnect", "rrt")))
