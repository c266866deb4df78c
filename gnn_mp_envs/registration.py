"""The one registration table: every environment id and the kwargs that make its variant."""

from __future__ import annotations

import gymnasium as gym

ENTRY_POINT = "gnn_mp_envs.envs.tree_env:TreePlanningEnv"

#: id -> kwargs of :class:`~gnn_mp_envs.envs.tree_env.TreePlanningEnv`.
ENVIRONMENTS: dict[str, dict] = {
    "GNNMP/Maze2DRRT-v0": {"task": "maze2d", "planner": "rrt", "max_nodes": 5000},
    "GNNMP/Maze2DBiRRT-v0": {"task": "maze2d", "planner": "birrt", "max_nodes": 5000},
    "GNNMP/PendulumRRT-v0": {"task": "pendulum", "planner": "rrt", "max_nodes": 20000},
    # Held-out arm problems solve in < 500 nodes; 5,000 keeps the per-step observation copy
    # small (pass max_nodes=20000 for the 20,000-node budget).
    "GNNMP/ArmBiRRT-v0": {"task": "arm", "planner": "birrt", "max_nodes": 5000},
}

#: Benchmark task name -> environment id.
TASK_ENV_IDS: dict[str, str] = {
    "maze2d": "GNNMP/Maze2DRRT-v0",
    "pendulum": "GNNMP/PendulumRRT-v0",
    "arm": "GNNMP/ArmBiRRT-v0",
}


def register_envs() -> None:
    """Register every id of :data:`ENVIRONMENTS` with Gymnasium (idempotent)."""
    for env_id, kwargs in ENVIRONMENTS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs=dict(kwargs))
