"""The one registration table: every task, its environment ids and every fact tools need about it.

A :class:`TaskSpec` says where a task family's class lives, which environment ids plan it
(with which planner and node budget), which of them the benchmark uses, which scene the
benchmark plans by default, which OMPL planners can run it, what its path length counts in,
and what learned samplers need to know that the observation space does not say (the state
scale of one extension, the periodic coordinates, the planner's metric, the sampling settings
shipped with each model). The environment, the benchmark, the OMPL runner, the sampler registry
and the training commands all read these facts from here; adding a task (inside or outside
this package) is one :func:`register_task` call::

    from gnn_mp_envs.registration import TaskSpec, register_task
    register_task(TaskSpec("corridor", "my_pkg.corridor:CorridorTask",
                           envs={"My/CorridorRRT-v0": {"planner": "rrt"}}, max_nodes=2000))
    env = gym.make("My/CorridorRRT-v0")       # and: gnn-mp benchmark --task corridor --import my_pkg.corridor
                                              #      gnn-mp train sampler --task corridor --import my_pkg.corridor
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from gnn_mp_envs.robots.checkers import CHECKERS
from gnn_mp_envs.utils.imports import import_entry

ENTRY_POINT = "gnn_mp_envs.envs.tree_env:TreePlanningEnv"
#: Entry point of the RL variants of every env id (``<Env>-RLPick-v0``, ``<Env>-RLBox-v0``).
RL_ENTRY_POINT = "gnn_mp_envs.envs.wrappers:make_rl_env"
#: What a policy's action is: ``"pick"`` (``Discrete(K)``: one of the step's candidate states,
#: ``gnn_mp_envs.envs.candidates.CandidatePickWrapper``) or ``"box"`` (``[-1, 1]^d``, a state
#: through the ``action_frame``).
ACTIONS = ("pick", "box")
#: Episode length limit of the RL envs (``TimeLimit``; the registered RL ids carry it as
#: ``max_episode_steps``): the iterations an evaluation plans at most (``--eval-max-steps``).
RL_MAX_EPISODE_STEPS = 4000
#: Sampling settings of a learned sampler when its task names none (see ``TaskSpec.sampler_settings``).
DEFAULT_SAMPLER_SETTINGS: dict[str, dict[str, Any]] = {
    "gnn": {"uniform_mix": 0.25, "temperature": 0.5, "sigma_scale": 0.6},
    "cvae": {"uniform_mix": 0.5},
    "gnn-cvae": {"uniform_mix": 0.5},
}


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
    #: OMPL's solve limit per problem in the benchmark (an OMPL row's success needs it; ours count nodes
    #: only) and the time axis of the success-vs-time figure (``--ompl-time-limit`` overrides it).
    time_limit_s: float = 10.0
    #: The variant the benchmark plans with (default: the first of ``envs``).
    benchmark_env: str | None = None
    #: Scene families the task accepts as ``task_kwargs={"scene": ...}`` (empty: no scenes).
    scenes: tuple[str, ...] = ()
    #: Scene the benchmark plans when none is given (the held-out family).
    benchmark_scene: str | None = None
    #: Scenes of kinds held out from training, on which training decisions are taken (split ``val``).
    validation_scenes: tuple[str, ...] = ()
    #: Out-of-distribution test scenes (``gnn-mp benchmark --suite ood``): never trained or tuned on;
    #: ``gnn-mp train sampler --scene`` refuses them.
    ood_scenes: tuple[str, ...] = ()
    #: Collision checkers the task's problems offer by name (``gym.make(..., checker=...)``, ``gnn-mp benchmark
    #: --checker``; :data:`gnn_mp_envs.robots.checkers.CHECKERS`, the first the default). Empty: the task has one
    #: checker and takes no ``checker=``.
    checkers: tuple[str, ...] = ()
    #: OMPL planners the isolated runner can run on this task (rows ``ompl-<planner>``).
    ompl_planners: tuple[str, ...] = ()
    #: ``"module:function"`` building the OMPL control-space setup of a kinodynamic task
    #: (``function(problem, planner) -> setup``, see ``gnn_mp_envs.baselines.ompl_runner``);
    #: None: geometric planning (RRTConnect / RRT over the state space).
    ompl_control_setup: str | None = None
    #: What a path length counts in (the sum of edge costs), for tables and plots.
    path_unit: str = "state-space length"
    #: The run counter samplers are judged by on this task (the OOD suite's ratios): collision
    #: checks where a check is the cost, nodes where an extension is (the pendulum's integration).
    headline_metric: str = "collision_checks"
    # --- what learned samplers need (the models' scales and the shipped sampling settings)
    #: About one tree extension in state units: the unit of relative positions and offsets of
    #: the tree models (None: the problems' ``step_size``).
    step_scale: float | None = None
    #: Indices of the angle coordinates (wrapped with period ``high - low``).
    periodic: tuple[int, ...] = ()
    #: Per-coordinate weights of the planner's nearest-neighbour metric,
    #: ``||w * wrap(a - b)||`` (None: Euclidean).
    metric_weights: tuple[float, ...] | None = None
    #: The head the ``gnn`` sampler uses: ``"mixture"`` (a Gaussian mixture over the tree's
    #: nodes) or ``"scorer"`` (a scorer of uniform candidates: kinodynamic tasks, RRT only).
    gnn_head: str = "mixture"
    #: Learned sampler name -> the sampling settings stored with its weights at training
    #: (chosen on split ``val``); missing names get :data:`DEFAULT_SAMPLER_SETTINGS`.
    sampler_settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: Linear maps ``(d x d)`` of ``x - centre`` (the state box's middle; periodic coordinates wrapped
    #: after) under which the task's problem distribution is invariant: training augments its
    #: examples with them (``gnn-mp train sampler --augment``). Maze2D: the square's eight
    #: rotations and reflections; the pendulum: ``(theta, omega) -> (-theta, -omega)``.
    symmetries: tuple[tuple[tuple[float, ...], ...], ...] = ()
    #: The RL reward's settings of this task (``TreePlanningEnv`` reward keywords over
    #: ``gnn_mp_envs.envs.wrappers.RL_REWARD``, e.g. ``{"node_cost": 0, "collision_check_cost": 1}``
    #: where collision checks are what the task is judged on): the defaults of ``make_rl_env`` and
    #: of the registered RL ids (``<Env>-RLPick-v0``, ``-RLBox-v0``).
    rl_reward: dict[str, float] = field(default_factory=dict)
    #: A task whose shipped learned-sampler weights this one uses when it has none of its own
    #: (a user's own maps in the maze2d state space: ``weights_from="maze2d"``). The state
    #: bounds must be the same; each sampler checks the observations it is given.
    weights_from: str | None = None

    @property
    def env_id(self) -> str:
        """The environment id the benchmark uses."""
        return self.benchmark_env or next(iter(self.envs))

    def env_id_for(self, planner: str | None = None) -> str:
        """The environment id of ``planner`` (``None``: the benchmark's); ValueError naming the known ones."""
        if planner is None:
            return self.env_id
        for env_id, variant in self.envs.items():
            if variant.get("planner") == planner:
                return env_id
        known = ", ".join(sorted(str(v.get("planner", "?")) for v in self.envs.values()))
        raise ValueError(f"task {self.name!r} has no {planner!r} planner environment; known: {known}")

    def planner(self, env_id: str | None = None) -> str:
        """The planner of an environment id of this task (default: the benchmark's)."""
        return str(self.envs[env_id or self.env_id].get("planner", "rrt"))

    def num_trees(self, env_id: str | None = None) -> int:
        """Trees the planner of ``env_id`` grows: 2 for BiRRT, 1 for RRT."""
        return 2 if self.planner(env_id) == "birrt" else 1

    def default_scene(self, split: str) -> str | None:
        """The scene an environment of ``split`` plans when none is named: the held-out family
        for ``split="test"``, the training families otherwise (``"train"`` when it is a scene)."""
        if not self.scenes:
            return None
        if split == "test" and self.benchmark_scene is not None:
            return self.benchmark_scene
        return "train" if "train" in self.scenes else self.scenes[0]

    def training_scene(self) -> str | None:
        """The scene training problems come from (tasks with scenes: the training families)."""
        return self.default_scene("train")

    def task_class(self) -> Callable[..., Any]:
        if not isinstance(self.entry_point, str):
            return self.entry_point
        return import_entry(self.entry_point)

    def sampler_defaults(self, name: str) -> dict[str, Any]:
        """The sampling settings stored with a newly trained ``name`` sampler for this task."""
        return dict(self.sampler_settings.get(name, DEFAULT_SAMPLER_SETTINGS.get(name, {})))

    def state_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The sampling bounds of every problem of the task as float32 arrays: exactly the
        environments' action box. Read once from a task instance and cached per process (the
        arm's costs a simulator start, ~0.1 s)."""
        if self.name not in _BOUNDS:
            task = self.task_class()(**({"scene": self.default_scene("test")} if self.scenes else {}))
            try:
                low, high = task.state_bounds()
            finally:
                task.close()
            _BOUNDS[self.name] = (np.asarray(low, np.float32).copy(), np.asarray(high, np.float32).copy())
        low, high = _BOUNDS[self.name]
        return low.copy(), high.copy()

    def periodic_mask(self, state_dim: int) -> np.ndarray:
        """``(state_dim,)`` bool: which coordinates wrap."""
        mask = np.zeros(state_dim, dtype=bool)
        mask[list(self.periodic)] = True
        return mask


#: Task name -> spec. Filled by :func:`register_task`; the built-in tasks are below.
TASK_SPECS: dict[str, TaskSpec] = {}
_BOUNDS: dict[str, tuple[np.ndarray, np.ndarray]] = {}
GNN_HEADS = ("mixture", "scorer")


def rl_env_id(env_id: str, action: str = "pick") -> str:
    """The registered RL variant of a planning env id: ``GNNMP/Maze2DRRT-v0`` ->
    ``GNNMP/Maze2DRRT-RLPick-v0`` (``action="box"``: ``...-RLBox-v0``)."""
    if action not in ACTIONS:
        raise ValueError(f"action must be one of {ACTIONS}, got {action!r}")
    name, dash, version = env_id.rpartition("-v")
    if not dash or not version.isdigit():
        name, version = env_id, "0"
    return f"{name}-RL{action.capitalize()}-v{version}"


def register_task(spec: TaskSpec, replace: bool = False) -> TaskSpec:
    """Add a task family and register its environment ids with Gymnasium."""
    if not spec.envs:
        raise ValueError(f"task {spec.name!r} registers no environment id")
    if spec.benchmark_env is not None and spec.benchmark_env not in spec.envs:
        raise ValueError(f"task {spec.name!r}: benchmark_env {spec.benchmark_env!r} is not one of its envs")
    if spec.gnn_head not in GNN_HEADS:
        raise ValueError(f"task {spec.name!r}: gnn_head must be one of {GNN_HEADS}, got {spec.gnn_head!r}")
    if spec.step_scale is not None and not spec.step_scale > 0:
        raise ValueError(f"task {spec.name!r}: step_scale must be > 0, got {spec.step_scale}")
    if spec.weights_from is not None and spec.weights_from not in TASK_SPECS:
        raise ValueError(f"task {spec.name!r}: weights_from names unknown task {spec.weights_from!r}; "
                         f"known: {', '.join(sorted(TASK_SPECS))}")
    unknown = sorted(set(spec.validation_scenes + spec.ood_scenes) - set(spec.scenes))
    if unknown:
        raise ValueError(f"task {spec.name!r}: validation/OOD scene(s) {unknown} are not among its scenes")
    for m in spec.symmetries:
        a = np.asarray(m, dtype=np.float64)
        if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.allclose(a @ a.T, np.eye(len(a))):
            raise ValueError(f"task {spec.name!r}: a symmetry must be an orthogonal square matrix, got {m}")
    if set(spec.validation_scenes) & set(spec.ood_scenes):
        raise ValueError(f"task {spec.name!r}: a scene cannot be both a validation and an OOD scene")
    if spec.name in TASK_SPECS and not replace:
        if TASK_SPECS[spec.name] == spec:
            return spec
        raise ValueError(f"task {spec.name!r} is already registered")
    TASK_SPECS[spec.name] = spec
    _BOUNDS.pop(spec.name, None)
    for env_id, variant in spec.envs.items():
        kwargs = {"task": spec.name, "max_nodes": spec.max_nodes, **variant}
        rl_ids = {rl_env_id(env_id, action): action for action in ACTIONS}
        for known in (env_id, *rl_ids):
            if known in gym.registry and replace:
                del gym.registry[known]
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs=dict(kwargs))
        for rl_id, action in rl_ids.items():
            # make_rl_env's MDP (the one `gnn-mp train rl` trains); gym.make adds the TimeLimit
            if rl_id not in gym.registry:
                gym.register(id=rl_id, entry_point=RL_ENTRY_POINT, max_episode_steps=RL_MAX_EPISODE_STEPS,
                             kwargs={"task": spec.name, "planner": variant.get("planner"), "action": action,
                                     "max_episode_steps": None})
    return spec


