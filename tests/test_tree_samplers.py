"""Learned tree samplers: exact incremental inference, a tiny training run end to end, reloads."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

from agents.checkpoints import load_checkpoint, save_checkpoint
from agents.nn.causal import causal_knn
from agents.tree.models import TreeGNN
from agents.samplers import load_sampler
from agents.tree.engine import IncrementalTreeGNN
from gnn_mp_envs.rollout import rollout
from tests.helpers import uniform_policy
from train.tree.adapters import adapter_for, task_scales
from train.tree.data import TreeDataConfig, generate
from train.tree.training import evaluate_loss, fit


def reference_embeddings(model: TreeGNN, obs) -> torch.Tensor:
    """The torch model's node embeddings of one padded observation."""
    n = int(np.asarray(obs["num_nodes"]).reshape(-1)[0])
    d = model.state_dim
    nodes = torch.as_tensor(np.asarray(obs["nodes"][:n])).to(model.state_scale.dtype)
    feats = torch.as_tensor(np.asarray(obs["node_features"][:n])).to(model.state_scale.dtype)
    tid = feats[:, 2 * d].long()
    parent = torch.as_tensor(np.asarray(obs["parent"][:n])).long()
    knn = causal_knn(nodes, tid, model.knn, model.step_scale, model.periodic)
    with torch.no_grad():
        return model.embed(nodes, feats, parent, knn)


def grown_observation(env_id: str, steps: int, **kwargs):
    env = gym.make(env_id, split="val", copy_observations=False, disable_env_checker=True, **kwargs)
    obs, _ = env.reset(seed=0, options={"index": 0})
    policy = uniform_policy(env, 0)
    snapshots = []
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(policy(obs))
        snapshots.append({k: np.array(v) for k, v in obs.items()})
        if terminated or truncated:
            break
    return env, snapshots


@pytest.mark.parametrize("env_id,periodic,trees", [("GNNMP/PendulumRRT-v0", (0,), 1), ("GNNMP/Maze2DBiRRT-v0", (), 2)])
def test_incremental_inference_equals_the_model(env_id, periodic, trees):
    """Embedding each new node once from cached older nodes gives the full forward pass's
    result (the GNN is causal), including duplicate states (ties go to the earlier node)."""
    env, snapshots = grown_observation(env_id, 250)
    low, high = env.action_space.low, env.action_space.high
    torch.manual_seed(0)
    model = TreeGNN(len(low), periodic=periodic, num_trees=trees, state_center=(low + high) / 2,
                    state_scale=(high - low) / 2, step_scale=np.full(len(low), 0.3)).double()
    engine = IncrementalTreeGNN(model, capacity=8)      # also exercises growing the caches
    for obs in snapshots[::7] + [snapshots[-1]]:
        engine.ingest(obs)
    reference = reference_embeddings(model, snapshots[-1])
    with torch.no_grad():
        keys = model.key(reference).numpy()
    assert engine.n == int(snapshots[-1]["num_nodes"][0]) > 50
    np.testing.assert_allclose(engine.keys[:engine.n], keys, atol=1e-6)
    counts = np.bincount(snapshots[-1]["node_features"][:engine.n, -1].astype(int), minlength=trees)
    np.testing.assert_array_equal(engine.counts, counts)


def test_causal_knn_only_looks_back_within_a_tree():
    nodes = torch.tensor([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.1, 0.0], [0.2, 0.0]])
    tree_id = torch.tensor([0, 1, 0, 0, 1])
    knn = causal_knn(nodes, tree_id, 2, torch.ones(2), torch.zeros(2, dtype=torch.bool))
    assert knn.tolist() == [[-1, -1], [-1, -1], [0, -1], [0, 2], [1, -1]]


