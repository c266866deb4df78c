"""Train a Stable-Baselines3 PPO or SAC sampler on a tree environment.

    gnn-mp train rl --lib sb3 --algo ppo --task maze2d --total-steps 50000
    gnn-mp train rl --lib sb3 --algo sac --task pendulum --total-steps 20000

Read top to bottom: flags (``train.rl.args.RLArgs``, one dataclass) -> vectorised
``make_rl_env`` envs (tree view of ``--view-nodes`` rows, actions in [-1, 1]) -> PPO or SAC with
``TreeFeaturesExtractor`` (the shared ``TreeEncoder``) -> optional warm start of the encoder
(``--init-from``) -> ``learn`` with a progress bar and an evaluation callback (split ``val``,
every ``--eval-every`` steps: checkpoint ``policy.pt``/``best.pt`` in the one checkpoint format,
``evaluations.json``, TensorBoard scalars) -> learning curve, optional ``--tune-mix`` and
``--ship``. Outputs go to a run directory (see :mod:`train.rl.args`).
"""

from __future__ import annotations

import time
from dataclasses import asdict

import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from tqdm import tqdm

from agents.checkpoints import CheckpointError
from agents.rl.pick import set_prior_scale
from agents.rl.policies import policy_from_sb3, warm_start_encoder
from agents.rl.sb3 import CandidatePickPolicy
from agents.rl.sb3_files import SB3Zip, read_sb3_zip, sb3_policy_kwargs
from gnn_mp_envs.envs.wrappers import make_rl_env
from train.args import MAX_COUNT
from train.rl.args import RESUME_FREE_FLAGS, RLArgs, RunResult, check_args, run_config, torch_device
from train.rl.evaluation import Evaluator
from train.rl.memory import sb3_buffer_nbytes
from train.run import RunError, TrainingRun, non_finite_policy
from train.workers import WithPlugins


class EvalCallback(BaseCallback):
    """Every ``--eval-every`` steps: evaluate on split val, checkpoint (and ``model.zip``), log to TensorBoard."""

    def __init__(self, evaluator: Evaluator, run: TrainingRun) -> None:
        super().__init__()
        self.evaluator, self.run = evaluator, run
        self.rollout_starts, self.rollouts, self.stopped_at = False, 0, None

    def _on_training_start(self) -> None:
        self._on_step()   # the untrained policy: the learning curve's first point

    def _on_rollout_start(self) -> None:
        self.rollout_starts = True
        self.rollouts += 1

    def _on_step(self) -> bool:
        if self.rollout_starts:
            self.rollout_starts = False
            # --minutes: stop before this rollout (its first env step is not trained on); one rollout at least
            if self.rollouts > 1 and self.evaluator.time_up():
                self.stopped_at = self.num_timesteps - self.training_env.num_envs
                return False
        if self.evaluator.due(self.num_timesteps):
            row = self.evaluator(self.num_timesteps)
            self.model.save(self.run.path("model.zip"))
            self.logger.dump(self.num_timesteps)
            lead = "\n" if self.evaluator.args.progress else ""   # below the progress bar
            print(f"{lead}  step {row['steps']:>7}: val success {row['success_rate']:.2f}, "
                  f"median nodes {row['median_nodes']:.0f} ({row['eval_wall_s']:.0f} s)", flush=True)
        return True


class ProgressCallback(BaseCallback):
    """A tqdm bar over environment steps (SB3's own needs ``rich``)."""

    def __init__(self, total: int | None) -> None:
        super().__init__()
        self.total, self.bar = total, None

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, unit="step", dynamic_ncols=True)

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self.bar.n)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


def policy_kwargs_of(args: RLArgs) -> dict:
    """SB3's ``policy_kwargs``: the candidate extractor with the picker's head (``pick``,
    :class:`~agents.rl.sb3.CandidatePickPolicy`) or the tree encoder with a Gaussian head (``box``);
    the reading of the flags an SB3 zip is rebuilt with too (:func:`agents.rl.sb3_files.sb3_policy_kwargs`)."""
    return sb3_policy_kwargs(asdict(args))


