"""Every fenced block of every docs page (and the README) runs as written.

* Every fence names its language: ``python``, ``bash`` (commands) or ``text`` (output, layouts),
  so no command can hide in an unlabelled block.
* The python blocks of a page run in order, in one fresh interpreter started in an empty
  directory (nothing depends on the repository being the working directory) that holds only
  the page's own files (the ``# file: PATH`` blocks below, written there, not run). docs/samplers.md
  and docs/rl.md have tests of their own that also check what their blocks print
  (tests/test_samplers.py, tests/test_rl.py).
* The bash blocks of a page run in order, each with ``bash -e -o pipefail``, in a fresh copy of
  the repository (what a new user has after ``git clone``), with ``.venv/bin`` there pointing at
  the test's interpreter. A python block whose first line is ``# file: PATH`` is that file of the
  user's own (``my_pkg/disks.py``); it is written there first. The commands run with the budget
  flags of tests/docs_shim.py appended (docs/index.md, "How the docs are tested"), in processes
  forked from one preloaded interpreter (tests/docs_server.py).
* A benchmark table a page prints right after the ``gnn-mp benchmark`` command that makes it is
  what that command prints now, run as written without the budget, up to wall times.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
TESTED_ELSEWHERE = {"samplers.md", "rl.md"}
LANGUAGES = {"python", "bash", "text"}
FENCE = re.compile(r"^( *)```([^\n`]*)\n(.*?)^\1```", re.M | re.S)
FILE_LINE = re.compile(r"# file: (\S+)")


def blocks(path: Path) -> list[tuple[str, str]]:
    """``(language, code)`` of every fenced block, in order (indented blocks dedented)."""
    return [(m.group(2).strip(), textwrap.dedent(m.group(3))) for m in FENCE.finditer(path.read_text())]


def python_blocks(path: Path) -> list[str]:
    return [code for lang, code in blocks(path) if lang == "python"]


def shell_blocks(path: Path) -> list[str]:
    return [code for lang, code in blocks(path) if lang == "bash"]


def file_blocks(path: Path) -> dict[str, str]:
    """The user's own files a page shows: python blocks starting ``# file: PATH`` (concatenated)."""
    files: dict[str, str] = {}
    for code in python_blocks(path):
        match = FILE_LINE.match(code)
        if match:
            files[match.group(1)] = files.get(match.group(1), "") + code + "\n"
    return files


WITH_BLOCKS = [p for p in PAGES if python_blocks(p) and p.name not in TESTED_ELSEWHERE]
WITH_COMMANDS = [p for p in PAGES if shell_blocks(p)]


def test_every_fence_names_its_language():
    unnamed = [(p.name, code.splitlines()[0] if code.strip() else "") for p in PAGES for lang, code in blocks(p)
               if lang not in LANGUAGES]
    assert not unnamed, f"fences without python / bash / text: {unnamed}"


def test_the_pages_with_blocks_are_the_expected_ones():
    """An oracle for the block reader: pages known to hold python and bash blocks are found (a
    reader that found none would make the tests below vacuous)."""
    names = {p.name for p in PAGES if python_blocks(p)}
    assert {"README.md", "environments.md", "samplers.md", "rl.md", "adding_a_task.md"} <= names
    assert {"README.md", "quickstart.md", "rl.md", "critical.md", "adding_a_task.md", "learned_samplers.md",
            "results.md", "samplers.md"} <= {p.name for p in WITH_COMMANDS}
    assert set(file_blocks(ROOT / "docs" / "adding_a_task.md")) == {"my_pkg/disks.py", "my_pkg/my_maps.py"}
    assert sum(len(shell_blocks(p)) for p in PAGES) >= 15


def test_the_budget_table_of_the_docs_is_the_one_applied():
    """docs/index.md prints tests/docs_shim.py's BUDGET: the reader sees what the test changes."""
    from docs_shim import BUDGET
    rows = dict(re.findall(r"^\| `([^`]+)` \| `([^`]+)` \|$", (ROOT / "docs" / "index.md").read_text(), re.M))
    assert rows == {command: " ".join(flags) for command, flags in BUDGET.items()}