@pytest.mark.parametrize("model", ["gnn", "cvae", "gnn-cvae"])
def test_a_briefly_trained_sampler_plans_and_reloads_identically(model, tmp_path):
    data = generate(TreeDataConfig(task="maze2d", problems=6, max_nodes=1500), progress=False)
    env = gym.make("GNNMP/Maze2DRRT-v0", split="val", max_nodes=1500, copy_observations=False,
                   disable_env_checker=True)
    adapter = adapter_for(model, "maze2d")
    net, ctor_args = adapter.build(task_scales("maze2d"))
    items = adapter.items(net, data, "grown", np.random.default_rng(0), 16)
    before = evaluate_loss(net, adapter, items)
    fit(net, adapter, items, items, minutes=0.05, lr=3e-3, batch_size=4, seed=0, writer=None, phase="t",
        progress=False)
    assert evaluate_loss(net, adapter, items) < before            # it learned something
    path = save_checkpoint(tmp_path / "m.pt", net, adapter.kind, ctor_args,
                           meta={"task": "maze2d", "sampler": {"uniform_mix": 0.3}})
    low, high = env.action_space.low, env.action_space.high
    runs = []
    for _ in range(2):
        sampler = load_sampler(model, task="maze2d", seed=5, checkpoint=str(path))
        assert sampler.uniform_mix == 0.3
        actions = []
        record = rollout(env, lambda obs: actions.append(sampler.act(obs)) or actions[-1], seed=5,
                         options={"index": 1})
        runs.append((record.success, record.nodes_expanded, np.array(actions)))
    assert runs[0][:2] == runs[1][:2]                         # same outcome and tree size ...
    np.testing.assert_array_equal(runs[0][2], runs[1][2])     # ... from the same proposals
    assert load_checkpoint(path)[1]["kind"] == adapter.kind


def test_a_checkpoint_for_another_task_is_refused(tmp_path):
    env = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=50)
    adapter = adapter_for("gnn", "maze2d")
    net, ctor_args = adapter.build(task_scales("maze2d"))
    path = save_checkpoint(tmp_path / "m.pt", net, adapter.kind, ctor_args, meta={"task": "maze2d"})
    with pytest.raises(ValueError, match="trained for task 'maze2d'"):
        load_sampler("gnn", task="arm", checkpoint=str(path))


def test_training_resumes_from_its_state(tmp_path):
    from agents.checkpoints import load_training_state
    data = generate(TreeDataConfig(task="maze2d", problems=4, max_nodes=1500), progress=False)
    env = gym.make("GNNMP/Maze2DRRT-v0", max_nodes=50)
    adapter = adapter_for("gnn", "maze2d")
    net, _ = adapter.build(task_scales("maze2d"))
    items = adapter.items(net, data, "grown", np.random.default_rng(0), 8)
    state_path = tmp_path / "resume.pt"
    first = fit(net, adapter, items, items, minutes=0.02, lr=1e-3, batch_size=2, seed=0, writer=None, phase="a",
                progress=False, resume_path=state_path)
    state = load_training_state(state_path)
    assert state["epoch"] == first["epochs"] == len(state["history"])
    fresh, _ = adapter.build(task_scales("maze2d"))
    second = fit(fresh, adapter, items, items, minutes=0.3, lr=1e-3, batch_size=2, seed=0, writer=None, phase="b",
                 progress=False, resume=state)
    assert second["epochs"] > first["epochs"]
    # compared as text: an epoch whose time ran out before its first batch has a NaN training loss,
    # and NaN != NaN (the full suite under load failed the plain == once)
    assert json.dumps(second["history"][:first["epochs"]]) == json.dumps(first["history"])


def test_resume_refuses_the_state_of_another_run_in_one_line(tmp_path, capsys):
    """`train sampler --resume`: another model's state was a traceback, another
    --lr / --batch-size / --seed resumed silently; each is refused in one line naming the flag (rc 2),
    and the same flags resume."""
    from train.tree.cli import main
    base = ["--task", "maze2d", "--model", "gnn", "--problems", "4", "--minutes", "0.005", "--dagger-rounds", "0",
            "--eval-problems", "0", "--out", str(tmp_path / "run"), "--data-dir", str(tmp_path / "data"),
            "--no-progress"]
    assert main(base) == 0 and (tmp_path / "run" / "resume.pt").exists()
    capsys.readouterr()
    for change, named in [(["--model", "cvae"], "model"), (["--lr", "0.001"], "lr"), (["--batch-size", "4"],
                          "batch_size"), (["--seed", "1"], "seed"), (["--task", "pendulum"], "task")]:
        assert main(base + change + ["--resume"]) == 2, change
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "another run" in err[0] and f"({named} " in err[0], err
    assert main(base + ["--resume"]) == 0


