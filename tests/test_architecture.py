"""The floors of the house, read from the sources (every import, at module level or inside a function):
no import circle among the package's modules; ``gnn_mp_envs`` imports neither ``agents`` nor
``train`` nor torch; ``agents`` imports no ``train``; nothing in the packages imports ``tools``.
Inside ``gnn_mp_envs``: the robots (``gnn_mp_envs.robots``) are a floor under the tasks and import no
task, and no task package imports another (they meet on the floors below them).
Inside ``agents``: every module is a method's or the shared floor's, no method imports another
method, and the shared floor imports no method. Inside ``train`` the same by job: no job (an entry
point's package: benchmark, tree samplers, RL, critical samples) imports another job, and ``train``'s
shared floor imports no job (``docs/architecture.md``)."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("gnn_mp_envs", "agents", "train")
TORCH_FAMILY = ("torch", "tensordict", "torchrl", "torch_geometric", "stable_baselines3")
#: The modules that import OMPL, inside functions: the OMPL runner and a kinodynamic task's control-space
#: setup, which only the runner's subprocess imports (through ``TaskSpec.ompl_control_setup``).
OMPL_SIDE = ("gnn_mp_envs.baselines.ompl_runner", "gnn_mp_envs.tasks.pendulum.ompl_setup")
#: The learned methods, one package each: none imports another (they meet on the shared floor).
METHODS = ("agents.tree", "agents.rl", "agents.critical")
#: The shared floor under the methods: what any method may import; it imports no method (a registry
#: may name a method's class as a ``"module:attribute"`` string, resolved on first use).
SHARED_FLOOR = ("agents", "agents.nn", "agents.samplers", "agents.checkpoints", "agents.registry")
#: ``train``'s jobs, one package per entry point: none imports another (they meet on ``train``'s floor).
JOBS = ("train.benchmark", "train.tree", "train.rl", "train.critical")
#: ``train``'s shared floor: flags and ``UsageError`` (``args``), the run shell (``run``), worker processes and
#: Ray actors (``workers``); it imports no job. ``train.cli``, the command, sits above the jobs it dispatches to.
TRAIN_FLOOR = ("train", "train.args", "train.run", "train.workers")


def modules(root: Path = ROOT) -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (root / package).rglob("*.py"):
            name = ".".join(path.relative_to(root).with_suffix("").parts)
            out[name.removesuffix(".__init__")] = path
    return out


def imported_names(name: str, path: Path) -> set[str]:
    """Every module name ``path`` imports (``from a import b`` gives ``a`` and ``a.b``)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


@functools.cache
def import_graph(root: Path = ROOT) -> tuple[nx.DiGraph, dict[str, set[str]]]:
    """The modules' import graph and, per module, the first part of every name it imports; read once
    per root (the tests only read them)."""
    mods = modules(root)
    graph = nx.DiGraph()
    graph.add_nodes_from(mods)
    external: dict[str, set[str]] = {}
    for name, path in mods.items():
        for target in imported_names(name, path):
            external.setdefault(name, set()).add(target.split(".")[0])
            while target and target not in mods:
                target = target.rsplit(".", 1)[0] if "." in target else ""
            if target and target != name:
                graph.add_edge(name, target)
    return graph, external


def test_no_import_circle():
    graph, _ = import_graph()
    circles = [sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]
    assert circles == []


def test_floors():
    graph, external = import_graph()
    breaks = [(a, b) for a, b in graph.edges
              if (a.startswith("gnn_mp_envs") and b.split(".")[0] in ("agents", "train"))
              or (a.startswith("agents") and b.startswith("train"))]
    assert breaks == []
    torch_in_envs = sorted(m for m, names in external.items() if m.startswith("gnn_mp_envs")
                           and names & set(TORCH_FAMILY))
    assert torch_in_envs == []
    assert sorted(m for m, names in external.items() if "tools" in names) == []


def test_the_graph_sees_imports_inside_functions():
    """An oracle for the reader itself: a lazy import inside a function is an edge too."""
    graph, _ = import_graph()
    assert graph.has_edge("agents.registry", "agents.samplers.baselines")      # imported inside a factory
    assert graph.has_edge("train.benchmark.runs", "gnn_mp_envs.evaluation")


def _part(name: str, parts: tuple[str, ...]) -> str | None:
    """The entry of ``parts`` that ``name`` is or lies under (the longest; None: none)."""
    found = [p for p in parts if name == p or name.startswith(p + ".")]
    return max(found, key=len) if found else None


def _method(name: str) -> str | None:
    return _part(name, METHODS)


def test_every_agents_module_is_a_method_or_the_shared_floor():
    unplaced = sorted(m for m in modules() if m.startswith("agents") and _method(m) is None
                      and (_part(m, SHARED_FLOOR) in (None, "agents") and m != "agents"))
    assert unplaced == []


def test_no_method_imports_another_method():
    graph, _ = import_graph()
    breaks = sorted((a, b) for a, b in graph.edges if _method(a) and _method(b) and _method(a) != _method(b))
    assert breaks == []


