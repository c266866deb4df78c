"""The sampler interface: one TensorDictModule contract, usable from Gymnasium loops."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict

from agents.nn.graph import to_pyg
from agents.samplers import SAMPLER_IN_KEYS, available_samplers, load_sampler


def _bounds(env_id="GNNMP/Maze2DBiRRT-v0"):
    env = gym.make(env_id)
    return env, env.action_space.low, env.action_space.high


@pytest.mark.parametrize("name", ["uniform", "goal-bias"])
def test_sampler_in_gym_loop_stays_in_bounds_and_is_seeded(name):
    env, low, high = _bounds("GNNMP/PendulumRRT-v0")
    actions = []
    for _ in range(2):
        sampler = load_sampler(name, bounds=(low, high), seed=3)
        obs, _ = env.reset(seed=0)
        run = []
        for _ in range(50):
            a = sampler.act(obs)
            assert env.action_space.contains(a)
            run.append(a)
            obs, *_ = env.step(a)
        actions.append(np.array(run))
    np.testing.assert_array_equal(actions[0], actions[1])


def test_goal_bias_targets_the_active_trees_root():
    env, low, high = _bounds()
    sampler = load_sampler("goal-bias", bounds=(low, high), seed=0, goal_bias=1.0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(sampler.act(obs), obs["goal"])
    obs, *_ = env.step(sampler.act(obs))
    assert obs["active_tree"][0] == 1
    np.testing.assert_allclose(sampler.act(obs), obs["start"])


@pytest.mark.parametrize("env_id", ["GNNMP/Maze2DBiRRT-v0", "GNNMP/Maze2DRRT-v0"])
def test_a_goal_bias_batch_is_its_samples_one_act_each(env_id):
    """``act_batch(obs, k)`` (one compiled call) gives, bit for bit, what ``k`` calls of ``act`` give from the
    same stream, sample ``j`` with the tree it extends active (BiRRT alternates from the observation's tree,
    RRT extends tree 0); a batch of observations is refused in one line."""
    env, low, high = _bounds(env_id)
    batched, single = (load_sampler("goal-bias", bounds=(low, high), seed=4, goal_bias=0.4) for _ in range(2))
    obs, _ = env.reset(seed=2)
    for _ in range(3):
        out = batched.act_batch(obs, 64)
        alternates = env_id.endswith("BiRRT-v0")
        for j in range(64):
            view = dict(obs, active_tree=np.array([(obs["active_tree"][0] + j) % 2 if alternates else 0]))
            np.testing.assert_array_equal(out[j].view(np.int32), single.act(view).view(np.int32))
        obs, *_ = env.step(out[0])
    assert 10 < np.sum([np.array_equal(x, obs["goal"]) or np.array_equal(x, obs["start"]) for x in out]) < 45
    stacked = {k: np.stack([v, v]) for k, v in obs.items()}
    with pytest.raises(ValueError, match="act_batch takes one observation"):
        batched.act_batch(stacked, 4)


def test_goal_bias_rate():
    env, low, high = _bounds("GNNMP/Maze2DRRT-v0")
    sampler = load_sampler("goal-bias", bounds=(low, high), seed=0, goal_bias=0.2)
    obs, _ = env.reset(seed=0)
    hits = np.mean([np.allclose(sampler.act(obs), obs["goal"]) for _ in range(2000)])
    assert 0.17 < hits < 0.23


def test_tensordict_module_batched():
    env, low, high = _bounds()
    module = load_sampler("uniform", bounds=(low, high), seed=0).as_module()
    assert list(module.in_keys) == list(SAMPLER_IN_KEYS) and list(module.out_keys) == ["action"]
    obs, _ = env.reset(seed=0)
    td = TensorDict({k: torch.as_tensor(np.stack([obs[k]] * 4)) for k in SAMPLER_IN_KEYS}, batch_size=[4])
    out = module(td)
    assert out["action"].shape == (4, 2)
    assert torch.all(out["action"] >= torch.as_tensor(low)) and torch.all(out["action"] <= torch.as_tensor(high))


def test_unknown_sampler_lists_known_names():
    with pytest.raises(ValueError, match="uniform"):
        load_sampler("nope", bounds=(np.zeros(2), np.ones(2)))
    with pytest.raises(ValueError, match="bounds"):
        load_sampler("uniform", np.zeros(2))                  # bounds where the task goes: refused, not misread
    with pytest.raises(TypeError):
        load_sampler("uniform", np.zeros(2), np.ones(2))      # the old positional bounds
    assert {"uniform", "goal-bias"} <= set(available_samplers())


def test_pyg_converter_matches_tree():
    env = gym.make("GNNMP/Maze2DBiRRT-v0").unwrapped
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(40):
        obs, *_ = env.step(rng.uniform(0, 1, 2).astype(np.float32))
    data = to_pyg(obs)
    n = int(obs["num_nodes"][0])
    assert data.num_nodes == n and data.x.shape == (n, 5)
    edges = set(map(tuple, data.edge_index.T.tolist()))
    children = [i for i in range(n) if obs["parent"][i] >= 0]
    assert len(edges) == 2 * len(children)
    for c in children:
        assert (int(obs["parent"][c]), c) in edges and (c, int(obs["parent"][c])) in edges
    batch = to_pyg({k: np.stack([obs[k], obs[k]]) for k in obs})
    assert batch.num_graphs == 2 and batch.num_nodes == 2 * n
    assert batch.start.shape == (2, 2)


# ---------------------------------------------------------------------------- pinned random streams
# The benchmark's counters depend on the exact samples: uniform = one torch.rand(*batch, d) per
# call, goal-bias = that, then one torch.rand(*batch, 1). These references re-implement the
# streams with a bare torch.Generator, so any change in draws, order, shape or dtype fails here.
def _reference_uniform(g, low, high, batch=()):
    lo, hi = torch.as_tensor(low), torch.as_tensor(high)
    return lo + torch.rand(*batch, lo.shape[0], generator=g) * (hi - lo)


def _reference_goal_bias(g, low, high, obs, goal_bias, batch=()):
    sample = _reference_uniform(g, low, high, batch)
    start, goal = torch.as_tensor(obs["start"]), torch.as_tensor(obs["goal"])
    target = torch.where(torch.as_tensor(obs["active_tree"]).reshape(*batch, 1) == 1, start, goal)
    pick = torch.rand(*batch, 1, generator=g) < goal_bias
    return torch.where(pick, target, sample)


def test_uniform_stream_is_pinned():
    env, low, high = _bounds("GNNMP/PendulumRRT-v0")
    obs, _ = env.reset(seed=0)
    sampler = load_sampler("uniform", bounds=(low, high), seed=7)
    first = np.array([sampler.act(obs) for _ in range(3)])
    # Literal values (torch's CPU Mersenne Twister): a torch upgrade that changed them would
    # change every benchmark table too.
    np.testing.assert_array_equal(first, np.array([[0.21942472457885742, -4.819149017333984],
                                                   [1.0003564357757568, 2.510244369506836],
                                                   [-1.6791086196899414, -1.1990175247192383]], np.float32))
    g = torch.Generator().manual_seed(7)
    sampler.reset(7)
    for _ in range(200):
        a = sampler.act(obs)
        assert isinstance(a, np.ndarray) and a.dtype == np.float32 and a.shape == (2,)
        np.testing.assert_array_equal(a, _reference_uniform(g, low, high).numpy())
    # Batched through the TensorDict path: one rand(*batch, d) per call.
    for batch in [(4,), (2, 3)]:
        sampler.reset(11)
        g = torch.Generator().manual_seed(11)
        td = TensorDict({k: torch.as_tensor(np.broadcast_to(obs[k], (*batch, *obs[k].shape)).copy())
                         for k in SAMPLER_IN_KEYS}, batch_size=list(batch))
        for _ in range(3):
            np.testing.assert_array_equal(sampler.as_module()(td)["action"].numpy(),
                                          _reference_uniform(g, low, high, batch).numpy())


@pytest.mark.parametrize("goal_bias", [0.05, 0.7])
def test_goal_bias_stream_is_pinned(goal_bias):
    env, low, high = _bounds("GNNMP/Maze2DBiRRT-v0")
    obs, _ = env.reset(seed=0)
    sampler = load_sampler("goal-bias", bounds=(low, high), seed=5, goal_bias=goal_bias)
    g = torch.Generator().manual_seed(5)
    hits = {0: 0, 1: 0}
    for _ in range(300):
        a = sampler.act(obs)
        ref = _reference_goal_bias(g, low, high, obs, goal_bias).numpy()
        assert a.dtype == np.float32
        np.testing.assert_array_equal(a, ref)
        tree = int(obs["active_tree"][0])
        hits[tree] += bool(np.array_equal(a, obs["start" if tree else "goal"]))
        obs, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            obs, _ = env.reset(seed=1)
    assert hits[0] > 0 and hits[1] > 0          # both targets were drawn, so both branches are pinned
    sampler.reset(9)
    g = torch.Generator().manual_seed(9)
    batch = (5,)
    td = TensorDict({k: torch.as_tensor(np.stack([obs[k]] * 5)) for k in SAMPLER_IN_KEYS}, batch_size=list(batch))
    td["active_tree"] = torch.tensor([[0], [1], [0], [1], [1]])
    for _ in range(20):
        ref = _reference_goal_bias(g, low, high, td, goal_bias, batch)
        np.testing.assert_array_equal(sampler.as_module()(td)["action"].numpy(), ref.numpy())


def test_act_returns_a_fresh_array_not_a_view_of_the_observation():
    env, low, high = _bounds("GNNMP/Maze2DRRT-v0")
    obs, _ = env.reset(seed=0)
    goal = obs["goal"].copy()
    sampler = load_sampler("goal-bias", bounds=(low, high), seed=0, goal_bias=1.0)
    a = sampler.act(obs)
    a += 1.0
    np.testing.assert_array_equal(obs["goal"], goal)


def test_samplers_are_tensordict_modules_reading_only_what_they_need():
    from tensordict.nn import TensorDictModuleBase
    env, low, high = _bounds()
    obs, _ = env.reset(seed=0)
    for name in ["uniform", "goal-bias"]:
        sampler = load_sampler(name, bounds=(low, high), seed=0)
        module = sampler.as_module()
        assert isinstance(module, TensorDictModuleBase) and module.sampler is sampler
        assert list(module.in_keys) == list(SAMPLER_IN_KEYS) and list(module.out_keys) == ["action"]
        # propose() needs only the keys in `reads` (any batch shape)
        needed = {k: torch.as_tensor(np.stack([obs[k]] * 3)) for k in sampler.reads}
        assert set(needed) <= {"start", "goal", "active_tree"}
        assert sampler.propose(needed).shape == (3, 2)
        # act() with only those keys works too: nothing else is converted
        assert sampler.act({k: obs[k] for k in sampler.reads}).shape == (2,)


# ---------------------------------------------------------------------------- docs
def docs_python_blocks(path):
    import re
    import textwrap
    text = path.read_text()
    return [textwrap.dedent(m.group(2)) for m in re.finditer(r"^( *)```python\n(.*?)^\1```", text, re.M | re.S)]


def test_docs_python_blocks_run(tmp_path):
    """Every python block of docs/samplers.md, in order, in one fresh interpreter."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    blocks = docs_python_blocks(root / "docs" / "samplers.md")
    assert len(blocks) >= 7           # gym loop, TorchRL module, encoder, actor/value, SB3, learned, registry, adding
    script = tmp_path / "samplers_docs.py"
    script.write_text("\n\n".join(blocks))
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    result = subprocess.run([sys.executable, str(script)], cwd=root, env=env, capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "torch.Size([4, 2])" in result.stdout
    assert "takes goal_bias; unknown: goal_bais" in result.stdout and "GoalMLPSampler 0.25" in result.stdout


def test_docs_samplers_listing_is_what_gnn_mp_samplers_prints():
    """docs/samplers.md prints `gnn-mp samplers` after the command: the listing is the registry's
    (the ompl-* lines only where OMPL is installed, as here when `make install` ran)."""
    import importlib.util
    import re
    import subprocess
    import sys
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / "samplers.md").read_text()
    match = re.search(r"^```bash\ngnn-mp samplers\n```\n\n```text\n(.*?)^```", text, re.M | re.S)
    assert match, "docs/samplers.md: no `gnn-mp samplers` block followed by its output"
    code = "import sys; from train.cli import main; sys.exit(main())"
    result = subprocess.run([sys.executable, "-c", code, "samplers"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    page, printed = match.group(1).splitlines(), result.stdout.splitlines()
    if importlib.util.find_spec("ompl") is None:
        page = [line for line in page if not line.startswith("ompl-")]
        printed = [line for line in printed if not line.startswith("ompl-")]
    assert page == printed


# ---------------------------------------------------------------------------- the registry refuses mistakes
def test_load_sampler_takes_bounds_from_the_task_spec():
    env = gym.make("GNNMP/ArmBiRRT-v0", disable_env_checker=True)
    sampler = load_sampler("uniform", task="arm", seed=0)
    np.testing.assert_array_equal(sampler.low32, env.action_space.low)
    np.testing.assert_array_equal(sampler.high32, env.action_space.high)
    env.close()


def one_line_error(call) -> str:
    with pytest.raises(ValueError) as exc:
        call()
    message = str(exc.value)
    assert "\n" not in message
    return message


def test_load_sampler_refuses_an_unknown_keyword():
    message = one_line_error(lambda: load_sampler("goal-bias", task="maze2d", goal_bais=0.5))
    assert "goal_bais" in message and "goal_bias" in message
    assert "unknown: temperature" in one_line_error(lambda: load_sampler("uniform", task="maze2d", temperature=2))
    assert "sigma_scale" in one_line_error(lambda: load_sampler("gnn", task="pendulum", sigma_scale=0.5))


def test_load_sampler_refuses_an_unknown_task_and_bounds_of_another_task():
    message = one_line_error(lambda: load_sampler("uniform", task="maze3d"))
    assert "maze3d" in message and "maze2d" in message
    message = one_line_error(lambda: load_sampler("gnn", task="arm", bounds=(np.zeros(2), np.ones(2))))
    assert "not task 'arm'" in message
    assert "task=" in one_line_error(lambda: load_sampler("gnn"))


def test_load_sampler_refuses_a_checkpoint_of_another_task():
    from agents.checkpoints import shipped_checkpoint
    for name in ("gnn", "cvae", "rl-ppo"):
        message = one_line_error(lambda: load_sampler(name, task="arm", checkpoint=shipped_checkpoint(name, "maze2d")))
        assert "trained for task 'maze2d', not 'arm'" in message


def test_a_sampler_refuses_observations_of_another_state_dimension():
    maze = load_sampler("goal-bias", task="maze2d", seed=0)
    gnn = load_sampler("gnn", task="maze2d", seed=0)
    env = gym.make("GNNMP/PendulumRRT-v0", disable_env_checker=True)
    obs, _ = env.reset(seed=0)
    arm = {**obs, "start": np.zeros(6, np.float32), "goal": np.zeros(6, np.float32)}
    for sampler in (maze, gnn):
        assert "6-D states" in one_line_error(lambda: sampler.act(arm))


def test_torch_compatible_stream_makes_torchs_draws():
    """The classical samplers and the shipped RL policies draw torch's values without torch: rand and
    randn after manual_seed, in any interleaving (randn's cached second value included), across the
    generator's twists (a state makes WORDS draws) and with a draw longer than a state; a stream
    reseeded (a sampler's reset) after draws that left a state and a cached value half used draws as a
    new one."""
    from agents.samplers.streams import WORDS, TorchCompatibleStream
    calls = [("rand", 2), ("randn", 2), ("randn", 3), ("rand", 1), ("randn", 1), ("randn", 6), ("rand", 5)]
    used = TorchCompatibleStream(123)
    for seed in (0, 7, 2**32 - 1):
        used.unit(3)
        used.normal(3)                  # leaves its second value cached
        used.reseed(seed)
        for stream in (TorchCompatibleStream(seed), used):
            g = torch.Generator().manual_seed(seed)
            for kind, n in calls * 40 + [("rand", 3 * WORDS + 5)] + calls:     # ~4 twists of draws
                ours = stream.unit(n) if kind == "rand" else stream.normal(n)
                theirs = (torch.rand if kind == "rand" else torch.randn)(n, generator=g).numpy()
                np.testing.assert_array_equal(ours, theirs)
    with pytest.raises(ValueError, match="16"):
        TorchCompatibleStream(0).normal(16)


def test_torch_compatible_stream_is_numpys_mersenne_twister():
    """The compiled generator's raw words are numpy's MT19937 seeded as RandomState seeds it (every word
    over several twists, seeds at both ends of the 32-bit range); ``uniform`` is the float32 numpy
    operations on ``low24``, bit for bit; a stream of ``seed=None`` continues a fresh numpy state."""
    from agents.samplers.streams import WORDS, TorchCompatibleStream
    for seed in (0, 1, 5489, 2**31, 2**32 - 1):
        bits = np.random.MT19937()
        np.random.RandomState(bits).seed(seed)
        stream = TorchCompatibleStream(seed)
        words = np.concatenate([stream.raw(n) for n in (1, WORDS - 1, 5, 3 * WORDS)])
        np.testing.assert_array_equal(words, bits.random_raw(len(words)))
    low = np.array([-2.9, 0.0, -1e-3, 7.5], np.float32)
    span = np.array([5.8, 1.0, 2e-3, 0.25], np.float32)
    scale = span * np.float32(2.0 ** -24)
    a, b = TorchCompatibleStream(11), TorchCompatibleStream(11)
    for k in (1, 3, 64, 200):
        expected = b.low24(k * 4).reshape(k, 4) * scale
        expected += low
        np.testing.assert_array_equal(a.uniform(k, low, scale).reshape(k, 4), expected)
    fresh = TorchCompatibleStream(None)
    bits = np.random.MT19937()
    bits.state = {"bit_generator": "MT19937", "state": {"key": fresh.state[:WORDS].astype(np.uint32),
                                                         "pos": int(fresh.state[WORDS])}}
    np.testing.assert_array_equal(fresh.raw(2 * WORDS), bits.random_raw(2 * WORDS))
    assert not np.array_equal(TorchCompatibleStream(None).state, TorchCompatibleStream(None).state)


def test_the_thread_policy():
    """Loading a learned sampler puts torch on one thread (a step's forward is small; a second thread
    costs up to 10x); threads=None opts out; classical samplers leave torch alone; the context
    manager restores the count."""
    from agents.samplers.base import inference_threads
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        load_sampler("uniform", task="maze2d")
        assert torch.get_num_threads() == 2
        load_sampler("cvae", task="maze2d", threads=None)
        assert torch.get_num_threads() == 2
        load_sampler("cvae", task="maze2d")
        assert torch.get_num_threads() == 1
        from threadpoolctl import threadpool_info
        assert all(pool["num_threads"] == 1 for pool in threadpool_info() if pool["user_api"] == "blas")
        torch.set_num_threads(2)
        with inference_threads():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_classical_samplers_run_without_torch():
    """The environments and the classical samplers need no torch: a fresh interpreter that cannot
    import torch or tensordict plans a problem with uniform and goal-bias samplers."""
    import subprocess
    import sys
    code = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('torch', 'tensordict', 'torchrl', 'torch_geometric'):\n"
        "            raise ImportError(f'blocked: {name}')\n"
        "sys.meta_path.insert(0, Block())\n"
        "from agents.registry import load_sampler\n"
        "from gnn_mp_envs.evaluation import evaluation_env, plan_problems, summarize\n"
        "env = evaluation_env('maze2d', 'test')\n"
        "for name in ('uniform', 'goal-bias'):\n"
        "    print(name, summarize(plan_problems(load_sampler(name, task='maze2d'), env, range(2), 0))['success_rate'])\n"
        "assert not any(m.split('.')[0] in ('torch', 'tensordict') for m in sys.modules)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "uniform 1.0" in result.stdout and "goal-bias 1.0" in result.stdout


@pytest.mark.parametrize("argv, code, fragment", [
    (["benchmark", "--task", "maze2d", "--samplers", "uniform,goal-bias", "--problems", "2", "--no-progress"], 0,
     None),
    (["benchmark", "--task", "maze2d", "--samplers", "uniform,gnn", "--problems", "1", "--no-progress"], 2,
     "pip install 'gnn-mp-envs[agents]'"),
    (["train", "sampler", "--help"], 2, "pip install 'gnn-mp-envs[agents]'"),
    (["samplers"], 0, "gnn"),
])
def test_an_environments_only_install_plans_classically_and_refuses_learned_samplers_in_one_line(argv, code, fragment):
    """Without the agents extra (torch and friends cannot be imported), the CLI plans with the
    classical samplers and refuses anything learned in one line naming the extra, rc 2."""
    import subprocess
    import sys
    blocker = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] in ('torch', 'tensordict', 'torchrl', 'torch_geometric', 'threadpoolctl',\n"
        "                                  'stable_baselines3', 'tensorboard'):\n"
        "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
        "sys.meta_path.insert(0, Block())\n"
        "from train.cli import main\n"
        f"sys.exit(main({argv!r}))\n")
    result = subprocess.run([sys.executable, "-c", blocker], capture_output=True, text=True, timeout=300)
    assert result.returncode == code, result.stderr[-2000:]
    if code == 2:
        err = result.stderr.strip().splitlines()
        assert len(err) == 1 and fragment in err[0], err
    elif argv == ["samplers"]:
        gnn_line = next(line for line in result.stdout.splitlines() if line.startswith("gnn "))
        assert "needs the 'agents' extra" in gnn_line
        assert "needs the" not in next(line for line in result.stdout.splitlines() if line.startswith("uniform "))


def test_proposals_run_the_forward_once_per_k_model_samples():
    """proposals=k: a learned sampler's forward runs once per k model samples of one episode and
    active tree, again for a new episode; proposals=1 runs it every time."""
    from agents.samplers import ModelSampler

    class Counting(ModelSampler):
        settings = ModelSampler.settings + ("proposals",)
        forwards = 0

        def forward_pass(self, obs):
            Counting.forwards += 1
            return np.asarray(obs["goal"], np.float64)

        def model_sample(self, obs):
            return self.refreshed(obs, self.forward_pass)

    env = gym.make("GNNMP/Maze2DBiRRT-v0", disable_env_checker=True)
    obs, _ = env.reset(seed=0, options={"index": 0})
    for k, expected in ((1, 12), (4, 3)):          # 12 model samples with the same active tree
        Counting.forwards = 0
        sampler = Counting(env.action_space.low, env.action_space.high, 0, uniform_mix=0.0, proposals=k)
        for _ in range(12):
            sampler.act(obs)
        assert Counting.forwards == expected
        assert sampler.forward_calls == expected and sampler.forward_time_s > 0   # the inference accounting
        sampler.reset(1)
        assert sampler.forward_calls == expected                                 # kept across resets
    sampler = Counting(env.action_space.low, env.action_space.high, 0, uniform_mix=0.0, proposals=4)
    Counting.forwards = 0
    other = {**obs, "active_tree": np.array([1])}
    sampler.act(obs), sampler.act(other), sampler.act(obs), sampler.act(other)
    assert Counting.forwards == 2                    # one cached forward per active tree (BiRRT)
    new_problem, _ = env.reset(seed=0, options={"index": 1})
    sampler.act(new_problem)
    assert Counting.forwards == 3                    # a new episode refreshes at once
    with pytest.raises(ValueError, match="proposals"):
        Counting(env.action_space.low, env.action_space.high, 0, proposals=0)


def test_the_proposals_tuning_rule():
    """tools/tune_proposals: the smallest value within 5% of the fastest among those as successful
    as the first; with an inference-share bound, the smallest value under it (else the largest)."""
    from tools.tune_proposals import choose
    rows = {1: dict(success_rate=1.0, median_wall_time_s=0.100, inference_share=0.50),
            8: dict(success_rate=1.0, median_wall_time_s=0.052, inference_share=0.20),
            16: dict(success_rate=1.0, median_wall_time_s=0.050, inference_share=0.08),
            32: dict(success_rate=0.9, median_wall_time_s=0.040, inference_share=0.05)}
    assert choose(rows, [1, 8, 16, 32]) == 8          # 32 fails more often; 8 is within 5% of 16
    assert choose(rows, [1, 8, 16, 32], inference_share=0.1) == 16
    assert choose(rows, [1, 8], inference_share=0.1) == 8


def test_the_mixture_tuning_tool_reads_its_candidates_and_its_rule(capsys):
    """tools/tune_adaptive: ``--setting adaptive`` takes true or dicts, a share (``uniform_mix``,
    ``goal_bias``) numbers in [0, 1); anything else is a one-line usage error before any planning.
    Chosen: the smallest geometric mean among the candidates whose worst kind is within ``--worst``."""
    from tools.tune_adaptive import choose, main, parse_candidates
    assert parse_candidates("adaptive", '[true, {"cells": 40}]') == [True, {"cells": 40}]
    assert parse_candidates("uniform_mix", "[0.5, 0, 0.75]") == [0.5, 0, 0.75]
    for setting, bad in [("adaptive", "[0.5]"), ("adaptive", "[false]"), ("uniform_mix", "[1.0]"),
                         ("uniform_mix", "[-0.1]"), ("goal_bias", "[true]"), ("uniform_mix", "[]"),
                         ("uniform_mix", "0.5"), ("uniform_mix", "[0.5")]:
        assert parse_candidates(setting, bad) is None, (setting, bad)
    with pytest.raises(SystemExit):
        main(["--setting", "uniform_mix", "--candidates", "[0.5, 1.5]"])
    err = capsys.readouterr().err.strip().splitlines()
    assert "numbers in [0, 1) for --setting uniform_mix" in err[-1]
    summary = {"0.5": {"geometric_mean": 0.64, "worst": 1.02}, "0.7": {"geometric_mean": 0.60, "worst": 1.17},
               "0.8": {"geometric_mean": 0.66, "worst": 0.90}}
    assert choose(summary, worst=1.1) == "0.5"       # 0.7 is best on average but too bad on one kind
    assert choose(summary, worst=1.2) == "0.7"
    assert choose(summary, worst=0.5) == "0.7"       # none within the bound: all compete


def test_a_tuned_setting_is_stored_in_the_weights_and_the_sidecar(tmp_path, monkeypatch):
    """tools.shipped_settings (the --write of tune_proposals and tune_adaptive): the chosen value joins
    meta["sampler"], which load_sampler applies; the tuning table and the command go beside it in the
    checkpoint and its sidecar; the other settings and the weights stay."""
    import json
    import shutil

    from agents.checkpoints import SHIPPED_DIR, read_checkpoint
    from agents.registry import load_sampler
    from tools.shipped_settings import store_tuned_setting, tool_command
    for suffix in (".pt", ".json"):
        shutil.copy(SHIPPED_DIR / f"cvae_maze2d{suffix}", tmp_path / f"cvae_maze2d{suffix}")
    monkeypatch.setattr("agents.checkpoints.SHIPPED_DIR", tmp_path)
    before = read_checkpoint(tmp_path / "cvae_maze2d.pt")
    command = tool_command("tools.tune_proposals", ["--candidates", "[1, 2]"])
    assert command == "python -m tools.tune_proposals --candidates '[1, 2]'"
    store_tuned_setting("cvae", "maze2d", {"proposals": 7}, "proposals_tuning", {"command": command, "rows": {}})
    after = read_checkpoint(tmp_path / "cvae_maze2d.pt")
    assert after["meta"]["sampler"] == {**before["meta"]["sampler"], "proposals": 7}
    assert after["meta"]["proposals_tuning"]["command"] == command
    side = json.loads((tmp_path / "cvae_maze2d.json").read_text())
    assert side["sampler"]["proposals"] == 7 and side["proposals_tuning"]["command"] == command
    assert all(torch.equal(after["state_dict"][k], v) for k, v in before["state_dict"].items())
    assert load_sampler("cvae", task="maze2d", seed=0).proposals == 7


def test_the_mixture_uniform_draw_is_generator_uniform():
    """ModelSampler's uniform share draws rng.uniform(low, high)'s exact values (written without its
    broadcasting overhead): the tree samplers' recorded counters depend on them."""
    from agents.samplers import ModelSampler

    class Never(ModelSampler):
        def model_sample(self, obs):
            raise AssertionError("uniform_mix=1 never asks the model")

    for task in ("maze2d", "pendulum", "arm"):
        from gnn_mp_envs.registration import task_spec
        low, high = task_spec(task).state_bounds()
        sampler = Never(low, high, 11, uniform_mix=1.0)
        ref = np.random.default_rng(11)
        obs = {"start": np.zeros(len(low), np.float32)}
        for _ in range(500):
            want = ref.random()                                   # the mixture's choice
            assert want < 1.0
            np.testing.assert_array_equal(sampler.act(obs), ref.uniform(sampler.low, sampler.high).astype(np.float32))


@pytest.mark.parametrize("task,setting", [("maze2d", {"temperature": -1.0}), ("maze2d", {"temperature": 0.0}),
                                          ("maze2d", {"sigma_scale": float("nan")}), ("maze2d", {"sigma_scale": -0.5}),
                                          ("pendulum", {"temperature": float("inf")})])
def test_a_gnn_sampler_refuses_a_temperature_or_scale_out_of_range(task, setting):
    """A negative temperature would invert the node mixture (the least likely node drawn most):
    a bad ``--setting`` is a one-line error, not a silently different sampler."""
    from agents.samplers import load_sampler
    with pytest.raises(ValueError, match="finite and > 0"):
        load_sampler("gnn", task=task, seed=0, **setting)


@pytest.mark.parametrize("name,setting,match", [("gnn", {"uniform_mix": "nan"}, "must be numbers"),
                                                ("cvae", {"goal_bias": True}, "must be numbers"),
                                                ("rl-ppo", {"deterministic": 3}, "true or false")])
def test_a_setting_of_the_wrong_type_is_refused(name, setting, match):
    """``--setting`` values that are not JSON arrive as strings (``gnn.uniform_mix=nan``): a
    one-line ValueError, not a TypeError from a comparison deep in the constructor; a flag takes
    a boolean, not any truthy value."""
    from agents.samplers import load_sampler
    with pytest.raises(ValueError, match=match):
        load_sampler(name, task="maze2d", seed=0, **setting)