def test_train_sampler_hidden_sets_the_width_and_is_recorded(tmp_path):
    """`--hidden` builds the model at that width, the checkpoint holds it and the recorded command repeats it."""
    from agents.tree.samplers import load_tree_sampler
    from train.tree.cli import main
    from train.tree.training import command_of
    argv = ["--task", "maze2d", "--model", "cvae", "--hidden", "8", "--problems", "4", "--minutes", "0.005",
            "--dagger-rounds", "0", "--eval-problems", "0", "--out", str(tmp_path / "run"), "--data-dir",
            str(tmp_path / "data"), "--no-progress"]
    assert main(argv) == 0
    model, record = load_checkpoint(tmp_path / "run" / "model.pt")
    assert record["ctor_args"]["hidden_channels"] == 8 and model.decoder[0].out_features == 8
    env = gym.make("GNNMP/Maze2DRRT-v0", disable_env_checker=True)
    sampler = load_tree_sampler("cvae", env.action_space.low, env.action_space.high, task="maze2d", seed=0,
                                checkpoint=tmp_path / "run" / "model.pt", uniform_mix=0.0)
    obs, _ = env.reset(seed=0)
    assert env.action_space.contains(sampler.act(obs))
    from train.tree.args import TrainArgs
    assert " --hidden 8 " in command_of(TrainArgs(model="cvae", hidden=8)) + " "
    assert "--hidden" not in command_of(TrainArgs(model="cvae"))


@pytest.mark.parametrize("task, name, proposals", [("maze2d", "gnn", 1), ("maze2d", "gnn", 8),
                                                   ("maze2d", "gnn-cvae", 1), ("maze2d", "gnn-cvae", 4),
                                                   ("pendulum", "gnn", None), ("pendulum", "gnn-cvae", 4)])
def test_one_sampler_fed_two_trees_of_the_same_problem_reads_each(task, name, proposals):
    """Two envs plan the same problem with different actions, one sampler serves both in turn: every
    draw is the one of a sampler that only ever saw that env, given the same stream (the caches, a
    forward reused over ``proposals`` samples included, are the observation's tree's). The pendulum's
    gnn is the candidate scorer (no proposals)."""
    import gymnasium as gym
    from agents.registry import load_sampler
    from gnn_mp_envs.registration import task_spec
    envs = [gym.make(task_spec(task).env_id, disable_env_checker=True) for _ in range(2)]
    obs = [env.reset(seed=0, options={"index": 0})[0] for env in envs]
    rngs = [np.random.default_rng(s) for s in (1, 2)]
    low, high = envs[0].action_space.low, envs[0].action_space.high
    for step in range(30):               # two different trees
        for i, env in enumerate(envs):
            obs[i] = env.step(rngs[i].uniform(low, high).astype(np.float32))[0]
    assert not np.array_equal(obs[0]["nodes"][1], obs[1]["nodes"][1])
    settings = {"goal_bias": 0.0} if proposals is None else {"proposals": proposals}
    # every act reads the tree: no uniform share, fixed (an adaptive share would hand out uniform draws)
    shared = load_sampler(name, task=task, seed=0, uniform_mix=0.0, adaptive=False, **settings)
    alone = [load_sampler(name, task=task, seed=0, uniform_mix=0.0, adaptive=False, **settings) for _ in envs]
    for step in range(12):
        for i in (0, 1):
            for sampler in (shared, alone[i]):
                sampler.rng = np.random.default_rng(100 * step + i)
            np.testing.assert_array_equal(shared.act(obs[i]), alone[i].act(obs[i]), err_msg=f"step {step}, env {i}")


def test_a_non_finite_loss_stops_training_in_one_line():
    """--lr 1e6: the loss turns NaN/inf; training stops with a one-line RunError before any
    non-finite weights are kept."""
    from train.run import RunError
    data = generate(TreeDataConfig(task="maze2d", problems=6, max_nodes=1500), progress=False)
    adapter = adapter_for("gnn", "maze2d")
    net, _ = adapter.build(task_scales("maze2d"))
    items = adapter.items(net, data, "grown", np.random.default_rng(0), 16)
    with pytest.raises(RunError, match="lower --lr") as exc:
        fit(net, adapter, items, items, minutes=0.2, lr=1e12, batch_size=4, seed=0, writer=None, phase="t",
            progress=False)
    assert "\n" not in str(exc.value)


def test_the_cvae_refuses_an_observation_with_other_obstacle_rows_in_one_line():
    """A map with more obstacle rows than the CVAE was trained on: one line
    naming the mismatch, not a torch shape error."""
    import gymnasium as gym
    from agents.registry import load_sampler
    env = gym.make("GNNMP/Maze2DRRT-v0", disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    sampler = load_sampler("cvae", task="maze2d", seed=0, uniform_mix=0.0)
    sampler.act(obs)                                                     # the task's own rows: fine
    more = {**obs, "obstacles": np.concatenate([obs["obstacles"], obs["obstacles"][:4]])}
    sampler.reset(0)
    with pytest.raises(ValueError, match="obstacle rows") as exc:
        sampler.act(more)
    assert "\n" not in str(exc.value)