def test_the_budget_is_appended_to_the_commands_it_names():
    from docs_shim import budget
    assert budget(["gnn-mp", "benchmark", "--task", "arm", "--problems", "20"])[:2] == ["--problems", "2"]
    assert budget(["gnn-mp", "benchmark", "--workers", "2", "--suite", "default"]) == ["--suite", "smoke", "--workers", "1"]
    assert budget(["gnn-mp", "critical", "train", "--model", "gnn"])[-2:] == ["--batch-size", "2"]
    assert budget(["gnn-mp", "train", "rl", "--help"]) == [] and budget(["gnn-mp", "samplers"]) == []
    assert budget(["python", "-m", "pytest", "-q"]) == ["tests/test_architecture.py"]


@pytest.mark.parametrize("page", WITH_BLOCKS, ids=lambda p: p.name)
def test_page_blocks_run(page, tmp_path):
    """The page's python blocks in order, in one interpreter; the user's own files (``# file:
    PATH`` blocks) are written to the directory it starts in, not run, so a block that uses one
    imports it as the reader would (``import my_pkg.disks``)."""
    for name, code in file_blocks(page).items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(code)
    script = tmp_path / f"{page.stem}.py"
    script.write_text("\n\n".join(code for code in python_blocks(page) if not FILE_LINE.match(code)))
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]


# ---------------------------------------------------------------------------- the bash blocks
#: Not part of a fresh clone (when git cannot list the files, e.g. in an unpacked archive).
NOT_CLONED = {".git", ".venv", "runs", "results", "data", "__pycache__", ".pytest_cache", ".hypothesis"}


def fresh_clone(target: Path) -> Path:
    """The repository's files as ``git clone`` gives them (tracked and new, not ignored ones)."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                                capture_output=True, check=True).stdout.decode().split("\0")
    except (OSError, subprocess.CalledProcessError):
        listed = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
                  if not NOT_CLONED & set(p.relative_to(ROOT).parts)]
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target / name)
    copy_compiled_cache(target)
    return target


def copy_compiled_cache(target: Path) -> None:
    """The numba caches this checkout has compiled so far (``agents/tree/compiled.py``, ~45 s of
    compilation per fresh copy). numba keys a cache on the source's mtime and size, which ``copy2``
    keeps, so the copy loads them; a cache not yet written is compiled there as in a fresh clone."""
    for cache in [*ROOT.glob("agents/**/__pycache__/*.nb[ic]"), *ROOT.glob("gnn_mp_envs/**/__pycache__/*.nb[ic]")]:
        destination = target / cache.relative_to(ROOT)
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(cache, destination)


class DocsRunner:
    """The preloaded server, the package copy it imports (``--ship`` writes there), the shims."""

    def __init__(self, base: Path) -> None:
        self.package = fresh_clone(base / "package")
        self.bin = base / "bin"
        self.bin.mkdir()
        import tempfile
        self.socket = Path(tempfile.mkdtemp(prefix="gnnmp-docs-")) / "sock"   # short: AF_UNIX paths hold ~100 bytes
        shim = Path(__file__).with_name("docs_shim.py")
        for kind in ("gnn-mp", "python"):
            wrapper = self.bin / kind
            wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -S "{shim}" "{self.socket}" "{sys.executable}" '
                               f'{kind} "$@"\n')
            wrapper.chmod(0o755)
        self.log = open(base / "server.log", "w+")
        self.server = subprocess.Popen([sys.executable, str(Path(__file__).with_name("docs_server.py")),
                                        str(self.socket)], cwd=self.package, env=self.env(), stdout=subprocess.PIPE,
                                       stderr=self.log, text=True, start_new_session=True)
        if self.server.stdout.readline().strip() != "ready":
            self.log.seek(0)
            raise RuntimeError(f"the docs server did not start: {self.log.read()[-3000:]}")

    def env(self) -> dict[str, str]:
        return dict(os.environ, PYTHONPATH=str(self.package), PATH=f"{self.bin}{os.pathsep}{os.environ['PATH']}",
                    MPLBACKEND="Agg")

    def clone_for(self, page: Path, target: Path) -> Path:
        """A fresh clone with ``.venv/bin`` pointing at the shims (installed: ``make`` skips the
        install) and the page's own files written."""
        clone = fresh_clone(target)
        venv_bin = clone / ".venv" / "bin"
        venv_bin.mkdir(parents=True)
        for kind in ("gnn-mp", "python"):
            (venv_bin / kind).symlink_to(self.bin / kind)
        stamp = clone / ".venv" / ".installed"
        stamp.touch()
        os.utime(stamp, (time.time() + 60, time.time() + 60))      # newer than pyproject.toml
        for name, code in file_blocks(page).items():
            (clone / name).parent.mkdir(parents=True, exist_ok=True)
            (clone / name).write_text(code)
        return clone

    def restore_shipped(self) -> None:
        """Undo a page's ``--ship`` in the package copy the server imports (atomically per file: the
        other page running meanwhile may be loading one)."""
        shipped = self.package / "agents" / "checkpoints"
        for path in shipped.iterdir():
            if path.is_file() and not (ROOT / "agents" / "checkpoints" / path.name).is_file():
                path.unlink()
        for path in (ROOT / "agents" / "checkpoints").iterdir():
            if path.is_file() and path.read_bytes() != (shipped / path.name).read_bytes():
                shutil.copy2(path, shipped / (path.name + ".restoring"))
                os.replace(shipped / (path.name + ".restoring"), shipped / path.name)

    def run_page(self, page: Path, target: Path) -> str | None:
        """The page's bash blocks in order in a fresh clone; None, or what failed."""
        clone = self.clone_for(page, target)
        try:
            for code in shell_blocks(page):
                result = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=clone, env=self.env(),
                                        capture_output=True, text=True, timeout=1200)
                if result.returncode != 0:
                    return (f"{page.name}: this block failed (rc {result.returncode}):\n{code}\n"
                            f"--- stderr\n{result.stderr[-4000:]}\n--- stdout\n{result.stdout[-2000:]}")
            return None
        finally:
            self.restore_shipped()

    def start(self, pages: list[Path], base: Path, concurrent: int = 2) -> None:
        """Run the pages two at a time (the commands mostly use one core each)."""
        from concurrent.futures import ThreadPoolExecutor
        self.pool = ThreadPoolExecutor(concurrent)
        self.results = {page: self.pool.submit(self.run_page, page, base / page.stem) for page in pages}

    def close(self) -> None:
        if hasattr(self, "pool"):
            self.pool.shutdown(wait=True, cancel_futures=True)
        try:
            os.killpg(self.server.pid, 9)
        except ProcessLookupError:
            pass
        self.server.wait()
        self.log.close()
        shutil.rmtree(self.socket.parent, ignore_errors=True)


