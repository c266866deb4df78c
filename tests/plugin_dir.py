"""A user's working directory for the tests of worker processes and Ray actors: a task module of its own
(``cwd_task``, imported with ``--import cwd_task``, not installed) beside files whose names shadow modules
every worker imports (``train.py``, ``numpy.py``, ``agents/``): importing any of those exits the process
with a message naming it. Nothing of the directory may be imported but the module ``--import`` names."""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The task ``cwd_task.py`` registers and its env id.
TASK, ENV_ID = "cwdtiny", "CwdTiny/TinyRRT-v0"
POISON = "raise SystemExit('imported {name} from the current directory')\n"


def make_user_directory(directory: Path) -> Path:
    """Fill ``directory`` as a user's directory; return it."""
    directory.mkdir(parents=True, exist_ok=True)
    source = (ROOT / "tests" / "tiny_task.py").read_text()
    source = source.replace('"tiny"', f'"{TASK}"').replace('"Tiny/TinyRRT-v0"', f'"{ENV_ID}"')
    source = source.replace('"Tiny/TinyBiRRT-v0"', '"CwdTiny/TinyBiRRT-v0"')
    assert TASK in source and ENV_ID in source
    (directory / "cwd_task.py").write_text(source)
    for name in ("train", "numpy", "gymnasium", "torch"):
        (directory / f"{name}.py").write_text(POISON.format(name=f"{name}.py"))
    (directory / "agents").mkdir()
    (directory / "agents" / "__init__.py").write_text(POISON.format(name="agents/"))
    return directory


def cli(*argv: str) -> list[str]:
    """The ``gnn-mp`` command line (this interpreter, no current directory on its path: ``-P``)."""
    return [sys.executable, "-P", "-c", "import sys; from train.cli import main; sys.exit(main())", *argv]


def environment() -> dict[str, str]:
    """The test process's environment without a ``PYTHONPATH`` that could name the directory."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
