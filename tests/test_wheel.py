"""A regular (non-editable) install works away from the checkout.

Every other test imports the package from the editable checkout, where every file is at hand. This one
builds the wheel (``pip wheel --no-deps``), installs it into a fresh virtual environment outside the
checkout and, from another folder, plans one problem of each built-in task with its default collision
checker through the installed ``gnn-mp`` command. A file the package reads at run time but the wheel
lacks (``pyproject.toml``'s package data) fails here. The test names no data path: it installs and plans.

Nothing is downloaded: the wheel is built with this environment's build backend
(``--no-build-isolation``; ``setuptools`` is in the ``test`` extra) and the fresh environment reads its
dependencies (numpy, torch, ...) from this environment's site-packages through a ``.pth`` line, which
puts the directory on ``sys.path`` without running the ``.pth`` files inside it (the editable install's
finder among them), so ``gnn_mp_envs``, ``agents`` and ``train`` can only come from the wheel.
"""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
#: The six built-in tasks; the mbm robots plan with their default checker (the sphere models).
TASKS = ("maze2d", "pendulum", "arm", "panda-mbm", "ur5-mbm", "fetch-mbm")
#: What a source copy leaves out: version control, environments, build and run outputs, caches (a stale
#: ``build/lib`` would put files into the wheel that the package data no longer names).
_NOT_SOURCE = shutil.ignore_patterns(".git", ".venv", "venv", "build", "dist", "site", "results", "runs", "data",
                                     "__pycache__", "*.egg-info", ".pytest_cache", "*.pyc", "*.nbi", "*.nbc")


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))} -> rc {proc.returncode}\n{proc.stdout[-2000:]}\n" \
                                 f"{proc.stderr[-4000:]}"
    return proc


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """(the fresh environment's bin/, a work folder outside the checkout, the environment variables)."""
    top = tmp_path_factory.mktemp("wheel")
    assert not top.resolve().is_relative_to(ROOT)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env.update(PYTHONNOUSERSITE="1", PIP_NO_INPUT="1", PIP_DISABLE_PIP_VERSION_CHECK="1", MPLBACKEND="Agg")
    source = top / "src"
    shutil.copytree(ROOT, source, ignore=_NOT_SOURCE, symlinks=True)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", str(top / "dist"), str(source)], top, env, 300)
    (wheel,) = (top / "dist").glob("gnn_mp_envs-*.whl")
    venv = top / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], top, env, 120)
    python = venv / "bin" / "python"
    purelib = _run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                   top, env, 60).stdout.strip()
    deps = [p for p in dict.fromkeys(site.getsitepackages()) if Path(p).is_dir()]
    (Path(purelib) / "_this_test_deps.pth").write_text("".join(f"{p}\n" for p in deps))
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q",
          str(wheel)], top, env, 300)
    work = top / "elsewhere"
    work.mkdir()
    return venv / "bin", work, env


def test_the_installed_packages_are_the_wheels(installed):
    bin_dir, work, env = installed
    out = _run([str(bin_dir / "python"), "-c", "import gnn_mp_envs, agents, train; "
                "print(gnn_mp_envs.__file__, agents.__file__, train.__file__)"], work, env, 120).stdout.split()
    assert len(out) == 3
    for path in map(Path, out):
        assert path.is_relative_to(bin_dir.parent), path
        assert not path.resolve().is_relative_to(ROOT), path


@pytest.mark.parametrize("task", TASKS)
def test_the_installed_command_plans_every_task(installed, task):
    bin_dir, work, env = installed
    out = work / f"{task}.json"
    _run([str(bin_dir / "gnn-mp"), "benchmark", "--task", task, "--samplers", "uniform", "--problems", "1",
          "--no-progress", "--json", str(out)], work, env, 300)
    report = json.loads(out.read_text())
    (run,) = report["runs"]["uniform"]
    assert run["success"] and run["path_valid"] and run["path_valid_fine"], run
