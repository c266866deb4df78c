"""Train a TorchRL PPO sampler on a tree environment.

    gnn-mp train rl --lib torchrl --algo ppo --task maze2d --total-steps 50000

Read top to bottom: flags (``train.rl.args.RLArgs``) -> a batched env (``SerialEnv``, or
``ParallelEnv`` with ``--parallel``) of ``GymWrapper(make_rl_env(...))`` (tree view of
``--view-nodes`` rows, actions in [-1, 1]) -> ``ProbabilisticActor`` and value head over the
shared ``TreeEncoder`` (:mod:`agents.rl.torchrl`) -> ``Collector`` -> GAE + ``ClipPPOLoss``,
``--n-epochs`` passes of minibatches per batch -> TensorBoard logger, periodic evaluation on
split ``val`` with checkpoints (the policy exported to the sampler ``rl-ppo-torchrl``).
"""

from __future__ import annotations

import math
import multiprocessing
import signal
import threading
import time
from dataclasses import asdict
from functools import partial

import torch
from torchrl.collectors import Collector
from torchrl.envs import GymWrapper, ParallelEnv, SerialEnv
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE
from torchrl.record.loggers import TensorboardLogger

from tqdm import tqdm

from agents.checkpoints import CheckpointError, load_training_state, save_training_state
from agents.rl.pick import set_prior_scale
from agents.rl.policies import policy_from_torchrl, warm_start_encoder
from agents.rl.torchrl import make_actor, make_pick_actor, make_pick_value, make_value
from gnn_mp_envs.envs.wrappers import make_rl_env
from train.args import MAX_COUNT
from train.rl.args import RESUME_FREE_FLAGS, RLArgs, RunResult, check_args, run_config, torch_device
from train.rl.evaluation import Evaluator
from train.run import RunError, TrainingRun, non_finite_policy
from train.workers import WithPlugins, start_ray


def keep_threads(threads: int) -> None:
    """Put torch back to the run's ``--threads``: closing a TorchRL batched env raises the process's
    thread count (``torchrl/envs/batched_envs.py``, ``close``), which made training 2.5x slower."""
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


def make_env(args: RLArgs, seed: int) -> GymWrapper:
    """One training env: ``make_rl_env`` (the registered RL ids' MDP) as a TorchRL env, seeded; a
    picker's ``Discrete`` action as an integer (``categorical_action_encoding``)."""
    env = GymWrapper(make_rl_env(args.task, split="train", **args.env_kwargs()),
                     categorical_action_encoding=args.action == "pick")
    env.set_seed(seed)
    return env


def start_workers_deaf_to_ctrl_c(env, workers: int) -> None:
    """``env.start()`` with Ctrl-C ignored only while its ``workers`` processes are spawned.

    SIGINT's ``SIG_IGN`` survives a worker's exec (a Python handler or a blocked mask does not),
    so the workers never see Ctrl-C; this process alone does, exits 130 with one line and kills
    them (``train.cli.exit_now``), instead of every worker printing a traceback (and one, now and
    then, hanging the exit). The start runs on a helper thread: as soon as the workers exist
    (``multiprocessing.active_children``), Ctrl-C works here again, also while they import and
    build their envs (seconds)."""
    before = set(multiprocessing.active_children())     # children of earlier work may exit meanwhile
    spawned: set = set()     # new children seen so far (one may exit before the next is spawned)
    failure: list[BaseException] = []

    def start() -> None:
        try:
            env.start()
        except BaseException as exc:        # re-raised on the calling thread
            failure.append(exc)

    starter = threading.Thread(target=start, name="env workers start", daemon=True)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        starter.start()
        while starter.is_alive():
            spawned |= set(multiprocessing.active_children()) - before
            if len(spawned) >= workers:
                break
            time.sleep(0.005)
    finally:
        signal.signal(signal.SIGINT, previous)
    while starter.is_alive():
        starter.join(0.1)                   # interruptible: Ctrl-C raises KeyboardInterrupt here
    if failure:
        raise failure[0]


