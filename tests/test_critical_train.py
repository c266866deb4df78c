"""Critical training: run directories, checkpoints in the agents.checkpoints format, safe resume,
--ship."""

import json
import os
import shlex
import uuid
from pathlib import Path

import pytest
import torch

from agents.checkpoints import CheckpointError, SHIPPED_DIR, load_training_state
from gnn_mp_envs.critical.dataset import DatasetConfig, load_or_generate
from train.critical import TrainArgs, TrainError, load_model, main, run_paths, train

torch.set_num_threads(1)
TINY = DatasetConfig(seed=3, num_maps=10, pairs_per_map=1, eval_problems=2)   # 8 train maps, 1 val


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("data")
    load_or_generate(TINY, d, "labelled", progress=False)
    return d


def _args(data_dir, **kw):
    kw = {"model": "gnn", "data": data_dir, "hidden": 8, "batch_size": 4, "epochs": 1, **kw}
    return TrainArgs(**kw)


def _shipped_snapshot():
    return {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in SHIPPED_DIR.iterdir() if p.is_file()}


def test_default_output_is_a_run_directory_not_the_package(data_dir, tmp_path):
    before = _shipped_snapshot()
    res = train(_args(data_dir), dataset=TINY, progress=False, runs_dir=tmp_path / "runs")
    assert _shipped_snapshot() == before                  # nothing written into agents/checkpoints
    ckpt = Path(res["checkpoint"])
    run = ckpt.parent
    assert run.parent == tmp_path / "runs" and run.name.startswith("gnn-seed0-")
    assert sorted(p.name for p in run.iterdir()) == ["critical_gnn.json", "critical_gnn.pt",
                                                     "critical_gnn.resume.pt", "tb"]
    # TensorBoard events: the loss per step, the validation scores per epoch
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    events = EventAccumulator(str(run / "tb" / "critical_gnn")).Reload()
    steps = json.loads((run / "critical_gnn.json").read_text())["history"][0]["steps"]
    assert [e.step for e in events.Scalars("train/loss")] == list(range(1, steps + 1))
    assert [e.step for e in events.Scalars("val/val_score")] == [steps]
    config = json.loads((run / "critical_gnn.json").read_text())   # the config beside the weights
    assert config["args"]["hidden"] == 8 and config["hparams"]["model"]["hidden_channels"] == 8
    assert config["dataset"]["seed"] == TINY.seed and len(config["history"]) == 1
    model, name, record = load_model(ckpt, "gnn")
    assert name == "gnn" and model.hidden_channels == 8 and record["meta"]["best"]["epoch"] == 1
    torch.load(run / "critical_gnn.resume.pt", weights_only=True)   # resume state: weights_only too
    # a second run gets its own directory
    res2 = train(_args(data_dir), dataset=TINY, progress=False, runs_dir=tmp_path / "runs")
    assert Path(res2["checkpoint"]).parent != run


