"""agents.checkpoints: one format for every model, loaded with weights_only=True only;
gnn_mp_envs.utils.io: atomic writes."""

import json
import os
import pickle
import re
import shlex
import stat
import threading
import uuid
from pathlib import Path

import pytest
import torch
from torch import nn

from agents.checkpoints import (FORMAT_VERSION, SHIPPED_DIR, CheckpointError, load_checkpoint,
                                load_training_state, model_kinds, read_checkpoint, register_model_kind,
                                save_checkpoint, save_training_state)
from agents.critical.models import MODELS, CriticalGAT, CriticalGNN, kind_of
from gnn_mp_envs.utils.io import atomic_path, atomic_write_bytes, atomic_write_text

torch.set_num_threads(1)
REPO = Path(__file__).resolve().parent.parent
SMALL = {"in_channels": 5, "hidden_channels": 8, "num_layers": 2}


def _small_gnn(seed=0):
    torch.manual_seed(seed)
    return CriticalGNN(**SMALL)


def _inputs(n=30):
    g = torch.Generator().manual_seed(1)
    x = torch.rand(n, 5, generator=g)
    ei = torch.randint(0, n, (2, 4 * n), generator=g)
    return x, ei


def _assert_one_line(exc: CheckpointError, path: Path):
    msg = str(exc)
    assert "\n" not in msg and str(path) in msg, msg
    assert "Traceback" not in msg and not re.search(r"\[Errno \d+\][^/]*$", msg)


# ----------------------------------------------------------------------------- round trip


def test_round_trip_is_weights_only_and_complete(tmp_path):
    model = _small_gnn()
    path = save_checkpoint(tmp_path / "m.pt", model, "critical/gnn", SMALL, meta={"note": "x", "n": 3})
    raw = torch.load(path, weights_only=True)          # plain types only
    assert set(raw) == {"format_version", "kind", "ctor_args", "obs_spec", "state_dict", "meta"}
    assert raw["format_version"] == FORMAT_VERSION and raw["kind"] == "critical/gnn"
    # the constructor's defaults are stored too, so changing a default later does not change the file
    assert raw["ctor_args"]["K"] == 3 and raw["ctor_args"]["centre"] == 0.5 and raw["ctor_args"]["hidden_channels"] == 8
    loaded, record = load_checkpoint(path, expected_kind="critical/gnn")
    assert isinstance(loaded, CriticalGNN) and not loaded.training
    assert record["meta"] == {"note": "x", "n": 3} and record["obs_spec"] is None
    x, ei = _inputs()
    with torch.no_grad():
        assert torch.equal(loaded(x, ei), model.eval()(x, ei))
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]     # no temporary file left


def test_save_accepts_a_state_dict_and_plain_values_only(tmp_path):
    import numpy as np
    model = _small_gnn()
    path = save_checkpoint(tmp_path / "s.pt", model.state_dict(), "critical/gnn", SMALL,
                           obs_spec={"node_features": np.int64(13)}, meta={"path": Path("a/b"), "acc": np.float32(0.5)})
    _, record = load_checkpoint(path)
    assert record["obs_spec"] == {"node_features": 13} and record["meta"] == {"path": "a/b", "acc": 0.5}
    with pytest.raises(TypeError, match="meta"):
        save_checkpoint(tmp_path / "bad.pt", model, "critical/gnn", SMALL, meta={"f": lambda: 0})
    with pytest.raises(TypeError, match="not a critical/gat"):
        save_checkpoint(tmp_path / "bad.pt", model, "critical/gat", SMALL)
    with pytest.raises(TypeError, match="constructor arguments"):
        save_checkpoint(tmp_path / "bad.pt", model, "critical/gnn", {**SMALL, "nonsense": 1})
    with pytest.raises(ValueError, match="unknown model kind"):
        save_checkpoint(tmp_path / "bad.pt", model, "no/such-kind", SMALL)
    assert not (tmp_path / "bad.pt").exists()


def test_registry_builds_any_registered_kind(tmp_path):
    class Tiny(nn.Module):
        def __init__(self, width: int = 3):
            super().__init__()
            self.lin = nn.Linear(width, 1)

    kind = f"test/tiny-{uuid.uuid4().hex[:6]}"
    register_model_kind(kind, Tiny)
    assert kind in model_kinds() and all(kind_of(n) in model_kinds() for n in MODELS)
    register_model_kind(kind, Tiny)                       # same class again: fine
    with pytest.raises(ValueError, match="already registered"):
        register_model_kind(kind, CriticalGNN)
    path = save_checkpoint(tmp_path / "t.pt", Tiny(4), kind, {"width": 4}, obs_spec={"state_dim": 6})
    model, record = load_checkpoint(path, kind)
    assert model.lin.in_features == 4 and record["obs_spec"] == {"state_dim": 6}


