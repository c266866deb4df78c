"""The flags of ``gnn-mp train rl`` (one dataclass, CleanRL style) and their checks.

The library scripts (:mod:`train.rl.sb3`, :mod:`train.rl.torchrl`) read top to bottom and share
the evaluation on validation problems (:mod:`train.rl.evaluation`) and the run shell of
:mod:`train.run`. A run directory holds::

    runs/rl/<lib>-<algo>-<task>-seed<S>-<time>/
        config.json          every flag of the run (+ library versions, start time)
        policy.pt (+ .json)  the latest evaluated policy (agents.checkpoints format, weights_only)
        best.pt (+ .json)    the best one on split ``val`` (success rate, then median nodes)
        evaluations.json     one row per evaluation (steps, wall time, success rate, nodes, ...)
        learning_curve.png   val success rate and median nodes against training steps
        tb/                  TensorBoard logs (`tensorboard --logdir runs/`)
"""

from __future__ import annotations

import inspect
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from gnn_mp_envs.envs.tree_env import MAX_NODES_LIMIT
from gnn_mp_envs.envs.wrappers import ACTIONS, RL_MAX_EPISODE_STEPS, make_rl_env
from train.args import (arg, bounded, minutes_float, non_negative_float, non_negative_int, positive_float, positive_int,
                        seed_int, size_int, temperature_float, worker_count)
from train.run import RunFlags

#: The defaults of ``make_rl_env``: the flags of the MDP take them, so a run trains the MDP of the
#: registered RL ids (``GNNMP/<Env>-RLPick-v0``) unless told otherwise.
_ENV_DEFAULTS = {name: p.default for name, p in inspect.signature(make_rl_env).parameters.items()
                 if p.default is not inspect.Parameter.empty}
#: Where the per-task hyperparameter files live (``<task>.yml``, in RL Zoo's format: :func:`read_hyperparams`).
HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"

LIBS = ("sb3", "torchrl")
#: Upper bounds of the candidates' and rewards' scales: beyond them candidates are uniform over the box
#: anyway, or rewards overflow the returns; a larger value is a typo.
MAX_LOCAL_SCALE, MAX_TARGET_SCALE, MAX_REWARD_SCALE = 1e3, 1e2, 1e6
ALGOS = ("ppo", "sac")
#: (lib, algo) -> registry name of the sampler a run's policy becomes
SAMPLER_NAMES = {("sb3", "ppo"): "rl-ppo", ("sb3", "sac"): "rl-sac", ("torchrl", "ppo"): "rl-ppo-torchrl"}


