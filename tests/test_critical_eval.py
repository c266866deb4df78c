"""Shipped critical-sample checkpoints load and evaluate; planning returns valid paths."""

from pathlib import Path

import numpy as np
import pytest
import torch

from gnn_mp_envs.critical.dataset import DatasetConfig, generate_eval
from gnn_mp_envs.critical.halton import halton_graph
from gnn_mp_envs.critical.planning import compare_planners, path_is_valid, summarize
from train.critical import CHECKPOINT_DIR, MODELS, evaluate, load_model, predict

torch.set_num_threads(2)
TINY = DatasetConfig(seed=5, num_maps=2, pairs_per_map=1, eval_problems=3)


@pytest.fixture(scope="module")
def tiny_blob_set():
    return generate_eval(TINY, "blob", progress=False)


def test_planning_comparison_returns_valid_paths(tiny_blob_set):
    probs = tiny_blob_set
    g = halton_graph()
    results = []
    for i in range(len(probs)):
        labels = g.nodes[probs.labels_of(i)]
        res = compare_planners(probs.maze(i), probs.start[i], probs.goal[i], {"oracle": labels})
        assert res["dense"].success  # labels came from a dense-graph path
        for r in res.values():
            if r.success:
                assert path_is_valid(probs.maze(i), r.path)
                assert np.allclose(r.path[0], probs.start[i]) and np.allclose(r.path[-1], probs.goal[i])
                assert r.cost >= np.linalg.norm(probs.goal[i] - probs.start[i]) - 1e-9
        results.append(res)
    summary = summarize(results)
    assert summary["dense"]["success_rate"] == 1.0
    assert set(summary) == {"sparse", "dense", "oracle", "_common"}


@pytest.mark.parametrize("name", sorted(MODELS))
def test_shipped_checkpoint_predicts(name, tiny_blob_set):
    path = CHECKPOINT_DIR / f"critical_{name}.pt"     # shipped (tests/test_shipped.py lists every file)
    model, loaded, record = load_model(path, name)
    assert loaded == name and record["meta"]["model"] == name and record["kind"] == f"critical/{name}"
    point, samples = predict(model, name, tiny_blob_set, halton_graph(), num_samples=4)
    assert point.shape == (len(tiny_blob_set), 2) and np.isfinite(point).all()
    assert (samples is None) == (MODELS[name][2] == "det")
    assert path.stat().st_size < 3_000_000


def test_evaluate_end_to_end_on_a_few_problems(tmp_path):
    rep = evaluate(models=["gnn", "gnn-cvae"], data_dir=tmp_path, num_problems=2, num_samples=4,
                   json_path=tmp_path / "r.json", plot_path=tmp_path / "p.png",
                   dataset=TINY, progress=False)
    assert (tmp_path / "r.json").exists() and (tmp_path / "p.png").stat().st_size > 1000
    assert {"gnn point", "gnn k=10", "gnn-cvae point", "mean label"} <= set(rep["accuracy"]["blob"])
    assert "best_of_4_accuracy" in rep["accuracy"]["blob"]["gnn-cvae point"]
    assert rep["planning"]["test"]["dense"]["success_rate"] == 1.0
    assert {"sparse", "gnn point", "gnn k=1", "gnn k=3", "gnn k=10", "gnn-cvae k=10",
            "uniform random k=10", "oracle (labels)"} <= set(rep["planning"]["blob"])


# -----------------------------------------------------------------------------


def _bad_files():
    """critical_gnn.pt variants that must not be evaluated."""
    data = (CHECKPOINT_DIR / "critical_gnn.pt").read_bytes()
    return {
        "gat weights named gnn": (CHECKPOINT_DIR / "critical_gat.pt").read_bytes(),
        "truncated": data[: len(data) // 2],
        "empty": b"",
        "random bytes": np.random.default_rng(0).bytes(20_000),
    }


@pytest.mark.parametrize("case", ["gat weights named gnn", "truncated", "empty", "random bytes"])
def test_evaluate_refuses_bad_checkpoints_with_one_line_and_exit_2(tmp_path, case, capsys):
    from agents.checkpoints import CheckpointError
    from train.cli import main as gnn_mp
    from train.critical import main
    ckpts = tmp_path / "ckpts"
    ckpts.mkdir()
    path = ckpts / "critical_gnn.pt"
    path.write_bytes(_bad_files()[case])
    with pytest.raises(CheckpointError):
        evaluate(models=["gnn"], checkpoint_dir=ckpts, data_dir=tmp_path / "data", dataset=TINY, progress=False)
    argv = ["evaluate", "--models", "gnn", "--checkpoints", str(ckpts), "--data", str(tmp_path / "data"),
            "--json", str(tmp_path / "r.json"), "--no-progress"]
    for run in (lambda: main(argv), lambda: gnn_mp(["critical", *argv])):
        assert run() == 2
        out = capsys.readouterr()
        assert out.err.count("\n") == 1 and str(path) in out.err, out.err
        assert "Traceback" not in out.err and "| gnn |" not in out.out
        assert "[Errno" not in out.err
        if case == "gat weights named gnn":
            assert "'critical/gat'" in out.err and "'critical/gnn'" in out.err
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "data").exists()   # failed before any data


def test_python_dash_m_train_critical(tmp_path):
    """`python -m train.critical` works and exits 2 with one line on a bad checkpoint."""
    import subprocess
    import sys
    ckpts = tmp_path / "ckpts"
    ckpts.mkdir()
    (ckpts / "critical_cnn.pt").write_bytes(b"\0" * 100)
    root = Path(__file__).resolve().parent.parent
    ok = subprocess.run([sys.executable, "-m", "train.critical", "evaluate", "--help"], cwd=root,
                        capture_output=True, text=True)
    assert ok.returncode == 0 and "--checkpoints" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "train.critical", "evaluate", "--models", "cnn",
                          "--checkpoints", str(ckpts), "--data", str(tmp_path / "d")], cwd=root,
                         capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "critical_cnn.pt" in bad.stderr, bad.stderr


def test_evaluate_with_no_checkpoints_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    """An empty checkpoint directory: exit 2, one line naming it, before minutes of labelling."""
    from train.critical import main
    monkeypatch.chdir(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    code = main(["evaluate", "--checkpoints", str(empty)])
    err = capsys.readouterr().err
    assert code == 2 and f"no checkpoints in {empty}" in err and err.strip().count("\n") == 0
    assert [p.name for p in tmp_path.iterdir()] == ["empty"]          # nothing labelled, nothing written