def register_scene(task: str, name: str, *, validation: bool = False, ood: bool = False) -> TaskSpec:
    """Add scene family ``name`` to the scenes of the registered task ``task`` (``validation`` /
    ``ood``: also to its validation / out-of-distribution scenes) and return the task's new spec.

    The task's own module keeps the family's data (the arm's
    :func:`~gnn_mp_envs.tasks.arm.scenes.register_scene_family`) and calls this so that the
    environment and the command line accept the name. Only the spec changes: the environment ids
    name the task, and an environment reads the task's spec when it is made. A scene the task
    already has is left as it is; an unknown task is a ``ValueError``.
    """
    from dataclasses import replace as replaced

    spec = task_spec(task)
    if not isinstance(name, str) or not name:
        raise ValueError(f"task {task!r}: a scene needs a non-empty name, got {name!r}")
    if validation and ood:
        raise ValueError(f"task {task!r}: a scene cannot be both a validation and an OOD scene")
    if name in spec.scenes:
        return spec
    new = replaced(spec, scenes=(*spec.scenes, name),
                  validation_scenes=spec.validation_scenes + ((name,) if validation else ()),
                  ood_scenes=spec.ood_scenes + ((name,) if ood else ()))
    TASK_SPECS[task] = new
    return new


def task_spec(name: str) -> TaskSpec:
    """The spec of a registered task; ``ValueError`` naming the known ones otherwise."""
    try:
        return TASK_SPECS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown task {name!r}; known: {', '.join(sorted(TASK_SPECS))}") from None