def make_batched_env(args: RLArgs):
    """``n_envs`` training envs stepped together; env ``i`` draws problems from seed ``seed + i``.
    ``--parallel``: the workers start here, deaf to Ctrl-C (:func:`start_workers_deaf_to_ctrl_c`)."""
    fns = [WithPlugins(partial(make_env, args, args.seed + i)) for i in range(args.n_envs)]   # --import in workers
    if not args.parallel:
        return SerialEnv(args.n_envs, fns)
    env = ParallelEnv(args.n_envs, fns)
    start_workers_deaf_to_ctrl_c(env, args.n_envs)
    return env


def make_env_group(args: RLArgs, seeds: list[int]) -> SerialEnv:
    """The envs of seeds ``seeds`` stepped together (one Ray actor's share of ``--n-envs``)."""
    return SerialEnv(len(seeds), [WithPlugins(partial(make_env, args, s)) for s in seeds])   # --import in actors


def make_collector(args: RLArgs, env, actor, frames_per_batch: int, total_frames: int):
    """TorchRL's ``Collector`` over the local batched env, or with ``--ray`` a ``RayCollector``:
    ``--ray-workers`` actors, actor ``w`` stepping envs ``w, w + workers, ...`` of ``--n-envs`` (the same
    seeds as a local run), a synchronous batch of ``frames_per_batch`` frames, the policy's weights
    sent to the actors after every update."""
    if args.ray is None:
        return Collector(env, actor, frames_per_batch=frames_per_batch, total_frames=total_frames,
                         auto_register_policy_transforms=False)
    import ray
    from torchrl.collectors.distributed import RayCollector
    local = args.ray == "local"
    groups = [[args.seed + i for i in range(w, args.n_envs, args.ray_workers)] for w in range(args.ray_workers)]
    init = {"address": None if local else args.ray, "include_dashboard": False, "log_to_driver": False,
            "configure_logging": False, **({"num_cpus": args.ray_workers} if local else {})}
    try:
        started = not ray.is_initialized()
        if started:                      # from an empty directory: the actors import nothing of the current one
            start_ray(**init)
        collector = RayCollector([WithPlugins(partial(make_env_group, args, g)) for g in groups], actor,
                                 frames_per_batch=frames_per_batch, total_frames=total_frames, sync=True,
                                 ray_init_config=init)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise RunError(f"--ray {args.ray}: cannot start the collectors ({str(exc).splitlines()[0]})") from None
    if started:                          # Ray stops with the collector, as when the collector had started it
        collector.shutdown = partial(_shutdown_with_ray, collector.shutdown)
    collector.update_policy_weights_(actor)    # the actors start from this policy (a resumed run's too)
    return collector


def _shutdown_with_ray(shutdown, *args, **kwargs) -> None:
    import ray
    shutdown(*args, **kwargs)
    ray.shutdown()


def collected(collector, args: RLArgs, state_path):
    """The collector's batches; with ``--ray``, an actor that dies (killed, out of memory, its node
    lost) ends the run in one line naming the checkpoint that ``--resume`` continues."""
    iterator = iter(collector)
    while True:
        try:
            batch = next(iterator)
        except StopIteration:
            return
        except Exception as exc:
            if args.ray is None or not type(exc).__module__.startswith("ray"):
                raise
            kept = f"{state_path} is kept: continue with --resume" if state_path.is_file() else \
                "no evaluation had saved a checkpoint yet"
            try:
                collector.shutdown()
            except Exception:           # the actors are already gone
                pass
            raise RunError(f"--ray: a collector actor died ({type(exc).__name__}); {kept}") from None
        yield batch


