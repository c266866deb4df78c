"""Shared test helpers: uniform actions from a numpy seed, driven through the one rollout loop."""

from __future__ import annotations

import base64
import json
import pickle
import zipfile
from typing import Any

import numpy as np

from gnn_mp_envs.rollout import run_steps


def uniform_policy(env: Any, seed: int = 0):
    """A policy drawing uniform actions in the env's action box from ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    return lambda _obs: rng.uniform(low, high).astype(np.float32)


def run_uniform(env: Any, seed: int | None = None, rng_seed: int = 0, max_steps: int = 100_000,
                options: dict | None = None) -> tuple[dict, dict, bool]:
    """Reset with ``seed``/``options`` and step with uniform actions; (last obs, last info, terminated)."""
    obs, info = env.reset(seed=seed, options=options)
    result = run_steps(env, uniform_policy(env, rng_seed), obs, max_steps=max_steps, info=info)
    return result.observation, result.info, result.terminated


def report_sigint_ignored(queue: Any) -> None:
    """A worker process's target: put whether it ignores Ctrl-C (SIGINT disposition SIG_IGN)."""
    import signal
    queue.put(signal.getsignal(signal.SIGINT) == signal.SIG_IGN)


def assert_problem_equals_yaml(doc: dict, robot: str, scene: str, file: int, start: list, goal: list,
                               objects: list) -> None:
    """A shipped MotionBenchMaker problem (``doc``: the robot's converted JSON) against values
    transcribed by hand from its YAML files: start, goal and object poses exactly, and the record
    the task plans."""
    from gnn_mp_envs.tasks.mbm import data as mbm_data
    shipped = doc["scenes"][scene]["problems"][file - 1]
    assert shipped["file"] == file
    assert shipped["start"] == start and shipped["goal"] == goal       # exact: the YAML's floats
    layout = doc["scenes"][scene]["objects"]
    for oid, kind, dims, position, orientation in objects:
        k = [row[0] for row in layout].index(oid)
        assert layout[k][1:] == [kind, dims]
        assert shipped["poses"][k] == position + orientation
    record = mbm_data.scene_records(scene, robot)[file - 1]
    assert record.robot == robot and record.file == file
    assert record.start == tuple(start) and record.goal == tuple(goal)


def solve_job_dying_on_problem_one(job: tuple):
    """The dataset's ``_solve_job``, except that the worker planning problem 1 is killed (SIGKILL)."""
    import os
    import signal

    from train.tree.data import solve_problem
    if job[1] == 1:
        os.kill(os.getpid(), signal.SIGKILL)
    return solve_problem(*job)


def armed(path, marker) -> None:
    """Rewrite ``path``'s ``data`` member with a cloudpickle payload in its policy keywords (what
    ``PPO.load`` unpickles): it creates ``marker`` when unpickled."""
    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(members["data"])
    data["policy_kwargs"] = {":type:": "<class 'dict'>",
                             ":serialized:": base64.b64encode(pickle.dumps(Payload())).decode()}
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)