def same_bounds(first: tuple[Any, Any], second: tuple[Any, Any]) -> bool:
    """Whether two ``(low, high)`` pairs are the same state box: equal shapes and values within
    float32 rounding (``atol=1e-5``; checkpoints and spaces store bounds as float32). The one
    comparison behind every "same state bounds" check (a sampler's ``bounds=``, a policy
    checkpoint's, a task borrowing another's weights)."""
    (low_a, high_a), (low_b, high_b) = ([np.asarray(v, np.float64) for v in pair] for pair in (first, second))
    return (low_a.shape == low_b.shape == high_a.shape == high_b.shape
            and bool(np.allclose(low_a, low_b, atol=1e-5)) and bool(np.allclose(high_a, high_b, atol=1e-5)))


def make_task(name: str, **kwargs: Any):
    """Instantiate a registered task family by name."""
    return task_spec(name).task_class()(**kwargs)


def _mbm_spec(name: str, task_class: str, env_id: str, path_unit: str = "rad, joint-space L2",
              max_nodes: int = 5000, time_limit_s: float = 10.0) -> TaskSpec:
    """A MotionBenchMaker robot's task: BiRRT; the benchmark plans the test split of all seven scenes,
    training uses the five training scenes (``"train"``), ``"test"`` holds the two held out; both
    checkers (the sphere model by default); step_scale: tasks/mbm STEP_SIZE (rad)."""
    return TaskSpec(name, f"gnn_mp_envs.tasks.mbm:{task_class}", envs={env_id: {"planner": "birrt"}},
                    max_nodes=max_nodes, time_limit_s=time_limit_s, scenes=("all", "train", "test", "table_pick", "table_under_pick", "box",
                                            "bookshelf_small", "bookshelf_tall", "bookshelf_thin", "cage"),
                    benchmark_scene="all", ompl_planners=("rrtconnect", "rrt"), path_unit=path_unit,
                    checkers=tuple(CHECKERS), step_scale=1.0,
                    rl_reward={"node_cost": 0.0, "collision_check_cost": 1.0})