def train(args: RLArgs) -> RunResult:
    check_args(args)
    if args.algo != "ppo":
        raise ValueError("the TorchRL script trains PPO only (use --lib sb3 for SAC)")
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    run = TrainingRun.create("rl", f"torchrl-{args.algo}-{args.task}", args.seed, out=args.out,
                             overwrite=args.overwrite, resume=args.resume)
    state_path = run.path("training_state.pt")
    if args.resume and not state_path.is_file():
        raise RunError(f"--resume: {run.dir} holds no TorchRL training state (training_state.pt) to continue")
    if args.resume:
        run.check_resumed_flags(asdict(args), RESUME_FREE_FLAGS)
    run.write_config(run_config(args), "config.json" if not args.resume else "config_resumed.json")
    device = torch.device(torch_device(args.device))

    # 1. environments
    probe = make_rl_env(args.task, split="train", **args.env_kwargs())
    observation_space, action_space = probe.observation_space, probe.action_space
    probe.close()

    # 2. actor and critic, each over its own encoder: a categorical over the candidates (pick) or a
    #    TanhNormal on [-1, 1] over a TreeEncoder (box)
    if args.action == "pick":
        from torchrl.data import Categorical
        actor = make_pick_actor(observation_space, action_spec=Categorical(action_space.n), head_hidden=args.pi_arch,
                                head=args.pick_head, **args.candidate_kwargs())     # indices, as make_env's envs read
        value = make_pick_value(observation_space, head_hidden=args.net_arch, **args.candidate_kwargs())
        set_prior_scale(actor, args.prior_scale)         # --prior-scale: the shared head's weight on a prior
    else:
        actor = make_actor(observation_space, action_space, head_hidden=args.net_arch[0],
                           init_scale=float(math.exp(args.log_std_init)), **args.encoder_kwargs())
        value = make_value(observation_space, hidden=args.net_arch[0], **args.encoder_kwargs())
    actor, value = actor.to(device), value.to(device)
    if args.init_from is not None and not args.resume:
        encoders = [m for m in (*actor.modules(), *value.modules()) if type(m).__name__ in ("TreeEncoder", "TreeGNNEncoder")]
        try:
            source = warm_start_encoder(args.init_from, *encoders)
        except ValueError as exc:        # no backbone of this run's size in the file
            raise RunError(f"--init-from: {exc}") from None
        print(f"encoders initialised from {args.init_from} ({source})")

    # 3. collector, advantage, loss, optimiser, logger
    frames_per_batch = args.n_steps * args.n_envs
    total_frames = math.ceil(args.total_steps / frames_per_batch) * frames_per_batch   # whole batches, as collected
    steps = 0
    optimiser_state = None
    if args.resume:
        try:                             # a damaged or foreign state: one line, as train sampler / critical train
            state = load_training_state(state_path)
            actor.load_state_dict(state["actor"])
            value.load_state_dict(state["value"])
            optimiser_state, steps = state["optimiser"], int(state["steps"])
        except CheckpointError as exc:
            raise RunError(f"--resume: {exc}") from None
        except (KeyError, RuntimeError, TypeError, ValueError) as exc:
            raise RunError(f"--resume: {state_path} is not the training state of this run's networks "
                           f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
        print(f"resuming {run.dir} at step {steps:,}")
    total_frames = max(total_frames - steps, frames_per_batch)
    # the environments' processes start once the networks (and a resumed state) are read: a damaged
    # state is refused before them
    env = make_batched_env(args) if args.ray is None else None      # --ray: the actors build their own
    collector = make_collector(args, env, actor, frames_per_batch, total_frames)
    # deactivate_vmap: the graph conversion has data-dependent shapes, which vmap cannot batch
    advantage = GAE(gamma=args.gamma, lmbda=args.gae_lambda, value_network=value, average_gae=True,
                    deactivate_vmap=True)
    loss_module = ClipPPOLoss(actor, value, clip_epsilon=args.clip_range, entropy_coeff=args.ent_coef,
                              normalize_advantage=False)
    optimiser = torch.optim.Adam(loss_module.parameters(), lr=args.lr)
    if optimiser_state is not None:
        optimiser.load_state_dict(optimiser_state)
    logger = TensorboardLogger(exp_name=f"ppo_{args.task}", log_dir=str(run.path("tb")))
    candidates = args.candidate_settings() if args.action == "pick" else None
    evaluator = Evaluator(args, run, lambda: policy_from_torchrl(actor),
                          log=lambda name, v, step: logger.log_scalar(name, v, step=step), candidates=candidates)
    if args.resume:
        evaluator.restore()

    def save_state(steps: int) -> None:        # what --resume continues
        save_training_state(state_path, {"actor": actor.state_dict(), "value": value.state_dict(),
                                         "optimiser": optimiser.state_dict(), "steps": int(steps)})
    print(f"TorchRL PPO on {args.task}: {sum(p.numel() for p in loss_module.parameters()):,} parameters, "
          f"{frames_per_batch} frames per batch, run directory {run.dir}")

    # 4. the loop: collect a batch, GAE, epochs of minibatch updates, log, evaluate
    bar = tqdm(total=None if args.total_steps >= MAX_COUNT else args.total_steps, initial=steps, unit="step", disable=not args.progress, dynamic_ncols=True)
    started, batch_bytes = time.perf_counter(), 0
    if evaluator.due(steps):
        row = evaluator(steps)
        bar.write(f"  step {steps:>7}: val success {row['success_rate']:.2f}, median nodes {row['median_nodes']:.0f} "
                  f"({row['eval_wall_s']:.0f} s)")
    try:
        for batch in collected(collector, args, state_path):
            if steps >= args.total_steps:
                break
            if steps > 0 and evaluator.time_up():      # --minutes: this batch is not trained on (one at least)
                bar.write(evaluator.stopped_note(steps))
                break
            keep_threads(args.threads)     # TorchRL raises torch's thread count when a batched env closes
            steps += batch.numel()
            batch_bytes = max(batch_bytes, batch.bytes())   # the rollout storage of one batch
            for _ in range(args.n_epochs):
                with torch.no_grad():
                    advantage(batch)
                flat = batch.reshape(-1)
                for idx in torch.randperm(flat.numel()).split(args.batch_size):
                    losses = loss_module(flat[idx])
                    loss = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                    optimiser.zero_grad()
                    loss.backward()
                    torch.nn.utils.clip_grad_norm_(loss_module.parameters(), 0.5)
                    optimiser.step()
            collector.update_policy_weights_()
            done = batch["next", "done"]
            logger.log_scalar("train/reward_per_step", batch["next", "reward"].mean().item(), step=steps)
            logger.log_scalar("train/episodes_ended", done.sum().item(), step=steps)
            logger.log_scalar("train/loss_objective", losses["loss_objective"].item(), step=steps)
            logger.log_scalar("train/loss_critic", losses["loss_critic"].item(), step=steps)
            bar.update(batch.numel())
            if evaluator.due(steps):
                row = evaluator(steps)
                save_state(steps)
                bar.write(f"  step {steps:>7}: val success {row['success_rate']:.2f}, median nodes "
                          f"{row['median_nodes']:.0f} ({row['eval_wall_s']:.0f} s)")
    except ValueError as exc:            # torch refuses a distribution over NaN parameters
        error = non_finite_policy(exc, args.lr)
        if error is None:
            raise
        raise error from None
    bar.close()
    collector.shutdown()
    keep_threads(args.threads)
    train_time = time.perf_counter() - started

    # 5. final evaluation, learning curve, --tune-mix, --ship
    best = evaluator.finish(steps)
    save_state(steps)
    if env is not None and not env.is_closed:
        env.close()
    keep_threads(args.threads)
    print(f"trained {steps:,} steps in {tqdm.format_interval(train_time)} (batches of "
          f"{tqdm.format_sizeof(batch_bytes, 'B', 1024)}); policy {best}")
    return RunResult(run.dir, best, steps, train_time, batch_bytes, evaluator.rows)
