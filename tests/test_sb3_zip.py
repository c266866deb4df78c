"""An SB3 ``.zip`` of a ``gnn-mp train rl`` run is a checkpoint wherever one is taken, weights only:
the model rebuilt from the run's ``config.json``, never from the zip's pickled entries."""

from __future__ import annotations

import json
import shutil
import warnings
import zipfile

import pytest
import torch

from tests.helpers import armed

RUN = ["train", "rl", "--task", "maze2d", "--n-envs", "2", "--n-steps", "64", "--batch-size", "32",
       "--eval-problems", "1", "--eval-max-steps", "200", "--total-steps", "128", "--no-progress"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from train.cli import main
    out = tmp_path_factory.mktemp("sb3zip") / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(RUN + ["--out", str(out)]) == 0
    return out


def test_a_runs_zip_loads_as_the_policy_its_run_exported_without_unpickling(run_dir, tmp_path):
    """load_sampler(checkpoint=model.zip) gives the run's sampler: the same kind, constructor
    arguments, sampler settings and weights as the policy.pt written at the same step; a payload
    in the zip's data (live: SB3's own reader runs it) never runs."""
    from agents.checkpoints import load_checkpoint
    from agents.registry import load_sampler
    from stable_baselines3.common.save_util import json_to_data
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    zip_path, marker = copy / "model.zip", tmp_path / "payload-ran"
    armed(zip_path, marker)
    json_to_data(zipfile.ZipFile(zip_path).read("data").decode())      # the payload is live for SB3's reader
    assert marker.exists()
    marker.unlink()

    sampler = load_sampler("rl-ppo", "maze2d", checkpoint=zip_path, seed=0)
    assert type(sampler).__name__ == "PickSampler"
    _, from_zip = load_checkpoint(zip_path)
    _, exported = load_checkpoint(copy / "policy.pt")                  # the last evaluation: the same weights
    assert from_zip["kind"] == exported["kind"] == "rl/sb3-ppo-pick"
    assert from_zip["ctor_args"] == exported["ctor_args"] and from_zip["obs_spec"] == exported["obs_spec"]
    assert from_zip["meta"]["sampler"] == exported["meta"]["sampler"] and from_zip["meta"]["task"] == "maze2d"
    assert set(from_zip["state_dict"]) == set(exported["state_dict"])
    assert all(torch.equal(from_zip["state_dict"][k], v) for k, v in exported["state_dict"].items())
    assert load_sampler("rl-ppo", checkpoint=zip_path).view_nodes == 64     # the task read from the run
    assert not marker.exists()


def test_benchmark_takes_a_zip_and_refuses_one_without_its_config_or_of_another_task(run_dir, tmp_path, capsys):
    from train.cli import main
    out = tmp_path / "b.json"
    zip_path = run_dir / "best_model.zip"
    assert main(["benchmark", "--task", "maze2d", "--samplers", "rl-ppo", "--checkpoint", f"rl-ppo={zip_path}",
                 "--problems", "1", "--json", str(out), "--no-progress"]) == 0
    assert json.loads(out.read_text())
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(zip_path, lone / "model.zip")
    broken = tmp_path / "broken"
    shutil.copytree(run_dir, broken)
    (broken / "config.json").write_text("{not json")
    cases = [(["--task", "maze2d", "--checkpoint", f"rl-ppo={lone / 'model.zip'}"], "config.json"),
             (["--task", "maze2d", "--checkpoint", f"rl-ppo={broken / 'model.zip'}"], "unreadable"),
             (["--task", "pendulum", "--checkpoint", f"rl-ppo={zip_path}"], "trained for task 'maze2d'"),
             (["--task", "maze2d", "--samplers", "rl-sac", "--checkpoint", f"rl-sac={zip_path}"], "rl/sb3-ppo-pick")]
    for argv, fragment in cases:
        capsys.readouterr()
        samplers = [] if "--samplers" in argv else ["--samplers", "rl-ppo"]
        try:
            code = main(["benchmark", *samplers, *argv, "--problems", "1", "--no-progress"])
        except SystemExit as exit_:
            code = exit_.code
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and fragment in err[0], (argv, err)


def test_a_runs_zip_is_a_row_of_its_own_beside_the_shipped_one(run_dir, tmp_path):
    """--samplers rl-ppo,mine --checkpoint mine=RUN/best_model.zip (issue 51): the zip's kind names the
    sampler (rl-ppo), its row is the run's policy (the counters of --checkpoint rl-ppo=the zip), and the
    shipped rl-ppo row stays beside it."""
    from train.cli import main
    zip_path = run_dir / "best_model.zip"
    common = ["benchmark", "--task", "maze2d", "--problems", "2", "--seed", "0", "--no-progress"]
    assert main([*common, "--samplers", "rl-ppo,mine", "--checkpoint", f"mine={zip_path}",
                 "--json", str(tmp_path / "mine.json")]) == 0
    assert main([*common, "--samplers", "rl-ppo", "--checkpoint", f"rl-ppo={zip_path}",
                 "--json", str(tmp_path / "named.json")]) == 0
    assert main([*common, "--samplers", "rl-ppo", "--json", str(tmp_path / "shipped.json")]) == 0
    runs = {name: json.loads((tmp_path / f"{name}.json").read_text())["runs"] for name in ("mine", "named", "shipped")}
    keys = ("success", "nodes_expanded", "collision_checks")

    def counters(rows):
        return [{k: r[k] for k in keys} for r in rows]
    assert counters(runs["mine"]["mine"]) == counters(runs["named"]["rl-ppo"])
    assert counters(runs["mine"]["rl-ppo"]) == counters(runs["shipped"]["rl-ppo"])


def test_a_zip_member_holding_code_is_refused_in_one_line(run_dir, tmp_path):
    """The .pth members are read with torch.load(weights_only=True): a pickled global is refused."""
    from agents.checkpoints import CheckpointError, read_checkpoint
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    path = copy / "model.zip"
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    import io
    buffer = io.BytesIO()
    torch.save({"w": torch.zeros(1), "code": print}, buffer)
    members["policy.pth"] = buffer.getvalue()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    with pytest.raises(CheckpointError, match="refused") as info:
        read_checkpoint(path)
    assert "\n" not in str(info.value)
