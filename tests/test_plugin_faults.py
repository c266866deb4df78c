"""Plugin code that misbehaves costs one row and one line, never the other results: a sampler that
raises KeyError or calls sys.exit, a task whose path_valid answers NaN."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PLUGIN = """
import sys
import gnn_mp_envs
from agents.samplers import register_sampler
from agents.samplers.baselines import UniformSampler

VICTIM = float(gnn_mp_envs.make_task('maze2d').problem('test', 1).goal[0])

class Faulty(UniformSampler):
    def act(self, obs):
        if int(obs['num_nodes'][0]) > 3 and abs(float(obs['goal'][0]) - VICTIM) < 1e-6:
            if self.fault == 'exit':
                sys.exit('the plugin gave up')
            raise KeyError('no such key')
        return super().act(obs)

def factory(fault):
    def make(low, high, task=None, seed=None, **kw):
        sampler = Faulty(low, high, seed)
        sampler.fault = fault
        return sampler
    return make

register_sampler('keyerror', factory('key'))
register_sampler('exits', factory('exit'))
"""


@pytest.mark.parametrize("name,workers,fragment", [("keyerror", "1", "KeyError: 'no such key'"),
                                                   ("exits", "1", "SystemExit: the plugin gave up"),
                                                   ("keyerror", "2", "KeyError: 'no such key'")])
def test_a_plugin_sampler_raising_keyerror_or_systemexit_keeps_the_other_rows(tmp_path, name, workers, fragment):
    (tmp_path / "faulty_samplers.py").write_text(PLUGIN)
    out = tmp_path / "report.json"
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, "benchmark", "--import", "faulty_samplers", "--samplers",
                             f"uniform,{name}", "--problems", "3", "--workers", workers, "--no-progress", "--json",
                             str(out)], cwd=tmp_path, capture_output=True, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines == [f"wrote {out} (partial)", lines[-1]], lines
    assert f"sampler {name!r} on maze2d problem 1: {fragment}" in lines[-1]
    report = json.loads(out.read_text())
    assert report["partial"] is True and all(r["problem"] != 1 for r in report["runs"][name])
    if workers == "1":          # serial: everything before the failing row finished (in two workers, what had)
        assert len(report["runs"]["uniform"]) == 3 and [r["problem"] for r in report["runs"][name]] == [0]


def test_a_path_valid_answering_nan_is_not_a_valid_path(monkeypatch):
    """``bool(nan)`` is True: a task's re-check answering NaN (or None, or an array) must count invalid."""
    import numpy as np

    from gnn_mp_envs.tasks.maze2d import Maze2DProblem
    from train import benchmark as bm
    for answer in (float("nan"), None, np.array([True, False]), "yes"):
        monkeypatch.setattr(Maze2DProblem, "path_valid", lambda self, *a, answer=answer, **k: answer)
        record = bm.run_episode("maze2d", {}, "uniform", 0, 0)
        assert record["success"] and record["path_valid"] is False and record["path_valid_fine"] is False
    monkeypatch.setattr(Maze2DProblem, "path_valid", lambda self, *a, **k: np.bool_(True))
    record = bm.run_episode("maze2d", {}, "uniform", 0, 0)
    assert record["path_valid"] is True
    monkeypatch.setattr(Maze2DProblem, "path_valid", lambda self, *a, **k: {}["missing"])
    with pytest.raises(bm.BenchmarkError, match="path_valid on problem 0: KeyError"):
        bm.run_episode("maze2d", {}, "uniform", 0, 0)