def test_resume_continues_exactly_and_uses_the_latest_run(data_dir, tmp_path):
    full = train(_args(data_dir, epochs=2, out=tmp_path / "full" / "critical_gnn.pt"), dataset=TINY,
                 progress=False)
    part = _args(data_dir, epochs=1, out=tmp_path / "part" / "critical_gnn.pt")
    train(part, dataset=TINY, progress=False)
    resumed = train(_args(data_dir, epochs=2, out=part.out, resume=True), dataset=TINY, progress=False)
    assert [h["val_accuracy"] for h in resumed["history"]] == [h["val_accuracy"] for h in full["history"]]
    a = load_training_state(tmp_path / "full" / "critical_gnn.resume.pt")["model"]
    b = load_training_state(tmp_path / "part" / "critical_gnn.resume.pt")["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    # without --out, --resume continues the latest run of this model and seed
    runs = tmp_path / "runs"
    first = train(_args(data_dir), dataset=TINY, progress=False, runs_dir=runs)
    assert run_paths(_args(data_dir, resume=True), runs).checkpoint == Path(first["checkpoint"])
    with pytest.raises(TrainError, match="no run of gnn with seed 5"):
        run_paths(_args(data_dir, resume=True, seed=5), runs)
    with pytest.raises(TrainError, match="exists"):                    # no silent overwrite
        train(_args(data_dir, out=part.out), dataset=TINY, progress=False)


def test_resume_state_is_loaded_weights_only(data_dir, tmp_path):
    """A resume file that would run code on load is refused."""
    marker = Path(f"/tmp/pwned_{uuid.uuid4().hex}")

    class Evil:
        def __reduce__(self):
            return os.system, (f"touch {shlex.quote(str(marker))}",)

    out = tmp_path / "critical_gnn.pt"
    torch.save({"format_version": 1, "training_state": {"epoch": Evil()}}, out.with_name("critical_gnn.resume.pt"))
    try:
        with pytest.raises(CheckpointError, match="refused"):
            train(_args(data_dir, out=out, resume=True), dataset=TINY, progress=False)
        assert not marker.exists()
    finally:
        marker.unlink(missing_ok=True)


def test_resume_of_another_configuration_is_refused(data_dir, tmp_path):
    out = tmp_path / "critical_gnn.pt"
    train(_args(data_dir, out=out), dataset=TINY, progress=False)
    with pytest.raises(CheckpointError, match="another run"):
        train(_args(data_dir, out=out, resume=True, hidden=16, epochs=2), dataset=TINY, progress=False)


def test_shipping_needs_the_flag(data_dir, tmp_path, monkeypatch):
    with pytest.raises(TrainError, match="--ship"):
        run_paths(_args(data_dir, out=SHIPPED_DIR / "critical_gnn.pt"))
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    (shipped / "critical_gnn.json").write_text('{"stale": "the sidecar of older weights"}\n')
    monkeypatch.setattr("agents.checkpoints.SHIPPED_DIR", shipped)
    res = train(_args(data_dir, out=tmp_path / "run" / "x.pt", ship=True), dataset=TINY, progress=False)
    assert res["shipped"] == str(shipped / "critical_gnn.pt")
    assert sorted(p.name for p in shipped.iterdir()) == ["critical_gnn.json", "critical_gnn.pt"]
    sidecar = json.loads((shipped / "critical_gnn.json").read_text())
    assert "stale" not in sidecar and sidecar == json.loads((tmp_path / "run" / "x.json").read_text())
    assert load_model(shipped / "critical_gnn.pt", "gnn")[1] == "gnn"


def test_cli_train_errors_are_one_line(data_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--model", "cnn", "--readout", "max", "--data", str(data_dir)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--readout" in err and "graph models" in err
    with pytest.raises(SystemExit) as info:
        main(["train"])
    assert info.value.code == 2 and "--model" in capsys.readouterr().err
    assert main(["train", "--model", "gnn", "--resume", "--data", str(data_dir)]) == 2
    assert "no run of gnn" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").rglob("*.pt"))


def test_node_level_training_max_steps_and_selection(data_dir, tmp_path):
    """The heat-map CNN trains on the label-node term; --max-steps bounds the work;
    the best epoch is chosen on the validation hit rate and CPU time is recorded."""
    res = train(_args(data_dir, model="cnn", hidden=4, batch_size=2, epochs=3, max_steps=3,
                      out=tmp_path / "cnn" / "critical_cnn.pt"), dataset=TINY, progress=False)
    steps = [h["steps"] for h in res["history"]]
    assert steps == [3]            # 8 training problems / batch 2 = 4 steps per epoch; stopped after 3
    h = res["history"][-1]
    assert {"val_accuracy", "val_hit@1", "val_hit@3", "val_hit@10", "val_score", "cpu_seconds"} <= set(h)
    assert res["best"]["val_score"] == max(x["val_score"] for x in res["history"])
    model, _, record = load_model(res["checkpoint"], "cnn")
    assert model.readout == "heatmap" and record["meta"]["hparams"]["node_target"] == "any"
    assert record["meta"]["hparams"]["max_steps"] == 3


def test_every_sub_command_takes_the_dataset_size_flags():
    """generate-data's --num-maps / --pairs-per-map / --eval-problems made a cache that train and
    evaluate did not use (they regenerated the full 4,800-problem set); the flags are now every
    sub-command's, and the same flags name the same dataset."""
    from train.critical.args import EvaluateArgs, GenerateArgs
    flags = {"data_seed": TINY.seed, "num_maps": TINY.num_maps, "pairs_per_map": TINY.pairs_per_map,
             "eval_problems": TINY.eval_problems}
    assert GenerateArgs(**flags).dataset() == TrainArgs(model="gnn", **flags).dataset() == \
        EvaluateArgs(**flags).dataset() == TINY