def read_resume_zip(path: Path, device: str) -> SB3Zip:
    """The tensors and plain JSON of the run's ``model.zip`` (:func:`agents.rl.sb3_files.read_sb3_zip`),
    read before the environments are made: a damaged file is refused before their processes start."""
    try:
        return read_sb3_zip(path, device=device)
    except (CheckpointError, OSError, ValueError, KeyError, RuntimeError) as exc:
        raise RunError(f"--resume: {path} does not hold this run's model ({str(exc).splitlines()[0]})") from None


def load_weights_only(model: PPO | SAC, path: Path, contents: SB3Zip) -> None:
    """Continue ``model`` from the SB3 ``.zip`` at ``path`` (read by :func:`read_resume_zip`) without
    unpickling anything: the policy's and the optimizers' tensors and the step count from the plain JSON
    of its ``data`` member; the pickled entries of ``data`` (policy keywords, spaces, schedules), which
    could run code, are never loaded: the model was built from the run's own flags, checked against its
    ``config.json``."""
    from stable_baselines3.common.save_util import recursive_setattr
    try:
        model.set_parameters(contents.params, exact_match=True, device=model.device)
        for name, tensor in (contents.variables or {}).items():   # SAC's entropy coefficient, as SB3's load does
            recursive_setattr(model, f"{name}.data", tensor.data)
    except (CheckpointError, OSError, ValueError, KeyError, RuntimeError) as exc:
        raise RunError(f"--resume: {path} does not hold this run's model ({str(exc).splitlines()[0]})") from None
    steps = contents.num_timesteps
    if steps is None:
        raise RunError(f"--resume: {path} holds no step count")
    model.num_timesteps = steps
    updates = contents.data.get("_n_updates", 0)
    model._n_updates = updates if isinstance(updates, int) and not isinstance(updates, bool) else 0


def build_model(args: RLArgs, env, run_dir) -> PPO | SAC:
    """PPO or SAC over the env with the tree encoder (or the candidate extractor) as features extractor."""
    policy_kwargs = policy_kwargs_of(args)
    common = {"learning_rate": args.lr, "gamma": args.gamma, "batch_size": args.batch_size, "seed": args.seed,
              "device": torch_device(args.device), "tensorboard_log": str(run_dir / "tb"), "verbose": 0}
    if args.algo == "ppo":
        policy = CandidatePickPolicy if args.action == "pick" else "MultiInputPolicy"
        return PPO(policy, env, n_steps=args.n_steps, n_epochs=args.n_epochs,
                   gae_lambda=args.gae_lambda, clip_range=args.clip_range, ent_coef=args.ent_coef,
                   policy_kwargs=policy_kwargs, **common)
    return SAC("MultiInputPolicy", env, buffer_size=args.buffer_size, learning_starts=args.learning_starts,
               policy_kwargs=policy_kwargs, **common)


def encoders_of(model: PPO | SAC) -> list:
    """Every encoder of a model (PPO: the shared one; SAC: actor, critic, target critic)."""
    return [m for m in model.policy.modules() if type(m).__name__ in ("TreeEncoder", "TreeGNNEncoder")]


