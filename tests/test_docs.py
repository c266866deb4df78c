"""Every python block of every docs page (and the README) runs as written: the blocks of a page in
order, in one fresh interpreter started in an empty directory (so nothing depends on the repository
being the working directory). docs/samplers.md and docs/rl.md have tests of their own that also
check what their blocks print (tests/test_samplers.py, tests/test_rl.py)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
TESTED_ELSEWHERE = {"samplers.md", "rl.md"}


def python_blocks(path: Path) -> list[str]:
    return [textwrap.dedent(m.group(2)) for m in re.finditer(r"^( *)```python\n(.*?)^\1```", path.read_text(),
                                                            re.M | re.S)]


WITH_BLOCKS = [p for p in PAGES if python_blocks(p) and p.name not in TESTED_ELSEWHERE]


def test_the_pages_with_blocks_are_the_expected_ones():
    """An oracle for the block reader: pages known to hold python blocks are found (a reader that
    found none would make the test below vacuous)."""
    names = {p.name for p in PAGES if python_blocks(p)}
    assert {"README.md", "environments.md", "samplers.md", "rl.md", "adding_a_task.md"} <= names


@pytest.mark.parametrize("page", WITH_BLOCKS, ids=lambda p: p.name)
def test_page_blocks_run(page, tmp_path):
    script = tmp_path / f"{page.stem}.py"
    script.write_text("\n\n".join(python_blocks(page)))
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