@pytest.fixture(scope="module")
def docs_runner(tmp_path_factory, request):
    """The server, running every selected page's commands (two pages at a time) from the start."""
    base = tmp_path_factory.mktemp("docs")
    runner = DocsRunner(base)
    selected = [item.callspec.params["page"] for item in request.session.items
                if getattr(item, "originalname", None) == "test_page_commands_run"]
    runner.start(selected, base)
    yield runner
    runner.close()


@pytest.mark.parametrize("page", WITH_COMMANDS, ids=lambda p: p.name)
def test_page_commands_run(page, docs_runner):
    """The page's bash blocks, in order, in a fresh clone, with the budget flags appended."""
    failure = docs_runner.results[page].result()
    assert failure is None, failure


def headings(page: Path) -> set[str]:
    """The anchors of a page's headings as the site makes them (Python-Markdown's ``toc`` slugs), and
    its ``{#id}`` attributes."""
    from markdown.extensions.toc import slugify
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    titles = [re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", m).replace("`", "")
              for m in re.findall(r"^#+\s+(.*?)\s*#*\s*$", text, re.M)]
    return {slugify(t, "-") for t in titles} | set(re.findall(r"\{\s*#([\w-]+)", text))


def broken_relative_links(pages: list[Path], root: Path = ROOT) -> list[str]:
    """Every relative link or image of ``pages`` that names no file of the repository, or an anchor
    (``page.md#part``, ``#part``) that its page has no heading for; not inside code blocks."""
    broken = []
    for page in pages:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
        for target in re.findall(r"\]\(\s*([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path) if path else page
            if not file.exists():
                broken.append(f"{page.relative_to(root)}: {target}")
            elif anchor and file.suffix == ".md" and anchor not in headings(file):
                broken.append(f"{page.relative_to(root)}: {target} (no such heading)")
    return broken


def test_every_relative_link_of_the_docs_names_a_file_that_exists():
    """README and every page under docs/ (generated results pages and the journal included): a
    relative link or image names a file of the repository, and a link's anchor a heading of its page
    (the README is not part of the site, whose build checks the pages' anchors too)."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    assert broken_relative_links(pages) == []


def test_a_broken_link_fails_the_link_check(tmp_path):
    """The check's oracle: a page with a missing file and a missing anchor beside good links."""
    page = tmp_path / "page.md"
    page.write_text("# Top part\n\n[a](#top-part) [b](#nowhere) [c](missing.md) [d](page.md#top-part)\n"
                    "```text\n[e](not-checked.md)\n```\n")
    assert broken_relative_links([page], tmp_path) == ["page.md: #nowhere (no such heading)", "page.md: missing.md"]


def test_the_journal_index_lists_every_journal_page():
    """docs/journal/index.md, the journal's one page in the site's navigation, links every page of the
    journal (a new page is added there)."""
    journal = ROOT / "docs" / "journal"
    listed = set(re.findall(r"\]\(([^)#\s]+\.md)\)", (journal / "index.md").read_text()))
    pages = {p.name for p in journal.glob("*.md")} - {"index.md"}
    assert pages - listed == set(), f"add these pages to docs/journal/index.md: {sorted(pages - listed)}"
    assert listed - pages == set()


# ---------------------------------------------------------------------------- printed tables
def printed_benchmark_tables() -> list[tuple[Path, str, str]]:
    """``(page, command, printed)``: every bash block of one ``gnn-mp benchmark`` command (no
    ``--suite``) whose next block is the table it prints (a ``text`` block starting with the
    table's title, ``<task> (GNNMP/...``)."""
    found = []
    for page in PAGES:
        fences = list(FENCE.finditer(page.read_text()))
        for command, output in zip(fences, fences[1:]):
            code = textwrap.dedent(command.group(3)).replace("\\\n", " ")
            if (command.group(2).strip() == "bash" and output.group(2).strip() == "text"
                    and re.match(r"\S+ \(GNNMP/", textwrap.dedent(output.group(3)))
                    and len(code.strip().splitlines()) == 1 and "gnn-mp benchmark" in code and "--suite" not in code):
                found.append((page, code.strip(), textwrap.dedent(output.group(3))))
    return found


def counters(table: str) -> list[str]:
    """A printed benchmark table without what varies with the machine: the title, each row's
    sampler, and the classical rows' success, nodes, edges, collision checks and path length (not
    wall times; a learned row's float math differs across CPU models, so only its name), and
    whether the re-check line found invalid paths."""
    lines = table.strip().splitlines()
    rows = [re.split(r"\s{2,}", line.strip())[:6] for line in lines[3:] if re.match(r"\S+\s+\d+%", line)]
    rows = [row if row[0] in ("uniform", "goal-bias") or row[0].startswith("ompl-") else row[:1] for row in rows]
    checks = [re.sub(r"[\d,]+", "N", line) for line in lines if line.startswith("returned paths")]
    return [lines[0], *map(" | ".join, rows), *checks]


def test_the_pages_print_their_benchmark_tables():
    assert {page.name for page, _, _ in printed_benchmark_tables()} >= {"adding_a_task.md", "ompl.md"}


@pytest.mark.parametrize("page, command, printed", printed_benchmark_tables(),
                         ids=lambda value: value.name if isinstance(value, Path) else "")
def test_a_printed_benchmark_table_is_what_its_command_prints(page, command, printed, tmp_path):
    """The table a page prints after a ``gnn-mp benchmark`` command is what the command prints
    now, run as written (no budget; the page's own files written first), up to wall times and the
    learned rows' counters, which can differ on another CPU model (docs/results.md)."""
    if "ompl-" in command:
        pytest.importorskip("ompl")
    for name, code in file_blocks(page).items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(code)
    words = command.split()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    while "=" in words[0]:
        words.pop(0)
    assert words[:2] == ["gnn-mp", "benchmark"], command
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, *words[1:]], cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert counters(printed) == counters(result.stdout), f"{page.name}: re-run `{command}` and paste its table"
