"""The one numba convention (``gnn_mp_envs.utils.compiled``): its on-disk cache never stops the package.
A damaged cache file (an interrupted write) is dropped and rewritten, and where no folder for the cache
is writable the code compiles anyway; each said in one line. Run in fresh processes, as a user meets them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

MODULE = "from gnn_mp_envs.utils.compiled import jit\n\n\n@jit\ndef plus_one(x):\n    return x + 1\n"
CALL = "import compiled_probe; print(compiled_probe.plus_one(41))"


def _run(folder: Path, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", CALL], cwd=folder, capture_output=True, text=True, timeout=300,
                          env={**os.environ, **env})


@pytest.fixture
def probe(tmp_path: Path) -> Path:
    (tmp_path / "compiled_probe.py").write_text(MODULE)
    return tmp_path


def test_a_damaged_cache_is_said_in_one_line_and_rewritten(probe: Path):
    first = _run(probe)
    assert first.returncode == 0 and first.stdout == "42\n" and first.stderr == ""
    files = sorted((probe / "__pycache__").glob("compiled_probe.plus_one-*.nb*"))
    assert {f.suffix for f in files} == {".nbi", ".nbc"}
    for f in files:                                    # an interrupted write: both files cut in half
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    damaged = _run(probe)
    assert damaged.returncode == 0 and damaged.stdout == "42\n"
    assert len(damaged.stderr.splitlines()) == 1 and "damaged" in damaged.stderr, damaged.stderr
    again = _run(probe)                                # the cache was written anew: nothing to say
    assert again.returncode == 0 and again.stdout == "42\n" and again.stderr == ""


def test_without_a_writable_cache_folder_the_code_still_compiles(probe: Path, tmp_path: Path):
    """numba finds no place of its own (its locators limited to ones that cannot serve this file): the
    cache moves to a folder of the temporary directory; with no place at all, nothing is cached."""
    temp = tmp_path / "tmp"
    temp.mkdir()
    moved = _run(probe, TMPDIR=str(temp), NUMBA_CACHE_LOCATOR_CLASSES="ZipCacheLocator,UserProvidedCacheLocator")
    assert moved.returncode == 0 and moved.stdout == "42\n"
    assert len(moved.stderr.splitlines()) == 1 and "goes to" in moved.stderr, moved.stderr
    assert list(temp.glob("gnn-mp-envs-numba-*/*/compiled_probe.plus_one-*.nbi"))
    assert not list(probe.glob("__pycache__/*.nbi"))
    nowhere = _run(probe, NUMBA_CACHE_LOCATOR_CLASSES="ZipCacheLocator")
    assert nowhere.returncode == 0 and nowhere.stdout == "42\n"
    assert len(nowhere.stderr.splitlines()) == 1 and "rebuilt in every process" in nowhere.stderr, nowhere.stderr


def test_a_cached_function_is_used_only_while_the_package_sources_are_unchanged(probe: Path):
    """numba alone checks the function's own file; the project's stamp covers every package source, so a
    change to a compiled function called from another module cannot leave a stale cache in use."""
    stats = ("print(compiled_probe.plus_one(41), compiled_probe.plus_one.stats.cache_hits,"
             " compiled_probe.plus_one.stats.cache_misses)")
    code = "import compiled_probe\n" + stats
    changed = ("import gnn_mp_envs.utils.compiled as c\nc.sources_stamp = lambda: 'another source tree'\n"
               "import compiled_probe\n" + stats)

    def run(text: str) -> str:
        out = subprocess.run([sys.executable, "-c", text], cwd=probe, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0 and out.stderr == "", out.stderr
        return out.stdout.strip()

    run(code)                                        # compiled and cached
    assert run(code).startswith("42 Counter({(int64,): 1})")              # a cache hit
    assert run(changed).split(" Counter")[1:] == ["()", "({(int64,): 1})"]   # another stamp: no hit, compiled again


def test_a_tables_describers_are_loaded_from_the_cache_in_a_fresh_process(tmp_path: Path):
    """A table of addresses is written by compiled functions generated from its groups' specs
    (``gnn_mp_envs.utils.array_groups``); the next process loads them from numba's cache, silently (a
    generated function's cache entry must find its module again, or it reads as damaged every time)."""
    code = ("import numpy as np\nfrom gnn_mp_envs.utils.array_groups import GroupTable, array_group\n"
            "G = array_group('G', (('a', np.float64, 2), ('b', np.int64, 1)))\n"
            "layout = GroupTable('probe', (G,))\n"
            "a, b = np.zeros((3, 2)), np.arange(5)\n"
            "table = layout.pack((G(a, b),))\n"
            "print(table[0, 0, 0] == a.ctypes.data, table[0, 0, 1:3].tolist(), table[0, 1, 0] == b.ctypes.data,"
            " table[0, 1, 1], sum(layout.whole_describer.stats.cache_hits.values()))")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def run() -> str:
        out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                             env=env)
        assert out.returncode == 0 and out.stderr == "", out.stderr
        return out.stdout.strip()

    assert run() == "True [3, 2] True 5 0"                           # compiled and cached
    assert run() == "True [3, 2] True 5 1"                           # loaded


def test_a_table_packed_in_one_call_is_the_table_the_checked_pack_writes():
    """``GroupTable.pack`` writes the whole table in one compiled call for arrays of exactly the specs' types;
    any other array takes the checked path: a read-only array is packed the same, a strided one or one of
    another dtype is refused in one line naming the field."""
    import numpy as np

    from gnn_mp_envs.utils.array_groups import GroupTable, array_group
    first = array_group("First", (("a", np.float64, 2), ("b", np.int64, 1)))
    second = array_group("Second", (("c", np.bool_, 1),))
    layout = GroupTable("probe_whole", (first, second))
    a, b, c = np.zeros((3, 2)), np.arange(5), np.ones(4, dtype=np.bool_)
    table = layout.pack((first(a, b), second(c)))
    assert table.shape == (2, 2, 4)
    np.testing.assert_array_equal(table, layout._checked_pack((first(a, b), second(c))))
    assert table[0, 0, 0] == a.ctypes.data and table[0, 0, 1:3].tolist() == [3, 2] and table[1, 0, 1] == 4
    assert layout.whole_describer.signatures and not layout.whole_describer._can_compile   # one signature only
    a.setflags(write=False)
    np.testing.assert_array_equal(layout.pack((first(a, b), second(c))), table)
    with pytest.raises(TypeError, match="First.b must be a C-contiguous 1-D int64 array"):
        layout.pack((first(a, np.arange(10)[::2]), second(c)))
    with pytest.raises(TypeError, match="Second.c must be a C-contiguous 1-D bool array"):
        layout.pack((first(a, b), second(c.astype(np.int8))))
    with pytest.raises(TypeError, match="group 1 must be a Second"):
        layout.pack((first(a, b), first(a, b)))