def test_the_shared_floor_imports_no_method():
    graph, _ = import_graph()
    breaks = sorted((a, b) for a, b in graph.edges if a.startswith("agents") and _method(a) is None
                    and _method(b) is not None)
    assert breaks == []


def test_the_method_rules_see_a_break():
    """An oracle for the two rules: the edges they forbid are edges the reader finds and names."""
    assert _method("agents.rl.sampler") == "agents.rl" and _method("agents.nn.priors") is None
    assert _method("agents.tree") == "agents.tree" and _method("agents.treelike") is None
    graph, _ = import_graph()
    assert graph.has_edge("agents.tree.models", "agents.nn.causal")      # a method on the floor: allowed


def _job(name: str) -> str | None:
    return _part(name, JOBS)


def test_every_train_module_is_a_job_or_the_floor():
    unplaced = sorted(m for m in modules() if m.startswith("train") and _job(m) is None
                      and m not in TRAIN_FLOOR and m != "train.cli")
    assert unplaced == []


def test_no_job_imports_another_job():
    graph, _ = import_graph()
    breaks = sorted((a, b) for a, b in graph.edges if _job(a) and _job(b) and _job(a) != _job(b))
    assert breaks == []


def test_the_train_floor_imports_no_job():
    graph, _ = import_graph()
    breaks = sorted((a, b) for a, b in graph.edges if a in TRAIN_FLOOR and _job(b) is not None)
    assert breaks == []


def test_the_job_rules_see_a_break():
    """An oracle for the two rules: the reader places modules by job, and finds the edges (module level
    and inside a function) by which a job reaches the floor, the edges a break would be."""
    assert _job("train.tree.data") == "train.tree" and _job("train.treelike") is None and _job("train.workers") is None
    graph, _ = import_graph()
    assert graph.has_edge("train.tree.data", "train.workers")         # inside a function
    assert graph.has_edge("train.benchmark.runs", "train.workers")    # at module level
    assert graph.has_edge("train.cli", "train.benchmark.args")        # the command above the jobs: allowed


def test_only_the_ompl_runner_side_imports_ompl():
    """The environments never import OMPL: only the runner's side does, and no module imports a task's
    OMPL setup (the runner finds it by the name in the task's spec)."""
    graph, external = import_graph()
    assert sorted(m for m, names in external.items() if "ompl" in names) == sorted(OMPL_SIDE)
    assert sorted(a for a, b in graph.edges if b in OMPL_SIDE[1:]) == []


# ---------------------------------------------------------------------- robots under tasks, tasks apart
ROBOTS = "gnn_mp_envs.robots"
TASKS = "gnn_mp_envs.tasks"


def _task_package(name: str) -> str | None:
    """The task package ``name`` lies in (``gnn_mp_envs.tasks.<task>``; None: not in one, e.g. the tasks'
    shared base)."""
    parts = name.split(".")
    if name.startswith(TASKS + ".") and len(parts) >= 3 and (ROOT / "gnn_mp_envs" / "tasks" / parts[2]).is_dir():
        return ".".join(parts[:3])
    return None


def robot_and_task_breaks(graph: nx.DiGraph) -> list[tuple[str, str]]:
    """Edges from the robots' floor to a task, and from one task package to another."""
    return sorted((a, b) for a, b in graph.edges
                  if ((a == ROBOTS or a.startswith(ROBOTS + ".")) and b.startswith(TASKS))
                  or (_task_package(a) and _task_package(b) and _task_package(a) != _task_package(b)))


def test_the_robots_import_no_task_and_no_task_imports_another():
    graph, _ = import_graph()
    assert robot_and_task_breaks(graph) == []
    assert graph.has_edge("gnn_mp_envs.tasks.mbm.task", "gnn_mp_envs.robots.catalog")   # a task on the floor: allowed


def test_the_robot_and_task_rules_fail_on_a_planted_break(tmp_path):
    """An oracle for the two rules: a copy of the sources with a robot module importing a task (at module
    level) and a task importing another task (inside a function) shows exactly those two breaks."""
    import shutil
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__", "*.npz",
                                                                                          "*.stl", "*.STL", "*.pt"))
    world = tmp_path / "gnn_mp_envs" / "robots" / "world.py"
    world.write_text(world.read_text() + "\nimport gnn_mp_envs.tasks.arm.scenes  # noqa\n")
    task = tmp_path / "gnn_mp_envs" / "tasks" / "arm" / "task.py"
    task.write_text(task.read_text() + "\n\ndef _planted():\n    from gnn_mp_envs.tasks.mbm import data  # noqa\n")
    graph, _ = import_graph(tmp_path)
    assert robot_and_task_breaks(graph) == [("gnn_mp_envs.robots.world", "gnn_mp_envs.tasks.arm.scenes"),
                                            ("gnn_mp_envs.tasks.arm.task", "gnn_mp_envs.tasks.mbm"),
                                            ("gnn_mp_envs.tasks.arm.task", "gnn_mp_envs.tasks.mbm.data")]
