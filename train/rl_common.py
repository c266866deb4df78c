"""What the RL training scripts share: the flags (one dataclass), the run directory, evaluation
on held-out problems, the learning curve, shipping, and the buffer-memory figures.

``train/rl_sb3.py`` and ``train/rl_torchrl.py`` read top to bottom; they call into here for the
parts that do not depend on the library. A run directory holds::

    runs/rl-<lib>-<algo>-<task>-s<seed>/
        config.json          every flag of the run (+ library versions, start time)
        policy.pt            the latest evaluated policy (agents.checkpoints format, weights_only)
        best.pt              the best one on split ``val`` (success rate, then median nodes)
        evaluations.json     one row per evaluation (steps, wall time, success, nodes, ...)
        learning_curve.png   val success and median nodes against training steps
        tb/                  TensorBoard logs (`tensorboard --logdir runs/`)
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gnn_mp_envs.utils.io import atomic_path, atomic_write_bytes, atomic_write_text
from train.args import arg, non_negative_float, non_negative_int, positive_float, positive_int

LIBS = ("sb3", "torchrl")
ALGOS = ("ppo", "sac")
#: (lib, algo) -> registry name of the sampler a run's policy becomes
SAMPLER_NAMES = {("sb3", "ppo"): "rl-ppo", ("sb3", "sac"): "rl-sac", ("torchrl", "ppo"): "rl-ppo-torchrl"}


def _mixes(text: str) -> list[float]:
    import argparse
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers in [0, 1], got {text!r}") from None
    if not values or not all(0.0 <= v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers in [0, 1], got {text!r}")
    return values


@dataclass
class RLArgs:
    """Flags of ``gnn-mp train rl`` (CleanRL style: one line of doc per field)."""

    # --- what to train
    algo: str = arg("ppo", "algorithm", choices=ALGOS)
    lib: str = arg("sb3", "library (torchrl: PPO only)", choices=LIBS)
    task: str = arg("maze2d", "task family: maze2d, pendulum, arm (arm: BiRRT, the action extends active_tree)")
    planner: str | None = arg(None, "planner variant (default: the task's benchmark env; maze2d also birrt)")
    total_steps: int = arg(50_000, "environment steps to train for (all envs together)", parse=positive_int)
    seed: int = arg(0, "seed of the envs' problem draws, the networks and the evaluation", parse=non_negative_int)
    # --- environment (make_rl_env)
    n_envs: int = arg(4, "environments stepped together (vectorised)", parse=positive_int)
    parallel: bool = arg(False, "one process per env (SB3 SubprocVecEnv / TorchRL ParallelEnv; default: serial)")
    view_nodes: int = arg(64, "rows of the tree view the policy sees (roots + most recent nodes)", parse=positive_int)
    max_nodes: int | None = arg(None, "tree node budget of the training envs (default: the task's)", parse=positive_int)
    action_frame: str = arg("target", "policy actions in [-1, 1]: offsets from the active tree's target "
                            "(target) or the rescaled state box (absolute)", choices=("target", "absolute"))
    step_penalty: float = arg(1.0, "reward: -step_penalty per planner iteration", parse=non_negative_float)
    collision_check_cost: float = arg(0.0, "reward: -cost per validity check of the step", parse=non_negative_float)
    success_reward: float = arg(10.0, "reward: +success_reward on the step that finds a path", parse=non_negative_float)
    progress_reward: float = arg(10.0, "reward shaping: coef of the potential-based progress term "
                                 "(ProgressReward; 0: the env's reward only)", parse=non_negative_float)
    reward_scale: float = arg(0.01, "multiply every reward by this (returns of order 1)", parse=positive_float)
    # --- networks (the shared TreeEncoder + the library's head)
    hidden_channels: int = arg(32, "TreeEncoder node embedding width", parse=positive_int)
    num_layers: int = arg(2, "TreeEncoder message-passing layers", parse=non_negative_int)
    out_channels: int = arg(64, "TreeEncoder graph embedding width", parse=positive_int)
    conv: str = arg("sage", "TreeEncoder convolution", choices=("sage", "graph", "gcn", "gatv2"))
    knn: int = arg(0, "TreeEncoder k-NN edges per node (0: tree edges only)", parse=non_negative_int)
    net_arch: list[int] = arg([64, 64], "hidden widths of the policy and value heads")
    encoder: str = arg("tree", "backbone: tree (TreeEncoder, sized by the flags above) or tree-gnn (the supervised GNN "
                       "sampler's causal TreeGNN, its architecture; what --init-from a tree_gnn checkpoint needs)",
                       choices=("tree", "tree-gnn"))
    init_from: Path | None = arg(None, "warm start: copy the backbone weights of this checkpoint (any kind holding "
                                 "one of the same size, e.g. agents/checkpoints/tree_gnn_maze2d.pt with --encoder tree-gnn)")
    # --- optimisation
    lr: float = arg(3e-4, "Adam learning rate", parse=positive_float)
    gamma: float = arg(0.99, "discount", parse=positive_float)
    batch_size: int = arg(128, "minibatch size", parse=positive_int)
    n_steps: int = arg(256, "PPO: steps per env per rollout", parse=positive_int)
    n_epochs: int = arg(4, "PPO: passes over each rollout", parse=positive_int)
    gae_lambda: float = arg(0.95, "PPO: GAE lambda", parse=positive_float)
    clip_range: float = arg(0.2, "PPO: clip range", parse=positive_float)
    ent_coef: float = arg(0.0, "PPO: entropy bonus", parse=non_negative_float)
    log_std_init: float = arg(-2.0, "PPO: initial log std of the Gaussian (actions in [-1, 1]; -2: std 0.135, a "
                              "narrow bias toward the target in the target frame)")
    buffer_size: int = arg(100_000, "SAC: replay buffer transitions", parse=positive_int)
    learning_starts: int = arg(1000, "SAC: steps before the first update", parse=non_negative_int)
    # --- evaluation, outputs
    eval_every: int = arg(10_000, "evaluate (and checkpoint) every N steps", parse=positive_int)
    eval_problems: int = arg(10, "problems 0..N-1 of split val per evaluation", parse=positive_int)
    eval_max_steps: int = arg(4000, "planner iterations per evaluation problem (then a failure)", parse=positive_int)
    uniform_mix: float = arg(0.5, "probability of a uniform sample instead of the policy's, in training "
                             "(UniformMixAction) and in the sampler", parse=non_negative_float)
    tune_mix: list[float] | None = arg(None, "after training, pick the final policy's uniform_mix among these "
                                       "on split val (e.g. 0.25,0.5,0.75)", parse=_mixes)
    out: Path | None = arg(None, "run directory (default: runs/rl-<lib>-<algo>-<task>-s<seed>)")
    ship: bool = arg(False, "copy the final policy to agents/checkpoints/<sampler>_<task>.pt (+ .json)")
    progress: bool = arg(True, "hide the progress bar")
    threads: int = arg(1, "torch threads (the machine is shared: keep 1)", parse=positive_int)

    def run_dir(self) -> Path:
        return self.out or Path("runs") / f"rl-{self.lib}-{self.algo}-{self.task}-s{self.seed}"

    def env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`gnn_mp_envs.envs.wrappers.make_rl_env` (besides task, split)."""
        kw: dict[str, Any] = {"view_nodes": self.view_nodes, "planner": self.planner, "action_frame": self.action_frame,
                              "step_penalty": self.step_penalty, "collision_check_cost": self.collision_check_cost,
                              "success_reward": self.success_reward, "uniform_mix": self.uniform_mix,
                              "progress_reward": self.progress_reward, "gamma": self.gamma,
                              "reward_scale": self.reward_scale}
        if self.max_nodes is not None:
            kw["max_nodes"] = self.max_nodes
        return kw

    def encoder_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``agents.encoders.encoder_from_space``."""
        if self.encoder == "tree-gnn":   # the supervised GNN sampler's architecture, so its weights fit
            from train.tree_samplers.models import TASKS, GNNAdapter
            t = TASKS[self.task]
            return {"backbone": "tree-gnn", "hidden_channels": GNNAdapter.hidden_channels,
                    "num_layers": GNNAdapter.num_layers, "knn": GNNAdapter.knn, "step_scale": t.step_scale,
                    "periodic": list(t.periodic), "num_trees": t.num_trees}
        return {"hidden_channels": self.hidden_channels, "num_layers": self.num_layers,
                "out_channels": self.out_channels, "conv": self.conv, "knn": self.knn}

    @property
    def sampler_name(self) -> str:
        return SAMPLER_NAMES[(self.lib, self.algo)]


@dataclass
class RunResult:
    """What a training script returns."""

    best: Path                          # the best policy on split val (best.pt)
    steps: int                          # environment steps trained
    train_seconds: float                # wall time of the training loop (evaluations included)
    buffer_bytes: int                   # SB3: the rollout/replay buffer's arrays; TorchRL: one batch
    evaluations: list[dict[str, Any]]   # the rows of evaluations.json


def check_args(args: RLArgs) -> None:
    """One-line ``ValueError`` for combinations that cannot run."""
    from gnn_mp_envs.registration import task_spec
    if (args.lib, args.algo) not in SAMPLER_NAMES:
        raise ValueError(f"--lib {args.lib} --algo {args.algo} is not available "
                         f"(available: {', '.join(f'{l}/{a}' for l, a in SAMPLER_NAMES)})")
    task_spec(args.task)
    if args.view_nodes < 2:
        raise ValueError("--view-nodes must be >= 2")
    if args.init_from is not None and not Path(args.init_from).exists():
        raise ValueError(f"--init-from {args.init_from}: no such file")
    if args.uniform_mix > 1:
        raise ValueError("--uniform-mix must be in [0, 1]")


def write_config(args: RLArgs, run_dir: Path, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """``config.json``: every flag, the library versions and the start time (atomic)."""
    import stable_baselines3
    import torch
    import torchrl
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(args).items()}
    config["versions"] = {"torch": torch.__version__, "torchrl": torchrl.__version__,
                          "stable_baselines3": stable_baselines3.__version__}
    config["started"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    config.update(extra or {})
    atomic_write_text(run_dir / "config.json", json.dumps(config, indent=2) + "\n")
    return config


# ----------------------------------------------------------------------------- evaluation
def evaluate_sampler(sampler: Any, task: str, problems: int, seed: int, *, split: str = "val",
                     planner: str | None = None, max_steps: int | None = None,
                     max_nodes: int | None = None) -> dict[str, Any]:
    """Plan problems ``0..problems-1`` of ``split`` with a sampler (the benchmark's seeding):
    success rate, median/mean nodes expanded, median collision checks, wall time."""
    from gnn_mp_envs.rollout import rollout
    from train.benchmark.args import problem_seed
    env = _eval_env(task, split, planner, max_nodes)
    records = []
    for i in range(problems):
        s = problem_seed(seed, i)
        sampler.reset(s)
        records.append(rollout(env, sampler.act, seed=s, options={"index": i}, max_steps=max_steps))
    nodes = np.array([r.nodes_expanded for r in records], float)
    return {"success": float(np.mean([r.success for r in records])), "median_nodes": float(np.median(nodes)),
            "mean_nodes": float(nodes.mean()),
            "median_collision_checks": float(np.median([r.collision_checks for r in records])),
            "median_wall_time_s": float(np.median([r.wall_time_s for r in records])), "problems": problems}


_EVAL_ENVS: dict[tuple, Any] = {}


def _eval_env(task: str, split: str, planner: str | None, max_nodes: int | None):
    """The full (unwrapped, benchmark) env the samplers are judged on, one per setting."""
    import gymnasium as gym

    import gnn_mp_envs  # noqa: F401
    from gnn_mp_envs.registration import task_spec
    key = (task, split, planner, max_nodes)
    if key not in _EVAL_ENVS:
        spec = task_spec(task)
        env_id = spec.env_id if planner is None else next(i for i, v in spec.envs.items()
                                                          if v.get("planner") == planner)
        kw = {} if max_nodes is None else {"max_nodes": max_nodes}
        _EVAL_ENVS[key] = gym.make(env_id, split=split, copy_observations=False, disable_env_checker=True, **kw)
    return _EVAL_ENVS[key]


def state_box(args: RLArgs) -> tuple[np.ndarray, np.ndarray, list[bool]]:
    """The task's state box (what ``[-1, 1]`` maps to) and which dimensions wrap (the pendulum's angle)."""
    from gnn_mp_envs.envs.wrappers import make_rl_env, periodic_dims
    env = make_rl_env(args.task, view_nodes=None, planner=args.planner, scale_actions=False)
    env.reset(seed=0)
    low, high = env.action_space.low, env.action_space.high
    periodic = periodic_dims(env.unwrapped.problem, low, high)
    env.close()
    return low, high, periodic


def score(row: dict[str, Any]) -> tuple[float, float]:
    """Higher is better: success rate, then fewer median nodes."""
    return (row["success"], -row["median_nodes"])


class Evaluator:
    """Periodic evaluation on split ``val``: checkpoints, ``evaluations.json``, TensorBoard scalars.

    ``export()`` must return ``(policy, kind, ctor_args)`` (``agents.models.rl``); ``log``
    receives ``(name, value, step)`` for TensorBoard.
    """

    def __init__(self, args: RLArgs, run_dir: Path, export: Callable[[], tuple],
                 log: Callable[[str, float, int], None] | None = None) -> None:
        self.args, self.run_dir, self.export = args, run_dir, export
        self.low, self.high, self.periodic = state_box(args)
        self.log = log
        self.rows: list[dict[str, Any]] = []
        self.best: tuple[float, float] | None = None
        self.started = time.perf_counter()
        self.next_at = 0

    def due(self, steps: int) -> bool:
        return steps >= self.next_at

    def sampler(self, policy: Any, uniform_mix: float | None = None):
        from agents.samplers.rl import RLSampler
        mix = self.args.uniform_mix if uniform_mix is None else uniform_mix
        return RLSampler(self.low, self.high, 0, policy=policy, view_nodes=self.args.view_nodes,
                         uniform_mix=mix, action_frame=self.args.action_frame, periodic=self.periodic).eval()

    def save(self, path: Path, policy: Any, kind: str, ctor_args: dict, uniform_mix: float, **meta: Any) -> Path:
        from agents.samplers.rl import save_policy
        return save_policy(path, policy, kind, ctor_args, task=self.args.task, view_nodes=self.args.view_nodes,
                           low=self.low, high=self.high, uniform_mix=uniform_mix,
                           action_frame=self.args.action_frame, periodic=self.periodic,
                           meta={"sampler_name": self.args.sampler_name, "planner": self.args.planner,
                                 "train_config": json.loads((self.run_dir / "config.json").read_text()),
                                 **meta})

    def __call__(self, steps: int) -> dict[str, Any]:
        """Evaluate the current policy; write ``policy.pt`` (and ``best.pt`` when it is the best)."""
        import torch
        a = self.args
        policy, kind, ctor_args = self.export()
        train_wall = time.perf_counter() - self.started
        t0 = time.perf_counter()
        with torch.no_grad():
            row = evaluate_sampler(self.sampler(policy), a.task, a.eval_problems, a.seed, planner=a.planner,
                                   max_steps=a.eval_max_steps, max_nodes=a.max_nodes)
        row = {"steps": int(steps), "train_wall_s": round(train_wall, 1), "eval_wall_s": round(time.perf_counter() - t0, 1),
               **row}
        self.rows.append(row)
        self.save(self.run_dir / "policy.pt", policy, kind, ctor_args, a.uniform_mix, evaluation=row)
        if self.best is None or score(row) > self.best:
            self.best = score(row)
            self.save(self.run_dir / "best.pt", policy, kind, ctor_args, a.uniform_mix, evaluation=row)
        atomic_write_text(self.run_dir / "evaluations.json", json.dumps(self.rows, indent=2) + "\n")
        if self.log is not None:
            for name in ("success", "median_nodes", "mean_nodes", "median_collision_checks"):
                self.log(f"eval/{name}", row[name], steps)
        self.next_at = steps + a.eval_every
        return row

    def finish(self, steps: int) -> Path:
        """Last evaluation, uniform-mix tuning (``--tune-mix``), learning curve, shipping."""
        if not self.rows or self.rows[-1]["steps"] != steps:
            self(steps)
        best = self.run_dir / "best.pt"
        if self.args.tune_mix:   # of the final policy, the one --ship copies
            tune_uniform_mix(self.run_dir / "policy.pt", self.args)
        plot_learning_curve(self.rows, self.run_dir / "learning_curve.png",
                            title=f"{self.args.lib} {self.args.algo.upper()} on {self.args.task}")
        if self.args.ship:   # the final policy: what the command trained (best.pt is the val pick)
            ship(self.run_dir / "policy.pt", self.args.sampler_name, self.args.task)
        return best


def tune_uniform_mix(path: Path, args: RLArgs) -> float:
    """Pick ``uniform_mix`` among ``args.tune_mix`` on split ``val`` and store it in the checkpoint."""
    import torch

    from agents.checkpoints import load_checkpoint, save_checkpoint
    from agents.samplers.rl import sampler_from_checkpoint
    low, high, _ = state_box(args)
    rows = []
    for mix in args.tune_mix or []:
        sampler = sampler_from_checkpoint(path, low, high, seed=0, uniform_mix=mix)
        with torch.no_grad():
            row = evaluate_sampler(sampler, args.task, args.eval_problems, args.seed, planner=args.planner,
                                   max_steps=args.eval_max_steps, max_nodes=args.max_nodes)
        rows.append({"uniform_mix": mix, **row})
        print(f"  uniform_mix {mix:.2f}: val success {row['success']:.2f}, median nodes {row['median_nodes']:.0f}")
    best = max(rows, key=score)
    model, record = load_checkpoint(path)
    meta = dict(record["meta"])
    meta["sampler"] = {"uniform_mix": best["uniform_mix"]}
    meta["mix_tuning"] = rows
    save_checkpoint(path, model, record["kind"], record["ctor_args"], obs_spec=record["obs_spec"], meta=meta)
    return best["uniform_mix"]


def ship(checkpoint: Path, sampler_name: str, task: str) -> Path:
    """Copy a run's best policy to ``agents/checkpoints/<sampler>_<task>.pt`` with a ``.json`` sidecar."""
    from agents.checkpoints import SHIPPED_DIR, read_checkpoint
    target = SHIPPED_DIR / f"{sampler_name}_{task}.pt"
    atomic_write_bytes(target, Path(checkpoint).read_bytes())
    meta = read_checkpoint(target)["meta"]
    atomic_write_text(target.with_suffix(".json"), json.dumps(meta, indent=2) + "\n")
    print(f"shipped {target}")
    return target