#: The eight rotations and reflections of the square, as matrices of ``x - centre``.
SQUARE_SYMMETRIES = tuple(
    tuple(tuple(float(v) for v in row) for row in m)
    for m in ([[1, 0], [0, 1]], [[0, -1], [1, 0]], [[-1, 0], [0, -1]], [[0, 1], [-1, 0]],
              [[-1, 0], [0, 1]], [[0, 1], [1, 0]], [[1, 0], [0, -1]], [[0, -1], [-1, 0]]))

BUILTIN_TASKS = (
    # maze2d: step_scale is the extension length (tasks/maze2d/task.py STEP_SIZE).
    # Scenes (tasks/maze2d/scenes.py): "walls" is every split's family; "mixed" the training
    # domain randomisation ("mixed-angled": plus walls at an angle); pockets, slits, slanted held-out
    # validation kinds; the rest the OOD test kinds.
    TaskSpec("maze2d", "gnn_mp_envs.tasks.maze2d:Maze2DScenesTask",
             envs={"GNNMP/Maze2DRRT-v0": {"planner": "rrt"}, "GNNMP/Maze2DBiRRT-v0": {"planner": "birrt"}},
             max_nodes=5000, ompl_planners=("rrtconnect", "rrt"), path_unit="unit-square length",
             step_scale=0.05,
             scenes=("walls", "mixed", "mixed-angled", "pockets", "slits", "slanted", "trap", "goal-trap",
                     "corridor", "spiral", "forest", "rotated"),
             validation_scenes=("pockets", "slits", "slanted"),
             ood_scenes=("trap", "goal-trap", "corridor", "spiral", "forest", "rotated"),
             symmetries=SQUARE_SYMMETRIES, rl_reward={"step_penalty": 1.0, "node_cost": 0.0}),
    # pendulum: one 0.2 s edge moves the state by ~0.4 (rad, rad/s); the metric weighs omega by
    # tasks/pendulum/task.py VELOCITY_WEIGHT; the GNN head that beat uniform there is the scorer.
    TaskSpec("pendulum", "gnn_mp_envs.tasks.pendulum:PendulumTask",
             envs={"GNNMP/PendulumRRT-v0": {"planner": "rrt"}},
             max_nodes=20000, ompl_planners=("rrt", "kpiece"),
             ompl_control_setup="gnn_mp_envs.tasks.pendulum.ompl_setup:pendulum_setup",
             path_unit="seconds of motion", headline_metric="nodes_expanded", step_scale=0.4, periodic=(0,),
             metric_weights=(1.0, 0.4),
             gnn_head="scorer", rl_reward={"collision_check_cost": 0.01},
             # Scenes (tasks/pendulum/task.py SCENE_FAMILIES): other goals, starts and torque limits.
             scenes=("upright", "mixed", "far-goal", "lively", "side-goal", "fast-goal", "moving-start", "weak",
                     "strong", "hang"),
             validation_scenes=("far-goal", "lively"),
             ood_scenes=("side-goal", "fast-goal", "moving-start", "weak", "strong", "hang"),
             symmetries=(((1.0, 0.0), (0.0, 1.0)), ((-1.0, 0.0), (0.0, -1.0))),
             sampler_settings={"gnn": {"uniform_mix": 0.2, "goal_bias": 0.05, "candidates": 16, "temperature": 1.0}}),
    # Held-out arm problems solve in < 500 nodes; 5,000 keeps the per-step observation copy
    # small (pass max_nodes=20000 for a 20,000-node budget). step_scale: tasks/arm STEP_SIZE (rad).
    TaskSpec("arm", "gnn_mp_envs.tasks.arm:ArmTask",
             envs={"GNNMP/ArmBiRRT-v0": {"planner": "birrt"}},
             max_nodes=5000, scenes=("train-a", "train-b", "train", "test", "pillars", "tall-clutter", "shelves", "bins"),
             benchmark_scene="test", validation_scenes=("pillars",), ood_scenes=("tall-clutter", "shelves", "bins"),
             ompl_planners=("rrtconnect", "rrt"), path_unit="rad, joint-space L2", step_scale=0.4,
             checkers=tuple(CHECKERS), rl_reward={"node_cost": 0.0, "collision_check_cost": 1.0}),
    # MotionBenchMaker's problems of the Panda, the UR5 and the Fetch (docs/mbm.md).
    _mbm_spec("panda-mbm", "PandaMBMTask", "GNNMP/PandaMBM-v0"),
    _mbm_spec("ur5-mbm", "UR5MBMTask", "GNNMP/UR5MBM-v0"),
    # The Fetch's bookshelf and cage problems need longer trees under a checker that covers its meshes:
    # 30,000 nodes and 30 s (chosen on the val split: uniform and OMPL's RRTConnect solve 94 to 96%
    # there, against 75 to 82% within 5,000 nodes and 10 s).
    _mbm_spec("fetch-mbm", "FetchMBMTask", "GNNMP/FetchMBM-v0", path_unit="joint-space L2 (rad; the torso's lift in m)",
              max_nodes=30000, time_limit_s=30.0),
)


def register_envs() -> None:
    """Register the built-in tasks and their environment ids (idempotent)."""
    for spec in BUILTIN_TASKS:
        register_task(spec)