def _widths(text: str) -> list[int]:
    """Comma-separated layer widths; ``""`` or ``none``: no hidden layer."""
    import argparse
    if text.strip().lower() in ("", "none"):
        return []
    from train.args import size_int
    return [size_int(v.strip()) for v in text.split(",") if v.strip()]


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
class RLArgs(RunFlags):
    """Flags of ``gnn-mp train rl`` (CleanRL style: one line of doc per field; the run shell's from
    :class:`train.run.RunFlags`: ``--ship`` copies the final policy)."""

    # --- what to train
    algo: str = arg("ppo", "algorithm", choices=ALGOS)
    lib: str = arg("sb3", "library (torchrl: PPO only)", choices=LIBS)
    task: str = arg("maze2d", "task (any registered task; --import adds your own; BiRRT tasks: the action extends "
                    "active_tree)")
    planner: str | None = arg(None, "planner variant (default: the task's benchmark env; maze2d also birrt)")
    total_steps: int = arg(50_000, "environment steps to train for (all envs together)", parse=positive_int)
    minutes: float | None = arg(None, "wall-time budget of the training loop (evaluations included): the run stops at "
                                "the first rollout after it (it trains one at least), then evaluates once more; without an explicit "
                                "--total-steps, no step limit (the steps reached depend on the machine: the run "
                                "prints them, and --total-steps N repeats them exactly)", parse=minutes_float)
    seed: int = arg(0, "seed of the envs' problem draws, the networks and the evaluation", parse=seed_int)
    hyperparams: Path | None = arg(None, "YAML hyperparameter file in RL Zoo's format (a section per RL env id; "
                                   "gnn-mp: holds the flags RL Zoo has no key for, but never --out, --overwrite, "
                                   "--ship, --resume or --import; explicit flags win); default: the "
                                   "task's shipped train/rl/hyperparams/<task>.yml when there is one; none: no file, "
                                   "the flags' own defaults", metavar="FILE")
    resume: bool = arg(False, "continue the run in --out from its last saved SB3 model (model.zip) or TorchRL "
                       "state (training_state.pt), up to --total-steps")
    device: str = arg("cpu", "torch device of the networks (cpu, cuda, auto: cuda when available)")
    # --- environment (make_rl_env)
    n_envs: int = arg(4, "environments stepped together (vectorised)", parse=worker_count)
    parallel: bool = arg(False, "one process per env (SB3 SubprocVecEnv / TorchRL ParallelEnv; default: serial)")
    ray: str | None = arg(None, "--lib torchrl: collect experience on --ray-workers Ray actors (TorchRL's "
                          "RayCollector), the learner here: no ADDRESS starts a local Ray instance; HOST:PORT, "
                          "ray://HOST:10001 or auto joins a running cluster", metavar="ADDRESS", const="local")
    ray_workers: int = arg(2, "--ray: Ray actors collecting experience, each stepping its share of --n-envs",
                           parse=worker_count)
    view_nodes: int = arg(_ENV_DEFAULTS["view_nodes"], "rows of the tree view the policy sees (roots + most recent "
                          "nodes)", parse=positive_int)
    max_nodes: int | None = arg(None, "tree node budget of the training envs (default: the task's)",
                                parse=bounded(int, 2, False, "an integer >= 2", MAX_NODES_LIMIT))
    action: str = arg(_ENV_DEFAULTS["action"], "what the policy does: pick one of --candidates candidate states "
                      "(Discrete; features relative to the tree) or output a state (box: [-1, 1]^d, --action-frame)",
                      choices=ACTIONS)
    candidates: int = arg(_ENV_DEFAULTS["candidates"], "pick: candidates per step (target, near-target, newest, "
                          "greedy, the rest uniform)", parse=size_int)
    local_scale: float = arg(_ENV_DEFAULTS["local_scale"], "pick: std of the newest/greedy candidates, in extensions",
                             parse=bounded(float, 0, True, "a positive number of extensions", MAX_LOCAL_SCALE))
    target_scale: float = arg(_ENV_DEFAULTS["target_scale"], "pick: std of the near-target candidate, as a "
                              "fraction of the box", parse=bounded(float, 0, True, "a positive fraction of the box",
                                                                   MAX_TARGET_SCALE))
    action_frame: str = arg(_ENV_DEFAULTS["action_frame"], "box: policy actions in [-1, 1] are offsets from the "
                            "active tree's target (target) or the rescaled state box (absolute)",
                            choices=("target", "absolute"))
    step_penalty: float | None = arg(None, "reward: -step_penalty per planner iteration (default: the task's "
                                     "TaskSpec.rl_reward, else RL_REWARD's 0)", parse=non_negative_float)
    node_cost: float | None = arg(None, "reward: -cost per node added (default: the task's, else 1)",
                                  parse=non_negative_float)
    collision_check_cost: float | None = arg(None, "reward: -cost per validity check of the step (default: the "
                                             "task's, else 0)", parse=non_negative_float)
    success_reward: float | None = arg(None, "reward: +success_reward on the step that finds a path (default: the "
                                       "task's, else 10)", parse=non_negative_float)
    progress_reward: float = arg(_ENV_DEFAULTS["progress_reward"], "reward shaping: coef of the potential-based "
                                 "progress term (ProgressReward; 0: the env's reward only)", parse=non_negative_float)
    reward_scale: float = arg(_ENV_DEFAULTS["reward_scale"], "multiply every reward by this (returns of order 1)",
                              parse=bounded(float, 0, True, "a positive number", MAX_REWARD_SCALE))
    # --- networks (the shared TreeEncoder + the library's head)
    hidden_channels: int = arg(32, "TreeEncoder node embedding width", parse=size_int)
    num_layers: int = arg(2, "TreeEncoder message-passing layers", parse=non_negative_int)
    out_channels: int = arg(64, "TreeEncoder graph embedding width", parse=size_int)
    conv: str = arg("sage", "TreeEncoder convolution", choices=("sage", "graph", "gcn", "gatv2"))
    knn: int = arg(0, "TreeEncoder k-NN edges per node (0: tree edges only)", parse=non_negative_int)
    net_arch: list[int] = arg([64, 64], "hidden widths of the value head (box: and of the policy head)")
    pi_arch: list[int] = arg([], "pick: hidden widths of the policy head over the candidate embeddings (none: "
                             "a linear score per candidate slot)", parse=_widths)
    pick_head: str = arg("linear", "pick: the policy's scores: a linear layer with a score per candidate slot, or one "
                         "score shared by the candidates (a bias per slot; with --prior, the prior's scale)",
                         choices=("linear", "shared"))
    candidate_hidden: int = arg(64, "pick: hidden width of the per-candidate MLP", parse=size_int)
    candidate_embed: int = arg(32, "pick: per-candidate embedding width", parse=size_int)
    tree_context: bool = arg(False, "pick: also encode the tree view with a TreeEncoder (sized by the flags above) and "
                             "give its embedding to every candidate")
    prior: Path | None = arg(None, "pick: a candidate prior, the supervised GNN sample scorer (a tree/gnn-scorer "
                             "checkpoint, or NAME for the shipped weights of --task, e.g. gnn on the pendulum): its "
                             "logit of each candidate over the whole tree is a feature, and the policy starts as "
                             "exactly that prior (a linear head, --pi-arch none); PPO learns what to add",
                             metavar="PATH|NAME")
    prior_temperature: float = arg(1.0, "pick: the prior's logits are divided by this", parse=temperature_float)
    prior_scale: float = arg(1.0, "pick --prior --pick-head shared: the head's starting weight on the prior's logits "
                             "(1: the policy starts as the prior; 0: blind to it, PPO learns how far to trust it)",
                             parse=bounded(float, 0, False, "a number in [0, 100]", 100.0))
    encoder: str = arg("tree", "backbone: tree (TreeEncoder, sized by the flags above) or tree-gnn (the supervised GNN "
                       "sampler's causal TreeGNN, its architecture; what --init-from a gnn checkpoint needs)",
                       choices=("tree", "tree-gnn"))
    init_from: Path | None = arg(None, "warm start: copy the backbone weights of this checkpoint (any kind holding "
                                 "one of the same size), or of the shipped weights of a sampler NAME for --task (e.g. "
                                 "gnn with --encoder tree-gnn)", metavar="PATH|NAME")
    # --- optimisation
    lr: float = arg(3e-4, "Adam learning rate", parse=positive_float)
    gamma: float = arg(_ENV_DEFAULTS["gamma"], "discount (and the shaping's gamma)", parse=positive_float)
    batch_size: int = arg(128, "minibatch size", parse=positive_int)
    n_steps: int = arg(256, "PPO: steps per env per rollout", parse=positive_int)
    n_epochs: int = arg(4, "PPO: passes over each rollout", parse=size_int)
    gae_lambda: float = arg(0.95, "PPO: GAE lambda", parse=positive_float)
    clip_range: float = arg(0.2, "PPO: clip range", parse=positive_float)
    ent_coef: float = arg(0.0, "PPO: entropy bonus", parse=non_negative_float)
    log_std_init: float = arg(-2.0, "PPO: initial log std of the Gaussian (actions in [-1, 1]; -2: std 0.135, a "
                              "narrow bias toward the target in the target frame; in [-20, 2], SAC's clamp)",
                              parse=bounded(float, -20.0, False, "a number in [-20, 2]", 2.0))
    buffer_size: int = arg(100_000, "SAC: replay buffer transitions", parse=positive_int)
    learning_starts: int = arg(1000, "SAC: steps before the first update", parse=non_negative_int)
    # --- evaluation, outputs
    eval_every: int = arg(10_000, "evaluate (and checkpoint) every N steps", parse=positive_int)
    eval_problems: int = arg(10, "problems 0..N-1 of split val per evaluation", parse=positive_int)
    select_on: str = arg("nodes", "best.pt: the evaluation with the highest success rate, then the fewest median "
                         "nodes or collision checks", choices=("nodes", "collision_checks"))
    eval_max_steps: int = arg(RL_MAX_EPISODE_STEPS, "planner iterations per evaluation problem (then a failure)",
                              parse=positive_int)
    max_episode_steps: int = arg(RL_MAX_EPISODE_STEPS, "training episodes end (truncated) after this many "
                                 "iterations", parse=positive_int)
    uniform_mix: float | None = arg(None, "probability of a uniform sample instead of the policy's, in training and "
                                    "in the sampler (default: box 0.5, pick 0)", parse=non_negative_float)
    tune_mix: list[float] | None = arg(None, "after training, pick the final policy's uniform_mix among these "
                                       "on split val (e.g. 0.25,0.5,0.75)", parse=_mixes)

    def env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`gnn_mp_envs.envs.wrappers.make_rl_env` (besides task, split)."""
        from agents.rl.run_config import env_kwargs
        return env_kwargs(asdict(self))

    @property
    def sampler_uniform_mix(self) -> float:
        """The uniform mixture of the run's sampler (the flag, else the action's default)."""
        from agents.rl.run_config import sampler_uniform_mix
        return sampler_uniform_mix(asdict(self))

    def candidate_settings(self) -> dict[str, Any]:
        """The run's ``CandidateSet`` configuration (pick): what its env and its sampler use."""
        from agents.rl.run_config import candidate_settings
        return candidate_settings(asdict(self))

    def candidate_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of the pick policy's ``CandidateEncoder.from_space``."""
        from agents.rl.run_config import candidate_kwargs
        return candidate_kwargs(asdict(self))

    def encoder_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``agents.rl.backbones.encoder_from_space`` (the reading of the flags shared
        with whatever rebuilds a run from its ``config.json``: :mod:`agents.rl.run_config`)."""
        from agents.rl.run_config import encoder_kwargs
        return encoder_kwargs(asdict(self))

    @property
    def sampler_name(self) -> str:
        return SAMPLER_NAMES[(self.lib, self.algo)]


@dataclass
class RunResult:
    """What a training script returns."""

    run_dir: Path                       # the run directory
    best: Path                          # the best policy on split val (best.pt)
    steps: int                          # environment steps trained
    train_seconds: float                # wall time of the training loop (evaluations included)
    buffer_bytes: int                   # SB3: the rollout/replay buffer's arrays; TorchRL: one batch
    evaluations: list[dict[str, Any]]   # the rows of evaluations.json


def check_args(args: RLArgs) -> None:
    """One-line ``ValueError`` for combinations that cannot run."""
    from gnn_mp_envs.registration import task_spec
    from train.args import import_modules
    import_modules(args.modules)
    if (args.lib, args.algo) not in SAMPLER_NAMES:
        raise ValueError(f"--lib {args.lib} --algo {args.algo} is not available "
                         f"(available: {', '.join(f'{l}/{a}' for l, a in SAMPLER_NAMES)})")
    spec = task_spec(args.task)
    env_id = spec.env_id_for(args.planner)
    max_nodes = args.max_nodes if args.max_nodes is not None else spec.max_nodes
    if max_nodes < spec.num_trees(env_id) + 2:
        raise ValueError(f"--max-nodes {max_nodes}: the tree needs room for its {spec.num_trees(env_id)} root(s) "
                         f"and at least 2 more nodes")
    if not 2 <= args.view_nodes <= max_nodes:
        raise ValueError(f"--view-nodes must be in [2, {max_nodes}] (the tree's node budget), got {args.view_nodes}")
    check_memory(args)
    for name, value in (("--gamma", args.gamma), ("--gae-lambda", args.gae_lambda), ("--uniform-mix", args.uniform_mix)):
        if value is not None and not 0.0 <= value <= 1.0:
            raise ValueError(f"{name} must be in [0, 1], got {value}")
    if args.action == "pick":
        from gnn_mp_envs.envs.candidates import CANDIDATE_KINDS
        if args.algo == "sac":
            raise ValueError("--algo sac acts in a box: use --action box (pick is a Discrete action, for PPO)")
        if args.candidates < len(CANDIDATE_KINDS):
            raise ValueError(f"--candidates must be >= {len(CANDIDATE_KINDS)} (one of each kind: "
                             f"{', '.join(CANDIDATE_KINDS)}), got {args.candidates}")
        if args.encoder != "tree" or args.init_from is not None:
            raise ValueError("--encoder tree-gnn and --init-from warm-start a box policy's tree encoder; a picker "
                             "(--action pick) reads candidate features (--tree-context adds a TreeEncoder, --prior "
                             "the supervised scorer's logits)")
        if args.pick_head == "shared" and args.pi_arch:
            raise ValueError(f"--pick-head shared scores the candidate embeddings directly; got --pi-arch "
                             f"{','.join(map(str, args.pi_arch))} (use --pi-arch none)")
        if args.prior is not None:
            if args.pi_arch:
                raise ValueError(f"--prior: the policy head is linear, so that it starts as the prior; got --pi-arch "
                                 f"{','.join(map(str, args.pi_arch))} (use --pi-arch none)")
            from agents.checkpoints import read_checkpoint
            args.prior = init_from_path(args.prior, args.task, flag="--prior")
            kind = read_checkpoint(args.prior)["kind"]     # a CheckpointError names the file and what is wrong
            if kind != "tree/gnn-scorer":
                raise ValueError(f"--prior {args.prior}: a {kind} checkpoint; the prior is a GNN sample scorer "
                                 "(tree/gnn-scorer: the pendulum's shipped gnn)")
        if args.prior_scale != 1.0 and (args.prior is None or args.pick_head != "shared"):
            raise ValueError(f"--prior-scale {args.prior_scale:g} is the shared head's starting weight on a prior: it "
                             "needs --prior and --pick-head shared")
    elif args.tree_context or args.prior is not None:
        raise ValueError("--tree-context and --prior are a picker's (--action pick); a box policy always reads the tree")
    if args.device not in ("cpu", "cuda", "auto") and not args.device.startswith("cuda:"):
        raise ValueError(f"--device must be cpu, cuda, cuda:N or auto, got {args.device!r}")
    if args.resume and args.out is None:
        raise ValueError("--resume needs --out RUN_DIR (the run to continue)")
    if args.ray is not None:
        if args.lib != "torchrl":
            raise ValueError("--ray collects with TorchRL's RayCollector: use --lib torchrl")
        if args.parallel:
            raise ValueError("--ray and --parallel both place the envs in other processes: choose one")
        if args.ray_workers > args.n_envs:
            raise ValueError(f"--ray-workers {args.ray_workers} > --n-envs {args.n_envs}: every actor steps at "
                             "least one env")
        if args.n_envs % args.ray_workers:      # TorchRL's RayCollector stacks the actors' batches: equal shapes
            raise ValueError(f"--n-envs {args.n_envs} does not split evenly over --ray-workers {args.ray_workers}: "
                             "every actor steps the same number of envs (--n-envs a multiple of --ray-workers)")
        if args.ray != "local":
            from train.args import UsageError, check_ray_address
            try:
                check_ray_address(args.ray)
            except UsageError as exc:
                raise ValueError(str(exc)) from None
    if args.clip_range >= 1.0:
        raise ValueError(f"--clip-range must be in (0, 1), got {args.clip_range}")
    if not args.net_arch or any(w < 1 or w > 65536 for w in args.net_arch):
        raise ValueError(f"--net-arch needs widths in [1, 65536], got {args.net_arch}")
    if args.algo == "ppo" and args.n_steps * args.n_envs < 2:
        raise ValueError(f"PPO needs at least 2 steps per rollout (--n-steps x --n-envs), got "
                         f"{args.n_steps} x {args.n_envs}")
    if args.algo == "sac":
        per_transition = 2 * 4 * args.view_nodes * 16            # observation and next one, float32, ~16 values a row
        if args.buffer_size * per_transition > memory_bytes() // 2:
            raise ValueError(f"--buffer-size {args.buffer_size:,} x --view-nodes {args.view_nodes} needs about "
                             f"{args.buffer_size * per_transition / 2**30:.1f} GiB, more than half this machine's memory")
    if args.init_from is not None:
        from agents.checkpoints import read_checkpoint
        args.init_from = init_from_path(args.init_from, args.task)
        read_checkpoint(args.init_from)        # a CheckpointError (a ValueError) names the file and what is wrong


#: The least one observation row of the tree view takes (a parent index, a mask byte, float32 position and
#: feature columns of a 2-D task), and one evaluation run's record.
ROW_BYTES, RUN_BYTES = 8 + 1 + 4 * (2 + 5), 1024


def check_memory(args: RLArgs) -> None:
    """Counts whose arrays could not fit on this machine, refused in one line (a ``ValueError``) before
    any work: a PPO rollout (``--n-steps`` x ``--n-envs`` observations of ``--view-nodes`` rows), the
    records of an evaluation, a linear pick head (``--candidates`` scores over ``--candidates`` x
    ``--candidate-embed`` features, with its gradients and Adam's two moments)."""
    from train.args import UsageError, check_fits_in_memory
    try:
        if args.algo == "ppo":
            check_fits_in_memory("--n-steps x --n-envs", args.n_steps * args.n_envs, args.view_nodes * ROW_BYTES,
                                 f"rollout steps (observations of --view-nodes {args.view_nodes} rows)")
        check_fits_in_memory("--eval-problems", args.eval_problems, RUN_BYTES, "evaluation runs")
        if args.action == "pick" and args.pick_head == "linear":
            check_fits_in_memory("--candidates x --candidates x --candidate-embed",
                                 args.candidates ** 2 * args.candidate_embed, 4 * 4,
                                 "weights of the linear pick head (float32, with gradients and Adam's moments)")
    except UsageError as exc:
        raise ValueError(str(exc)) from None


def torch_device(name: str) -> str:
    """``--device`` as a torch device string (``auto``: cuda when available, else cpu)."""
    if name == "auto":
        import torch
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


def hyperparams_file(args: RLArgs) -> Path | None:
    """The YAML file a run reads: ``--hyperparams``, else the task's shipped one (None: none, also for
    ``--hyperparams none``)."""
    if args.hyperparams is not None:
        return None if str(args.hyperparams).lower() == "none" else Path(args.hyperparams)
    shipped = HYPERPARAMS_DIR / f"{args.task}.yml"
    return shipped if shipped.is_file() else None


#: The section of a hyperparameter file RL Zoo does not read: ``algo`` (what its env sections are for,
#: ``rl_zoo3.train --algo``) and the flags of ``gnn-mp train rl`` RL Zoo has no key for.
OWN_SECTION = "gnn-mp"
#: RL Zoo's keys of an env section -> the flags they are.
ZOO_KEYS = {"n_timesteps": "total_steps", "learning_rate": "lr", "n_envs": "n_envs", "n_steps": "n_steps",
            "batch_size": "batch_size", "n_epochs": "n_epochs", "ent_coef": "ent_coef", "clip_range": "clip_range",
            "gamma": "gamma", "gae_lambda": "gae_lambda", "buffer_size": "buffer_size",
            "learning_starts": "learning_starts"}
#: ``env_kwargs`` of an env section: keywords of ``make_rl_env`` that are flags of the same name.
ZOO_ENV_KWARGS = ("view_nodes", "max_nodes", "candidates", "local_scale", "target_scale", "action_frame",
                  "uniform_mix", "progress_reward", "reward_scale", "max_episode_steps", "step_penalty", "node_cost",
                  "collision_check_cost", "success_reward")
#: ``policy_kwargs.features_extractor_kwargs`` of an env section -> flags.
ZOO_EXTRACTOR_KWARGS = {"hidden": "candidate_hidden", "embed": "candidate_embed", "tree_context": "tree_context",
                        "hidden_channels": "hidden_channels", "num_layers": "num_layers",
                        "out_channels": "out_channels", "conv": "conv", "knn": "knn"}
#: RL Zoo's ``policy`` of a picker and of a box policy.
ZOO_POLICIES = ("agents.rl.sb3.CandidatePickPolicy", "MultiInputPolicy")


def _mapping(path: Path, value: Any, where: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ValueError(f"--hyperparams {path}: {where} is not a mapping")
    return value


def _zoo_values(path: Path, name: str, section: dict) -> dict[str, Any]:
    """An RL Zoo env section as flag values (RL Zoo's keys this command has a flag for)."""
    out: dict[str, Any] = {}
    for key, value in section.items():
        if key in ZOO_KEYS:
            out[ZOO_KEYS[key]] = value
        elif key == "policy":
            if value not in ZOO_POLICIES:
                raise ValueError(f"--hyperparams {path}: policy {value!r} in section {name!r}; gnn-mp train rl builds "
                                 f"{' or '.join(ZOO_POLICIES)} (from --action)")
        elif key == "env_kwargs":
            for k, v in _mapping(path, value, f"{name}.env_kwargs").items():
                if k not in ZOO_ENV_KWARGS:
                    raise ValueError(f"--hyperparams {path}: unknown key {k!r} in {name}.env_kwargs (known: "
                                     f"{', '.join(ZOO_ENV_KWARGS)})")
                out[k] = v
        elif key == "policy_kwargs":
            for k, v in _mapping(path, value, f"{name}.policy_kwargs").items():
                if k == "net_arch" and isinstance(v, dict):      # a picker's: {pi: [...], vf: [...]}
                    unknown = sorted(set(v) - {"pi", "vf"})
                    if unknown:
                        raise ValueError(f"--hyperparams {path}: unknown key {unknown[0]!r} in {name}.policy_kwargs."
                                         "net_arch (pi, vf)")
                    out.update({flag: v[k2] for k2, flag in (("pi", "pi_arch"), ("vf", "net_arch")) if k2 in v})
                elif k in ("net_arch", "pick_head", "log_std_init"):
                    out[k] = v
                elif k == "features_extractor_kwargs":
                    for k2, v2 in _mapping(path, v, f"{name}.policy_kwargs.{k}").items():
                        if k2 not in ZOO_EXTRACTOR_KWARGS:
                            raise ValueError(f"--hyperparams {path}: unknown key {k2!r} in {name}.policy_kwargs."
                                             f"{k} (known: {', '.join(ZOO_EXTRACTOR_KWARGS)})")
                        out[ZOO_EXTRACTOR_KWARGS[k2]] = v2
                else:
                    raise ValueError(f"--hyperparams {path}: unknown key {k!r} in {name}.policy_kwargs (known: "
                                     "net_arch, pick_head, log_std_init, features_extractor_kwargs)")
        else:
            raise ValueError(f"--hyperparams {path}: unknown key {key!r} in section {name!r} (RL Zoo's keys gnn-mp "
                             f"reads: policy, {', '.join(ZOO_KEYS)}, env_kwargs, policy_kwargs)")
    return out


#: Flags a hyperparameter file never gives: where the run writes, what it overwrites, continues or ships
#: into the package, what code it imports. They come from the command line only (a file is refused).
COMMAND_LINE_ONLY = {"out": "--out", "overwrite": "--overwrite", "ship": "--ship", "resume": "--resume",
                     "modules": "--import", "hyperparams": "--hyperparams"}


def _flag_values(path: Path, values: dict, name: str, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """A section of flag values (field names; dashes accepted)."""
    import dataclasses
    fields = {f.name for f in dataclasses.fields(RLArgs)} - {"lib", "algo", "task"} - set(COMMAND_LINE_ONLY)
    out = {}
    for key, value in values.items():
        if key in skip:
            continue
        flag = {"n_timesteps": "total_steps", "learning_rate": "lr", "import": "modules"}.get(
            str(key), str(key).replace("-", "_"))
        if flag in COMMAND_LINE_ONLY:
            raise ValueError(f"--hyperparams {path}: {key!r} in section {name!r} is refused: {COMMAND_LINE_ONLY[flag]} "
                             "is a command-line flag only (a file never chooses where a run writes, what it "
                             "overwrites or ships, or what it imports)")
        if flag not in fields:
            raise ValueError(f"--hyperparams {path}: unknown key {key!r} in section {name!r}")
        out[flag] = value
    return out


def read_hyperparams(path: Path, lib: str, algo: str, task: str, planner: str | None = None,
                     action: str = "pick") -> dict[str, Any]:
    """The flag values a YAML hyperparameter file gives a run; one-line ``ValueError`` otherwise.

    The file is in RL Zoo's format (``rl_zoo3.train -conf FILE`` trains from it): a section per RL
    env id of RL Zoo's keys (:data:`ZOO_KEYS`, ``policy``, ``env_kwargs``, ``policy_kwargs``), for
    the algorithm its section ``gnn-mp:`` names (``algo``, default ppo; a run of another algorithm
    reads nothing), which also holds this command's flags RL Zoo has no key for. The run reads the
    section of its own env id (``--planner``, ``--action``), else the one of the task's default
    picker id. A file in the earlier layout, a section per ``<lib>-<algo>`` of flag values, is still
    read (that section)."""
    import yaml

    from gnn_mp_envs.registration import rl_env_id, task_spec
    path = Path(path)
    if path.exists() and not path.is_file():
        raise ValueError(f"--hyperparams {path}: not a regular file")
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"--hyperparams {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"--hyperparams {path}: cannot be read ({type(exc).__name__})") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"--hyperparams {path}: not YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--hyperparams {path}: expected a mapping of sections (RL Zoo's: an env id, e.g. "
                         f"GNNMP/Maze2DRRT-RLPick-v0:), got {type(data).__name__}")
    legacy = f"{lib}-{algo}"
    if any(f"{l}-{a}" in data for l in LIBS for a in ALGOS):
        return _flag_values(path, _mapping(path, data.get(legacy), f"section {legacy!r}"), legacy)
    own = _mapping(path, data.get(OWN_SECTION), f"section {OWN_SECTION!r}")
    if own.get("algo", "ppo") not in ALGOS:
        raise ValueError(f"--hyperparams {path}: {OWN_SECTION}.algo must be one of {', '.join(ALGOS)}, got "
                         f"{own.get('algo')!r}")
    if own.get("algo", "ppo") != algo:
        return {}
    sections = {k: v for k, v in data.items() if k != OWN_SECTION}
    values: dict[str, Any] = {}
    if sections:
        spec = task_spec(task)
        candidates = [rl_env_id(spec.env_id_for(planner), action), rl_env_id(spec.env_id, "pick")]
        name = next((k for k in candidates if k in sections), None)
        if name is None:
            raise ValueError(f"--hyperparams {path}: no section for task {task!r} ({candidates[0]}); the file has "
                             f"{', '.join(map(str, sections))}")
        values = _zoo_values(path, name, _mapping(path, sections[name], f"section {name!r}"))
    flags = _flag_values(path, own, OWN_SECTION, skip=("algo",))
    twice = sorted(set(values) & set(flags))
    if twice:
        raise ValueError(f"--hyperparams {path}: {twice[0]} is given both in RL Zoo's section and in {OWN_SECTION}:")
    return {**values, **flags}


def init_from_path(value: str | Path, task: str, flag: str = "--init-from") -> Path:
    """``--init-from`` (or ``--prior``): a checkpoint file, or the name of a sampler whose shipped weights
    for ``task`` exist (``gnn`` -> ``agents/checkpoints/gnn_<task>.pt``: works from any directory,
    unlike a path into the checkout)."""
    from agents.checkpoints import SHIPPED_DIR, shipped_checkpoint
    path = Path(value)
    if path.is_file():
        return path.resolve()           # stored absolute: a resumed run or PPO.load elsewhere finds it
    if "/" not in str(value) and shipped_checkpoint(str(value), task).is_file():
        return shipped_checkpoint(str(value), task)
    names = sorted(p.stem[:-len(task) - 1] for p in SHIPPED_DIR.glob(f"*_{task}.pt"))
    raise ValueError(f"{flag} {value}: no such file, nor shipped weights of that name for task {task!r} "
                     f"(shipped: {', '.join(names) or 'none'})")


def memory_bytes() -> int:
    """Physical memory of this machine (bytes)."""
    import os
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


#: Flags a resumed run may change: the step budget, where and how it runs, what it reports.
RESUME_FREE_FLAGS = ("total_steps", "minutes", "resume", "overwrite", "ship", "threads", "progress", "out", "device",
                     "parallel", "modules", "ray", "ray_workers",
                     "hyperparams")      # the file's path (the checkout may have moved); its values are compared


def run_config(args: RLArgs) -> dict[str, Any]:
    """What ``config.json`` records: every flag, the library versions and the start time."""
    import time
    from dataclasses import asdict

    import stable_baselines3
    import torch
    import torchrl
    return {**asdict(args), "versions": {"torch": torch.__version__, "torchrl": torchrl.__version__,
                                         "stable_baselines3": stable_baselines3.__version__},
            "started": time.strftime("%Y-%m-%dT%H:%M:%S")}


__all__ = ["ALGOS", "HYPERPARAMS_DIR", "LIBS", "RESUME_FREE_FLAGS", "SAMPLER_NAMES", "RLArgs", "RunResult", "check_args",
           "hyperparams_file", "OWN_SECTION", "read_hyperparams", "run_config", "torch_device", "ZOO_KEYS"]