def test_training_state_round_trip_with_optimizer(tmp_path):
    model = _small_gnn()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    x, ei = _inputs()
    model(x, ei).sum().backward()
    opt.step()
    path = save_training_state(tmp_path / "r.pt", {"model": model.state_dict(), "optimizer": opt.state_dict(),
                                                    "epoch": 3, "history": [{"loss": 0.5}], "best_state": None})
    torch.load(path, weights_only=True)
    state = load_training_state(path)
    opt2 = torch.optim.Adam(_small_gnn(1).parameters(), lr=1e-3)
    opt2.load_state_dict(state["optimizer"])
    assert state["epoch"] == 3 and state["history"] == [{"loss": 0.5}]
    with pytest.raises(CheckpointError, match="not a training state"):
        load_training_state(save_checkpoint(tmp_path / "c.pt", model, "critical/gnn", SMALL))


# ----------------------------------------------------------------------------- refusals


def _torch_file(path, obj):
    torch.save(obj, path)
    return path


def _good_record(tmp_path):
    return torch.load(save_checkpoint(tmp_path / "good.pt", _small_gnn(), "critical/gnn", SMALL), weights_only=True)


BAD_FILES = {
    "missing": lambda d, good: d / "nope.pt",
    "empty": lambda d, good: _write(d / "e.pt", b""),
    "truncated": lambda d, good: _write(d / "t.pt", (d / "good.pt").read_bytes()[:3000]),
    "random bytes": lambda d, good: _write(d / "r.pt", os.urandom(4096)),
    "zeros": lambda d, good: _write(d / "z.pt", bytes(4096)),
    "a directory": lambda d, good: _mkdir(d / "dir.pt"),
    "plain tensor": lambda d, good: _torch_file(d / "p.pt", torch.zeros(3)),
    "no format version": lambda d, good: _torch_file(d / "v.pt", {k: v for k, v in good.items() if k != "format_version"}),
    "missing keys": lambda d, good: _torch_file(d / "k.pt", {"format_version": 1, "kind": "critical/gnn"}),
    "newer format": lambda d, good: _torch_file(d / "n.pt", {**good, "format_version": FORMAT_VERSION + 1}),
    "bad format": lambda d, good: _torch_file(d / "b.pt", {**good, "format_version": "1"}),
    "unknown kind": lambda d, good: _torch_file(d / "u.pt", {**good, "kind": "critical/transformer"}),
    "weights do not fit": lambda d, good: _torch_file(d / "w.pt", {**good, "ctor_args": {**good["ctor_args"],
                                                                                           "hidden_channels": 16}}),
    "missing weights": lambda d, good: _torch_file(d / "m.pt", {**good, "state_dict": {}}),
    "non-tensor weights": lambda d, good: _torch_file(d / "x.pt", {**good, "state_dict": {
        k: 1 for k in good["state_dict"]}}),
    "ctor args do not fit": lambda d, good: _torch_file(d / "c.pt", {**good, "ctor_args": {"bogus": 1}}),
    "old format": lambda d, good: _torch_file(d / "o.pt", {"model": "gnn", "hparams": {"model": SMALL},
                                                           "state_dict": good["state_dict"], "meta": {}}),
}
EXPECTED = {"missing": "no such checkpoint", "empty": "empty", "truncated": "truncated", "random bytes": "not a",
            "zeros": "not a", "a directory": "directory", "plain tensor": "not a checkpoint",
            "no format version": "no format_version", "missing keys": "missing keys",
            "newer format": "newer", "bad format": "unknown format version", "unknown kind": "unknown model kind",
            "weights do not fit": "shape mismatch", "missing weights": "missing",
            "non-tensor weights": "shape mismatch", "ctor args do not fit":
            "constructor arguments", "old format": "old-format"}


def _write(path, data):
    path.write_bytes(data)
    return path


def _mkdir(path):
    path.mkdir()
    return path


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_unusable_files_are_refused_with_one_line_naming_the_file(tmp_path, case):
    good = _good_record(tmp_path)
    path = BAD_FILES[case](tmp_path, good)
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(path)
    _assert_one_line(info.value, path)
    assert EXPECTED[case] in str(info.value), str(info.value)
    assert isinstance(info.value, ValueError)


def test_another_kind_than_expected_names_the_file_and_both_kinds(tmp_path):
    torch.manual_seed(0)
    path = save_checkpoint(tmp_path / "critical_gnn.pt", CriticalGAT(**SMALL), "critical/gat", SMALL)
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(path, expected_kind="critical/gnn")
    _assert_one_line(info.value, path)
    assert "'critical/gat'" in str(info.value) and "'critical/gnn'" in str(info.value)
    assert read_checkpoint(path, ["critical/gnn", "critical/gat"])["kind"] == "critical/gat"


def _evil(cmd):
    class Evil:
        def __reduce__(self):
            return os.system, (cmd,)
    return Evil()


