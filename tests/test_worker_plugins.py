"""Worker processes and Ray actors import the ``--import`` modules, from the file the command loaded, and
nothing else of the current directory (issue 52 item 2, issue 51 item 11).

Each command runs from a user's directory (:mod:`tests.plugin_dir`) holding its own task module and files
that shadow ``train``, ``numpy``, ``gymnasium``, ``torch`` and ``agents``: a worker that put the directory
on its path would import one of those and die naming it; a worker without the task module would not know
the task.
"""

from __future__ import annotations

import json
import multiprocessing
import subprocess

import pytest

from tests.plugin_dir import ENV_ID, TASK, cli, environment, make_user_directory


def _spawned_probe(sources, queue) -> None:
    import sys

    from train.args import import_plugin_sources
    import_plugin_sources(sources)
    from gnn_mp_envs.registration import TASK_SPECS
    queue.put((TASK in TASK_SPECS, sys.modules["cwd_task"].__file__, "numpy" in sys.modules and
               sys.modules["numpy"].__file__))


def test_a_spawned_process_imports_the_parents_plugin_by_its_file(tmp_path, monkeypatch):
    """The parent loads ``cwd_task`` from its current directory; a process started elsewhere (spawn, in
    another directory) imports the same file, and the real numpy, not the directory's."""
    import sys

    import train.args
    from train.args import import_modules, plugin_sources
    for name in ("_PLUGINS", "_FROM_DIRECTORY"):       # this process's plugins: as they were, afterwards
        monkeypatch.setattr(train.args, name, {})
    monkeypatch.delitem(sys.modules, "cwd_task", raising=False)
    user = make_user_directory(tmp_path / "user")
    monkeypatch.chdir(user)
    import_modules(["cwd_task"])
    sources = plugin_sources()
    assert ("cwd_task", str(user / "cwd_task.py"), False) in sources
    monkeypatch.chdir(tmp_path)
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_spawned_probe, args=(sources, queue))
    process.start()
    known, file, numpy_file = queue.get(timeout=120)
    process.join(60)
    assert known and file == str(user / "cwd_task.py")
    assert numpy_file and not numpy_file.startswith(str(user))


def test_benchmark_on_ray_actors_imports_the_plugin_and_nothing_else_of_the_directory(tmp_path):
    """`benchmark --ray --workers 2` from the user's directory: Ray put the driver's directory first on
    every actor's path (a `train.py` there killed the actors: "0 of 2 runs finished"), and the actors
    did not import --import modules of the current directory."""
    pytest.importorskip("ray")
    user = make_user_directory(tmp_path)
    result = subprocess.run(cli("benchmark", "--import", "cwd_task", "--task", TASK, "--samplers", "uniform",
                                "--problems", "2", "--ray", "--workers", "2", "--no-progress", "--json", "out.json"),
                            cwd=user, env=environment(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads((user / "out.json").read_text())
    assert report["env_id"] == ENV_ID
    assert [r["problem"] for r in report["runs"]["uniform"]] == [0, 1]
    assert all(r["success"] for r in report["runs"]["uniform"])


def test_train_sampler_workers_import_the_plugin(tmp_path):
    """`train sampler --workers 2` (spawned workers: torch is imported) on a task of the current
    directory: the workers knew no such task (a 53-line traceback)."""
    user = make_user_directory(tmp_path)
    result = subprocess.run(cli("train", "sampler", "--import", "cwd_task", "--task", TASK, "--problems", "4",
                                "--eval-problems", "2", "--workers", "2", "--minutes", "0.02", "--dagger-rounds", "0",
                                "--out", "run", "--data-dir", "data", "--no-progress"),
                            cwd=user, env=environment(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert (user / "run" / "model.pt").is_file() or any((user / "run").glob("*.pt"))


def test_ompl_rows_import_the_plugin_and_nothing_else_of_the_directory(tmp_path):
    """The OMPL runner is a `python -m` subprocess: it put the current directory first on its path (a
    `numpy.py` there failed every OMPL row) and found --import modules only that way."""
    pytest.importorskip("ompl")
    user = make_user_directory(tmp_path)
    result = subprocess.run(cli("benchmark", "--import", "cwd_task", "--task", TASK, "--samplers",
                                "uniform,ompl-rrtconnect", "--problems", "2", "--no-progress", "--json", "out.json"),
                            cwd=user, env=environment(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    runs = json.loads((user / "out.json").read_text())["runs"]["ompl-rrtconnect"]
    assert [r["problem"] for r in runs] == [0, 1] and all(r["success"] for r in runs)


def test_a_plugin_from_a_folder_on_the_parents_path_reaches_a_process_started_elsewhere(tmp_path):
    """A plugin the parent imported by name from a folder on its own ``sys.path`` (pytest's root, PYTHONPATH),
    here a namespace package (a folder without ``__init__.py``) and a plain package: a process started in
    another folder without that path (a Ray actor) imports it from the recorded file. It failed before
    ("No module named ...": only modules loaded from the current directory were recorded by file), which
    killed the Ray actors of a test run after another test had imported tests.tiny_task."""
    import sys
    for name, init in (("nsplug", False), ("pkgplug", True)):
        root = tmp_path / f"root_{name}"
        (root / name).mkdir(parents=True)
        if init:
            (root / name / "__init__.py").write_text("")
        (root / name / "mod.py").write_text("VALUE = 7\n")
        parent = (f"import sys, json; sys.path.insert(0, {str(root)!r}); "
                  f"from train.args import import_modules, plugin_sources; import_modules([{name + '.mod'!r}]); "
                  "print(json.dumps(plugin_sources()))")
        out = subprocess.run([sys.executable, "-c", parent], cwd=tmp_path, capture_output=True, text=True, check=True)
        sources = json.loads(out.stdout.strip().splitlines()[-1])
        child = ("import sys, json; from train.args import import_plugin_sources; "
                 f"import_plugin_sources([tuple(s) for s in json.loads({json.dumps(json.dumps(sources))})]); "
                 f"import {name}.mod; print({name}.mod.VALUE)")
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir(exist_ok=True)
        run = subprocess.run([sys.executable, "-c", child], cwd=elsewhere, capture_output=True, text=True)
        assert run.returncode == 0 and run.stdout.strip() == "7", run.stderr[-400:]
