"""Every weight file the package ships, by name: each one present, in the current format, of the
kind its name promises, trained for its task, with a sidecar, and usable by name.

The list is explicit on purpose: a deleted or renamed file fails here (a glob would quietly
test fewer files), and a file added without a line here fails too.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import gymnasium as gym
import pytest
import torch

import gnn_mp_envs  # noqa: F401
from agents.checkpoints import FORMAT_VERSION, SHIPPED_DIR, load_checkpoint, shipped_checkpoint

#: (sampler name, task) -> the checkpoint kind it must hold.
SHIPPED_SAMPLERS = {
    ("gnn", "maze2d"): "tree/gnn", ("gnn", "arm"): "tree/gnn", ("gnn", "pendulum"): "tree/gnn-scorer",
    ("cvae", "maze2d"): "tree/cvae", ("cvae", "pendulum"): "tree/cvae", ("cvae", "arm"): "tree/cvae",
    ("gnn-cvae", "maze2d"): "tree/gnn-cvae", ("gnn-cvae", "pendulum"): "tree/gnn-cvae",
    ("gnn-cvae", "arm"): "tree/gnn-cvae",
    ("rl-ppo", "maze2d"): "rl/sb3-ppo-pick", ("rl-ppo", "pendulum"): "rl/sb3-ppo-pick",
    ("rl-ppo", "arm"): "rl/sb3-ppo-pick", ("rl-ppo-torchrl", "arm"): "rl/torchrl-ppo-pick",
    ("rl-ppo-torchrl", "pendulum"): "rl/torchrl-ppo-pick",
    ("gnn", "panda-mbm"): "tree/gnn", ("cvae", "panda-mbm"): "tree/cvae",
    ("rl-ppo", "panda-mbm"): "rl/sb3-ppo-pick", ("gnn", "ur5-mbm"): "tree/gnn", ("gnn", "fetch-mbm"): "tree/gnn",
    ("cvae", "ur5-mbm"): "tree/cvae",
}
#: Critical-sample models (maze2d's fixed Halton graph; no task in the name).
SHIPPED_CRITICAL = {"gnn": "critical/gnn", "gat": "critical/gat", "gnn-cvae": "critical/gnn-cvae",
                    "cnn": "critical/cnn", "cvae": "critical/cvae"}


def test_the_list_is_the_directory():
    listed = {shipped_checkpoint(n, t).name for n, t in SHIPPED_SAMPLERS} | {
        shipped_checkpoint(f"critical_{m}").name for m in SHIPPED_CRITICAL}
    assert {p.name for p in SHIPPED_DIR.glob("*.pt")} == listed
    assert {p.name for p in SHIPPED_DIR.glob("*.json")} == {n.replace(".pt", ".json") for n in listed}


@pytest.mark.parametrize("name,task", sorted(SHIPPED_SAMPLERS), ids=lambda v: str(v))
def test_shipped_sampler_weights(name, task):
    from agents.registry import load_sampler
    path = shipped_checkpoint(name, task)
    raw = torch.load(path, weights_only=True, map_location="cpu")
    assert raw["format_version"] == FORMAT_VERSION and raw["kind"] == SHIPPED_SAMPLERS[name, task]
    _, record = load_checkpoint(path, expected_kind=raw["kind"])
    assert record["meta"]["task"] == task
    assert json.loads(path.with_suffix(".json").read_text())["task"] == task
    sampler = load_sampler(name, task=task, seed=0)
    assert set(record["meta"]["sampler"]) <= set(sampler.settings)
    env = gym.make(gnn_mp_envs.task_spec(task).env_id, copy_observations=False, max_nodes=50,
                   disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    for _ in range(5):
        action = sampler.act(obs)
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)
    env.close()


@pytest.mark.parametrize("model", sorted(SHIPPED_CRITICAL))
def test_shipped_critical_weights(model):
    path = shipped_checkpoint(f"critical_{model}")
    raw = torch.load(path, weights_only=True, map_location="cpu")
    assert raw["format_version"] == FORMAT_VERSION and raw["kind"] == SHIPPED_CRITICAL[model]
    _, record = load_checkpoint(path, expected_kind=SHIPPED_CRITICAL[model])
    sidecar = json.loads(path.with_suffix(".json").read_text())
    assert sidecar["model"] == model == record["meta"]["model"]
    assert sidecar["hparams"]["model"].items() <= record["ctor_args"].items()


def _stored_rates_table() -> dict[str, list[str]]:
    """docs/learned_samplers.md's table of the stored sampling rates: task -> its two cells (gnn; cvae, gnn-cvae)."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "learned_samplers.md").read_text()
    head = text.index("| task | gnn | cvae, gnn-cvae |")
    rows = {}
    for line in text[head:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def _stated_rates(cell: str) -> dict[str, float]:
    """The rates a cell of that table states: uniform share, goal share (fractions), samples a step (1 unstated)."""
    rates = {"uniform_mix": float(re.search(r"(\d+)% uniform", cell).group(1)) / 100,
             "samples_per_step": float(m.group(1)) if (m := re.search(r"(\d+) samples a step", cell)) else 1.0}
    if (m := re.search(r"(\d+)% goal", cell)):
        rates["goal_bias"] = float(m.group(1)) / 100
    return rates


def test_the_docs_table_of_stored_rates_is_the_sidecars():
    """docs/learned_samplers.md states every shipped learned sampler's uniform share and batch as its sidecar
    stores them (a batch tuning that writes new values fails here until the table follows)."""
    table = _stored_rates_table()
    tasks = sorted({task for (name, task) in SHIPPED_SAMPLERS if name in ("gnn", "cvae", "gnn-cvae")})
    assert sorted(table) == tasks
    for task, (gnn_cell, cvae_cell) in table.items():
        for name, cell in (("gnn", gnn_cell), ("cvae", cvae_cell), ("gnn-cvae", cvae_cell)):
            shipped = (name, task) in SHIPPED_SAMPLERS
            if not shipped:
                assert f"no {name}" in cell or cell == "none shipped", (task, name, cell)
                continue
            stored = json.loads(shipped_checkpoint(name, task).with_suffix(".json").read_text())["sampler"]
            for key, value in _stated_rates(cell).items():
                default = 1.0 if key == "samples_per_step" else 0.0
                assert float(stored.get(key, default)) == pytest.approx(value), (task, name, key, cell)
