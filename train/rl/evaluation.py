"""Evaluation of an RL policy during training: the policy as the sampler the benchmark runs,
planned on validation problems through :func:`gnn_mp_envs.evaluation.plan_problems`.

:class:`Evaluator` is called every ``--eval-every`` steps: it exports the library's policy
(``export() -> (policy, kind, ctor_args)``, :mod:`agents.rl.policies`), plans problems
``0..N-1`` of split ``val`` with the benchmark's seeding rule, writes ``policy.pt`` and, when it
is the best so far, ``best.pt`` (success rate, then the fewest median nodes or collision
checks, ``--select-on``) with their ``.json`` sidecars, ``evaluations.json`` and TensorBoard
scalars; ``on_best`` lets the library script save its own model beside it (SB3:
``best_model.zip``). The untrained policy (step 0) is the learning curve's first point; it stays
``best.pt`` only if no trained policy scored at least as well (a tie goes to the trained one),
and ``finish`` then says so. ``finish`` adds the last evaluation, the optional ``--tune-mix``
search, the learning curve and ``--ship`` (of ``best.pt``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

from gnn_mp_envs.utils.io import atomic_write_text
from train.rl.args import RLArgs
from train.run import TrainingRun, plot_learning_curve


def score(row: dict[str, Any], select_on: str = "nodes") -> tuple[float, float]:
    """Higher is better: success rate, then fewer median nodes (or collision checks)."""
    key = "median_collision_checks" if select_on == "collision_checks" else "median_nodes"
    return (row["success_rate"], -row[key])


class Evaluator:
    """Periodic evaluation on split ``val``: checkpoints, ``evaluations.json``, TensorBoard scalars.

    ``log`` receives ``(name, value, step)`` for TensorBoard; ``on_best(steps)`` is called when a
    new ``best.pt`` was written; ``candidates``: a picker's ``CandidateSet`` configuration.
    """

    def __init__(self, args: RLArgs, run: TrainingRun, export: Callable[[], tuple],
                 log: Callable[[str, float, int], None] | None = None,
                 candidates: dict[str, Any] | None = None, on_best: Callable[[int], None] | None = None) -> None:
        from gnn_mp_envs.evaluation import evaluation_env
        from gnn_mp_envs.registration import task_spec
        self.args, self.run, self.export, self.log, self.on_best = args, run, export, log, on_best
        self.candidates = candidates
        spec = task_spec(args.task)
        self.low, self.high = spec.state_bounds()
        self.periodic = spec.periodic_mask(len(self.low)).tolist()
        self.env = evaluation_env(args.task, "val", planner=args.planner, max_nodes=args.max_nodes)
        self.rows: list[dict[str, Any]] = []
        self.best: tuple[float, float] | None = None
        self.best_steps: int | None = None
        self.started = time.perf_counter()
        self.next_at = 0

    def restore(self) -> None:
        """Continue a resumed run: its evaluations so far and its best."""
        path = self.run.path("evaluations.json")
        if path.is_file():
            self.rows = json.loads(path.read_text())
        for row in self.rows:
            if self._better(row):
                self.best, self.best_steps = score(row, self.args.select_on), row["steps"]
        if self.rows:
            self.next_at = self.rows[-1]["steps"] + self.args.eval_every

    def _better(self, row: dict[str, Any]) -> bool:
        """Whether ``row`` replaces the best so far (a trained policy wins a tie with the untrained one)."""
        if self.best is None:
            return True
        new = score(row, self.args.select_on)
        return new > self.best or (new == self.best and self.best_steps == 0 and row["steps"] > 0)

    def due(self, steps: int) -> bool:
        return steps >= self.next_at

    def time_up(self) -> bool:
        """Whether ``--minutes`` of wall time have passed since the training loop started (this object's
        creation; evaluations included): the scripts then stop at the next rollout's start."""
        minutes = getattr(self.args, "minutes", None)
        return minutes is not None and time.perf_counter() - self.started >= 60.0 * minutes

    def stopped_note(self, steps: int) -> str:
        """The line a run stopped by ``--minutes`` prints: where it stopped and how to repeat it."""
        return (f"--minutes {self.args.minutes:g}: stopped at step {steps:,} (the steps depend on this machine's speed; "
                f"--total-steps {steps} repeats this run exactly)")

    def sampler(self, policy: Any, uniform_mix: float | None = None):
        from agents.rl.policies import PickPolicy
        from agents.rl.sampler import PickSampler, RLSampler
        mix = self.args.sampler_uniform_mix if uniform_mix is None else uniform_mix
        if isinstance(policy, PickPolicy):
            return PickSampler(self.low, self.high, 0, policy=policy, view_nodes=self.args.view_nodes,
                               candidates=self.candidates, uniform_mix=mix)
        return RLSampler(self.low, self.high, 0, policy=policy, view_nodes=self.args.view_nodes,
                         uniform_mix=mix, action_frame=self.args.action_frame, periodic=self.periodic)

    def evaluate(self, sampler: Any) -> dict[str, Any]:
        """Problems ``0..N-1`` of split ``val`` planned with ``sampler``: the figures of ``summarize``."""
        from agents.samplers.base import inference_threads
        from gnn_mp_envs.evaluation import plan_problems, summarize
        a = self.args
        with inference_threads():
            return summarize(plan_problems(sampler, self.env, range(a.eval_problems), a.seed,
                                           max_steps=a.eval_max_steps, progress=a.progress, desc="val"))

    def save(self, name: str, policy: Any, kind: str, ctor_args: dict, uniform_mix: float, **meta: Any) -> Path:
        from agents.rl.sampler import policy_record
        obs_spec, full_meta = policy_record(task=self.args.task, view_nodes=self.args.view_nodes, low=self.low,
                                            high=self.high, uniform_mix=uniform_mix,
                                            action_frame=self.args.action_frame, periodic=self.periodic,
                                            candidates=self.candidates,
                                            meta={"sampler_name": self.args.sampler_name, "planner": self.args.planner,
                                                  "train_config": json.loads(self.run.path("config.json").read_text()),
                                                  **meta})
        return self.run.save_checkpoint(name, policy, kind, ctor_args, obs_spec=obs_spec, meta=full_meta)

    def __call__(self, steps: int) -> dict[str, Any]:
        """Evaluate the current policy; write ``policy.pt`` (and ``best.pt`` when it is the best)."""
        import torch
        a = self.args
        policy, kind, ctor_args = self.export()
        train_wall = time.perf_counter() - self.started
        t0 = time.perf_counter()
        with torch.no_grad():
            row = self.evaluate(self.sampler(policy))
        row = {"steps": int(steps), "train_wall_s": round(train_wall, 1), "eval_wall_s": round(time.perf_counter() - t0, 1),
               **row}
        self.rows.append(row)
        mix = a.sampler_uniform_mix
        self.save("policy.pt", policy, kind, ctor_args, mix, evaluation=row)
        if self._better(row):
            self.best, self.best_steps = score(row, a.select_on), int(steps)
            self.save("best.pt", policy, kind, ctor_args, mix, evaluation=row)
            if self.on_best is not None:
                self.on_best(int(steps))
        atomic_write_text(self.run.path("evaluations.json"), json.dumps(self.rows, indent=2) + "\n")
        if self.log is not None:
            for name in ("success_rate", "median_nodes", "mean_nodes", "median_collision_checks"):
                self.log(f"eval/{name}", row[name], steps)
        self.next_at = steps + a.eval_every
        return row

    def finish(self, steps: int) -> Path:
        """Last evaluation, uniform-mix tuning (``--tune-mix``), learning curve, shipping of ``best.pt``."""
        if not self.rows or self.rows[-1]["steps"] != steps:
            self(steps)
        best = self.run.path("best.pt")
        if self.best_steps == 0:
            print("note: no trained policy did as well as the untrained one on split val: best.pt is the untrained "
                  "policy (step 0)")
        if self.args.tune_mix:   # of the selected policy, the one --ship copies
            self.tune_uniform_mix(best)
        x = [r["steps"] for r in self.rows]
        key = "median_collision_checks" if self.args.select_on == "collision_checks" else "median_nodes"
        label = "median collision checks" if key == "median_collision_checks" else "median nodes expanded"
        plot_learning_curve(self.run.path("learning_curve.png"),
                            {f"{label} (val)": (x, [r[key] for r in self.rows])},
                            right={"success rate (val)": (x, [r["success_rate"] for r in self.rows])},
                            right_label="success rate", right_limits=(-0.05, 1.05), xlabel="training steps",
                            ylabel=label, title=f"{self.args.lib} {self.args.algo.upper()} on {self.args.task} "
                                                f"(best: step {self.best_steps})")
        if self.args.ship:
            from agents.rl.sampler import RL_SAMPLERS
            self.run.ship(best, self.args.sampler_name, self.args.task,
                          expected_kind=RL_SAMPLERS[self.args.sampler_name])
        self.env.close()
        return best

    def tune_uniform_mix(self, path: Path) -> float:
        """Pick ``uniform_mix`` among ``--tune-mix`` on split ``val`` and store it in the checkpoint."""
        import torch

        from agents.checkpoints import load_checkpoint
        from agents.rl.sampler import sampler_from_checkpoint
        rows = []
        for mix in self.args.tune_mix or []:
            sampler = sampler_from_checkpoint(path, self.low, self.high, seed=0, uniform_mix=mix)
            with torch.no_grad():
                row = self.evaluate(sampler)
            rows.append({"uniform_mix": mix, **row})
            print(f"  uniform_mix {mix:.2f}: val success {row['success_rate']:.2f}, "
                  f"median nodes {row['median_nodes']:.0f}, median collision checks "
                  f"{row['median_collision_checks']:.0f}")
        best = max(rows, key=lambda r: score(r, self.args.select_on))
        model, record = load_checkpoint(path)
        meta = {**record["meta"], "sampler": {**record["meta"].get("sampler", {}), "uniform_mix": best["uniform_mix"]},
                "mix_tuning": rows}
        self.run.save_checkpoint(path.name, model, record["kind"], record["ctor_args"], obs_spec=record["obs_spec"],
                                 meta=meta)
        return best["uniform_mix"]


__all__ = ["Evaluator", "score"]