def test_a_checkpoint_that_would_run_code_is_refused_and_runs_nothing(tmp_path):
    marker = Path(f"/tmp/pwned_{uuid.uuid4().hex}")
    cmd = f"touch {shlex.quote(str(marker))}"
    # the payload is live: plain pickle would run it
    probe = tmp_path / "probe"
    pickle.loads(pickle.dumps(_evil(f"touch {shlex.quote(str(probe))}")))
    assert probe.exists()
    good = _good_record(tmp_path)
    files = {
        "torch.save, evil meta": _torch_file(tmp_path / "a.pt", {**good, "meta": {"x": _evil(cmd)}}),
        "torch.save, evil top level": _torch_file(tmp_path / "b.pt", _evil(cmd)),
        "raw pickle": _write(tmp_path / "c.pt", pickle.dumps(_evil(cmd), protocol=2)),
    }
    try:
        for name, path in files.items():
            for load in (load_checkpoint, load_training_state):
                with pytest.raises(CheckpointError) as info:
                    load(path)
                _assert_one_line(info.value, path)
                assert not marker.exists(), f"{name}: loading ran code"
    finally:
        marker.unlink(missing_ok=True)


def test_no_unsafe_torch_load_in_the_sources():
    """``weights_only=False`` nowhere in the packages."""
    offenders = []
    for package in ("agents", "train", "gnn_mp_envs"):
        for path in (REPO / package).rglob("*.py"):
            text = path.read_text()
            if re.search(r"weights_only\s*=\s*False", text) or "pickle.load(" in text:
                offenders.append(str(path.relative_to(REPO)))
    assert offenders == []


# ----------------------------------------------------------------------------- shipped files


# The shipped files themselves: tests/test_shipped.py (an explicit list).


# ----------------------------------------------------------------------------- atomic writes


def test_atomic_path_renames_on_success_and_cleans_up_on_failure(tmp_path):
    target = tmp_path / "sub" / "out.png"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp.name.endswith(".png") and tmp != target
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new"
    mode = stat.S_IMODE(target.stat().st_mode)
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o666 & ~umask                           # not mkstemp's 0600
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("writer crashed")
    assert target.read_bytes() == b"new"                   # old content intact
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.png"]
    atomic_write_text(tmp_path / "t.json", "{}")
    assert (tmp_path / "t.json").read_text() == "{}"


def test_atomic_path_names_are_unique_per_writer(tmp_path):
    target = tmp_path / "x.bin"
    with atomic_path(target) as a, atomic_path(target) as b:
        assert a != b
        a.write_bytes(b"a")
        b.write_bytes(b"b")
    assert target.read_bytes() == b"a"                     # the last rename wins, whole

    errors = []

    def writer(k):
        try:
            for _ in range(30):
                atomic_write_bytes(target, bytes([k]) * 10_000)
        except Exception as exc:   # noqa: BLE001 - collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    data = target.read_bytes()
    assert errors == [] and len(data) == 10_000 and len(set(data)) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["x.bin"]


def test_io_errors_name_the_target_file(tmp_path):
    target = tmp_path / "missing-dir" / "m.pt"
    with pytest.raises(FileNotFoundError) as info:
        with atomic_path(target, mkdir=False):
            pass
    assert info.value.filename == str(target)
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OSError) as info:
        save_checkpoint(blocker / "m.pt", _small_gnn(), "critical/gnn", SMALL)
    assert str(blocker / "m.pt") in str(info.value)


def test_a_failed_write_is_an_os_error_naming_the_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    """Disk full during torch.save (torch raises RuntimeError from its stream writer): one OSError
    naming the checkpoint, which the CLIs print as one line; the earlier file stays whole."""
    path = tmp_path / "model.pt"
    model = _small_gnn()
    save_checkpoint(path, model, "critical/gnn", SMALL)
    before = path.read_bytes()

    def full_disk(*args, **kwargs):
        raise RuntimeError("[enforce fail at inline_container.cc:603] . PytorchStreamWriter failed writing file "
                           "data/0: file write failed")
    monkeypatch.setattr(torch, "save", full_disk)
    for write in (lambda: save_checkpoint(path, model, "critical/gnn", SMALL),
                  lambda: save_training_state(path, {"step": 1})):
        with pytest.raises(OSError) as exc:
            write()
        assert exc.value.filename == str(path) and "file write failed" in exc.value.strerror
        assert "\n" not in f"{exc.value.strerror}: {exc.value.filename}"
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]      # no temporary file left


def test_a_crafted_size_is_refused_before_the_model_is_allocated(tmp_path):
    """A checkpoint whose constructor arguments were edited to a huge width:
    the weights are checked against a skeleton on the meta device, so the refusal comes before
    the real model (gigabytes at 4096) is ever built."""
    devices = []

    class Probe(nn.Module):
        def __init__(self, width: int = 4) -> None:
            super().__init__()
            devices.append(torch.empty(0).device.type)
            self.lin = nn.Linear(width, width)

    register_model_kind("test/probe", Probe, overwrite=True)
    path = save_checkpoint(tmp_path / "p.pt", Probe(4), "test/probe", {"width": 4})
    record = torch.load(path, weights_only=True)
    record["ctor_args"]["width"] = 4096
    torch.save(record, path)
    devices.clear()
    with pytest.raises(CheckpointError, match="shape mismatch"):
        load_checkpoint(path)
    assert devices == ["meta"]
    save_checkpoint(path, Probe(4), "test/probe", {"width": 4})
    devices.clear()
    model, _ = load_checkpoint(path)                      # a good file: the skeleton, then the model
    assert devices == ["meta", "cpu"] and model.lin.weight.device.type == "cpu"