def plot_learning_curve(rows: list[dict[str, Any]], path: Path, title: str = "") -> Path | None:
    """Val success rate and median nodes against training steps (PNG, atomic)."""
    if not rows:
        return None
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    steps = [r["steps"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.plot(steps, [r["median_nodes"] for r in rows], "o-", color="tab:blue", label="median nodes (val)")
    ax.set_xlabel("training steps")
    ax.set_ylabel("median nodes expanded", color="tab:blue")
    ax2 = ax.twinx()
    ax2.plot(steps, [r["success"] for r in rows], "s--", color="tab:green", label="success (val)")
    ax2.set_ylabel("success rate", color="tab:green")
    ax2.set_ylim(-0.05, 1.05)
    ax.set_title(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------- memory
def sb3_buffer_nbytes(buffer: Any) -> int:
    """Bytes of every numpy array an SB3 rollout/replay buffer holds (what it asked for)."""
    total = 0
    for value in vars(buffer).values():
        if isinstance(value, np.ndarray):
            total += value.nbytes
        elif isinstance(value, dict):
            total += sum(v.nbytes for v in value.values() if isinstance(v, np.ndarray))
    return total


def sb3_buffer_bytes(observation_space: Any, action_dim: int, size: int, n_envs: int, kind: str) -> int:
    """Bytes SB3 2.9 allocates for a Dict-observation buffer, computed from the space (nothing
    allocated): observations in the space's dtypes (float32, int64 ``parent``, int8 ``mask``, ...)
    and float32 actions, plus ``kind="rollout"`` (PPO's ``DictRolloutBuffer``, ``size`` steps per
    env: six float32 per-step arrays) or ``kind="replay"`` (SAC's ``DictReplayBuffer``, ``size``
    transitions in all: next observations too, rewards, dones, timeouts). Checked against real
    buffers in ``tests/test_rl.py``."""
    steps = size * n_envs if kind == "rollout" else max(size // n_envs, 1) * n_envs
    obs = sum(int(np.prod(sub.shape)) * np.dtype(sub.dtype).itemsize for sub in observation_space.spaces.values())
    if kind == "rollout":
        return steps * (obs + 4 * action_dim + 6 * 4)
    return steps * (2 * obs + 4 * action_dim + 3 * 4)


def memory_table(task: str, view_nodes: int, ppo_steps: int = 2048, sac_size: int = 100_000) -> list[dict[str, Any]]:
    """The buffer figures of ``docs/rl.md``: full padding vs the view, PPO rollout and SAC replay."""
    from gnn_mp_envs.envs.wrappers import make_rl_env
    rows = []
    for label, k in (("full padding", None), (f"view {view_nodes}", view_nodes)):
        env = make_rl_env(task, view_nodes=k)
        d = env.action_space.shape[0]
        ppo = sb3_buffer_bytes(env.observation_space, d, ppo_steps, 1, "rollout")
        sac = sb3_buffer_bytes(env.observation_space, d, sac_size, 1, "replay")
        rows.append({"task": task, "observation": label, "ppo_rollout_bytes": ppo, "sac_replay_bytes": sac})
        env.close()
    return rows


def human_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TiB"


def fmt_seconds(s: float) -> str:
    return f"{s / 60:.1f} min" if s >= 90 else f"{s:.0f} s" if math.isfinite(s) else "?"