def train(args: RLArgs) -> RunResult:
    check_args(args)
    torch.set_num_threads(args.threads)
    run = TrainingRun.create("rl", f"sb3-{args.algo}-{args.task}", args.seed, out=args.out, overwrite=args.overwrite,
                             resume=args.resume)
    if args.resume and not run.path("model.zip").is_file():
        raise RunError(f"--resume: {run.dir} holds no SB3 model (model.zip) to continue")
    if args.resume:
        run.check_resumed_flags(asdict(args), RESUME_FREE_FLAGS)
    run.write_config(run_config(args), "config.json" if not args.resume else "config_resumed.json")
    resumed = read_resume_zip(run.path("model.zip"), torch_device(args.device)) if args.resume else None

    # 1. environments: n_envs copies of make_rl_env (the registered RL ids' MDP), seeded
    env_kwargs = {"task": args.task, "split": "train", **args.env_kwargs()}
    # WithPlugins: SubprocVecEnv's processes import the --import modules (a task of the user's) first
    vec_env = make_vec_env(WithPlugins(make_rl_env), n_envs=args.n_envs, seed=args.seed, env_kwargs=env_kwargs,
                           vec_env_cls=SubprocVecEnv if args.parallel else DummyVecEnv)

    # 2. the agent (or the saved one, --resume), the optional warm start of its encoder(s)
    if args.resume:
        model = build_model(args, vec_env, run.dir)          # the run's architecture, from its (checked) flags
        load_weights_only(model, run.path("model.zip"), resumed)
        print(f"resuming {run.dir} at step {model.num_timesteps:,}")
    else:
        model = build_model(args, vec_env, run.dir)
        if args.prior is not None:       # CandidatePickPolicy starts its head as the prior (--prior-scale: its weight)
            set_prior_scale(model.policy, args.prior_scale)
            print(f"the policy starts as the prior's logits ({args.prior}, temperature {args.prior_temperature})"
                  if args.prior_scale == 1.0 else f"the policy reads the prior's logits ({args.prior}, temperature "
                  f"{args.prior_temperature}) at a starting weight of {args.prior_scale:g}")
    if args.init_from is not None and not args.resume:
        try:
            source = warm_start_encoder(args.init_from, *encoders_of(model))
        except ValueError as exc:        # no backbone of this run's size in the file
            raise RunError(f"--init-from: {exc}") from None
        print(f"encoder initialised from {args.init_from} ({source})")
    buffer = model.rollout_buffer if args.algo == "ppo" else model.replay_buffer
    buffer_bytes = sb3_buffer_nbytes(buffer)
    print(f"{args.algo.upper()} on {args.task}: {sum(p.numel() for p in model.policy.parameters()):,} parameters, "
          f"{'rollout' if args.algo == 'ppo' else 'replay'} buffer {tqdm.format_sizeof(buffer_bytes, 'B', 1024)}, "
          f"run directory {run.dir}")

    # 3. evaluation on split val (the policy exported to the sampler the benchmark runs)
    def log(name: str, value: float, step: int) -> None:
        model.logger.record(name, value)

    def save_best(steps: int) -> None:      # SB3's own format beside best.pt (PPO.load reads it)
        model.save(run.path("best_model.zip"))

    candidates = args.candidate_settings() if args.action == "pick" else None
    evaluator = Evaluator(args, run, lambda: policy_from_sb3(model), log=log, candidates=candidates,
                          on_best=save_best)
    if args.resume:
        evaluator.restore()

    # 4. learn (the model saved as model.zip at every evaluation: what --resume continues)
    bar_total = None if args.total_steps >= MAX_COUNT else args.total_steps      # --minutes alone: no step limit
    callbacks = [EvalCallback(evaluator, run)] + ([ProgressCallback(bar_total)] if args.progress else [])
    started = time.perf_counter()
    remaining = max(args.total_steps - model.num_timesteps, 0)
    try:
        model.learn(total_timesteps=remaining, callback=callbacks, tb_log_name=f"{args.algo}_{args.task}",
                    reset_num_timesteps=not args.resume)
    except ValueError as exc:            # torch refuses a distribution over NaN parameters
        error = non_finite_policy(exc, args.lr)
        if error is None:
            raise
        raise error from None
    train_time = time.perf_counter() - started
    if callbacks[0].stopped_at is not None:      # --minutes: the steps trained on, what --total-steps repeats
        model.num_timesteps = callbacks[0].stopped_at
        print(evaluator.stopped_note(model.num_timesteps))

    # 5. final evaluation, learning curve, --tune-mix, --ship
    best = evaluator.finish(model.num_timesteps)
    model.save(run.path("model.zip"))
    vec_env.close()
    print(f"trained {model.num_timesteps:,} steps in {tqdm.format_interval(train_time)}; policy {best}")
    return RunResult(run.dir, best, int(model.num_timesteps), train_time, buffer_bytes, evaluator.rows)
