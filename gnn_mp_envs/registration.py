"""The one registration table: every task, its environment ids and the facts tools need about it.

A :class:`TaskSpec` says where a task family's class lives, which environment ids plan it
(with which planner and node budget), which of them the benchmark uses, which scene the
benchmark plans by default and which OMPL planners can run it. The environment, the
benchmark, the OMPL runner and the CLI all read these facts from here; adding a task (inside
or outside this package) is one :func:`register_task` call::

    from gnn_mp_envs.registration import TaskSpec, register_task
    register_task(TaskSpec("corridor", "my_pkg.corridor:CorridorTask",
                           envs={"My/CorridorRRT-v0": {"planner": "rrt"}}, max_nodes=2000))
    env = gym.make("My/CorridorRRT-v0")       # and: gnn-mp benchmark --task corridor --import my_pkg.corridor
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable

import gymnasium as gym

ENTRY_POINT = "gnn_mp_envs.envs.tree_env:TreePlanningEnv"


@dataclass(frozen=True)
class TaskSpec:
    """Facts about one task family."""

    #: Short name used by ``TreePlanningEnv(task=...)``, the benchmark's ``--task`` and the CLI.
    name: str
    #: ``"module:Class"`` (imported on first use: the arm pulls in pybullet) or the class itself.
    entry_point: str | Callable[..., Any]
    #: Environment id -> extra ``TreePlanningEnv`` kwargs of that variant (e.g. the planner).
    envs: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: Tree node budget of every variant (the padded observation's size).
    max_nodes: int = 5000
    #: The variant the benchmark plans with (default: the first of ``envs``).
    benchmark_env: str | None = None
    #: Scene families the task accepts as ``task_kwargs={"scene": ...}`` (empty: no scenes).
    scenes: tuple[str, ...] = ()
    #: Scene the benchmark plans when none is given (the held-out family).
    benchmark_scene: str | None = None
    #: OMPL planners the isolated runner can run on this task (rows ``ompl-<planner>``).
    ompl_planners: tuple[str, ...] = ()
    #: What a path length counts in (the sum of edge costs), for tables and plots.
    path_unit: str = "state-space length"

    @property
    def env_id(self) -> str:
        """The environment id the benchmark uses."""
        return self.benchmark_env or next(iter(self.envs))

    def default_scene(self, split: str) -> str | None:
        """The scene an environment of ``split`` plans when none is named: the held-out family
        for ``split="test"``, the training families otherwise (``"train"`` when it is a scene)."""
        if not self.scenes:
            return None
        if split == "test" and self.benchmark_scene is not None:
            return self.benchmark_scene
        return "train" if "train" in self.scenes else self.scenes[0]

    def task_class(self) -> Callable[..., Any]:
        if not isinstance(self.entry_point, str):
            return self.entry_point
        module, _, cls = self.entry_point.partition(":")
        return getattr(importlib.import_module(module), cls)


#: Task name -> spec. Filled by :func:`register_task`; the built-in tasks are below.
TASK_SPECS: dict[str, TaskSpec] = {}
#: Environment id -> ``TreePlanningEnv`` kwargs (derived from the specs, kept for reference).
ENVIRONMENTS: dict[str, dict[str, Any]] = {}


def register_task(spec: TaskSpec, replace: bool = False) -> TaskSpec:
    """Add a task family and register its environment ids with Gymnasium."""
    if not spec.envs:
        raise ValueError(f"task {spec.name!r} registers no environment id")
    if spec.benchmark_env is not None and spec.benchmark_env not in spec.envs:
        raise ValueError(f"task {spec.name!r}: benchmark_env {spec.benchmark_env!r} is not one of its envs")
    if spec.name in TASK_SPECS and not replace:
        if TASK_SPECS[spec.name] == spec:
            return spec
        raise ValueError(f"task {spec.name!r} is already registered")
    TASK_SPECS[spec.name] = spec
    for env_id, variant in spec.envs.items():
        kwargs = {"task": spec.name, "max_nodes": spec.max_nodes, **variant}
        ENVIRONMENTS[env_id] = kwargs
        if env_id in gym.registry and replace:
            del gym.registry[env_id]
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs=dict(kwargs))
    return spec


def task_spec(name: str) -> TaskSpec:
    """The spec of a registered task; ``ValueError`` naming the known ones otherwise."""
    try:
        return TASK_SPECS[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; known: {', '.join(sorted(TASK_SPECS))}") from None


def make_task(name: str, **kwargs: Any):
    """Instantiate a registered task family by name."""
    return task_spec(name).task_class()(**kwargs)


BUILTIN_TASKS = (
    TaskSpec("maze2d", "gnn_mp_envs.tasks.maze2d:Maze2DTask",
             envs={"GNNMP/Maze2DRRT-v0": {"planner": "rrt"}, "GNNMP/Maze2DBiRRT-v0": {"planner": "birrt"}},
             max_nodes=5000, ompl_planners=("rrtconnect", "rrt"), path_unit="unit-square length"),
    TaskSpec("pendulum", "gnn_mp_envs.tasks.pendulum:PendulumTask",
             envs={"GNNMP/PendulumRRT-v0": {"planner": "rrt"}},
             max_nodes=20000, ompl_planners=("rrt", "kpiece"), path_unit="seconds of motion"),
    # Held-out arm problems solve in < 500 nodes; 5,000 keeps the per-step observation copy
    # small (pass max_nodes=20000 for a 20,000-node budget).
    TaskSpec("arm", "gnn_mp_envs.tasks.arm:ArmTask",
             envs={"GNNMP/ArmBiRRT-v0": {"planner": "birrt"}},
             max_nodes=5000, scenes=("train-a", "train-b", "train", "test"), benchmark_scene="test",
             ompl_planners=("rrtconnect", "rrt"), path_unit="rad, joint-space L2"),
)


def register_envs() -> None:
    """Register the built-in tasks and their environment ids (idempotent)."""
    for spec in BUILTIN_TASKS:
        register_task(spec)
