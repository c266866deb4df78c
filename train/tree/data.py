"""Datasets of the paper's Algorithm 1 (offline part): uniform-sampler solutions, cut into examples.

Seeded training problems (split ``train``; for tasks with scenes the training families) are
solved with the uniform sampler through :func:`gnn_mp_envs.evaluation.plan_problem` (the
benchmark's seeding rule). For each solved
problem the file keeps the whole final tree (states, node features as the environment
computed them, parents, tree ids), the solution path's node indices, every iteration's tree
size and active tree, start, goal and the observation's obstacle rows. Examples
(*snapshots*: a tree and the sample that should come next) are cut from that at load time,
in one of two views:

* ``"prefix"`` (the paper's): the graph is ``x_init`` (and, for BiRRT, ``x_goal``) plus the
  path nodes inserted before path node ``j``; the label is path node ``j``.
* ``"grown"`` (the remedy for the train/online mismatch): the tree the uniform planner had
  actually grown at an iteration (its first rows, insertion order); the label is the first
  node along the solution path, walked from the active tree's root, that the active tree
  does not hold yet (RRT: the next path node beyond the tree; BiRRT's goal tree walks the
  path from the goal).

Files are byte-reproducible for a seed and config, written atomically, and carry a format
version (:mod:`gnn_mp_envs.utils.npz`).
"""

from __future__ import annotations

from concurrent.futures.process import BrokenProcessPool

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from gnn_mp_envs.utils.npz import DatasetCacheError, read_npz, write_npz
from train.workers import SharedPool

log = logging.getLogger(__name__)

#: Bump when the stored arrays change meaning; loaders refuse other versions (2: maze2d obstacle rows
#: became [cx, cy, half_x, half_y, cos, sin, is_blob], 64 of them).
FORMAT_VERSION = 2
VIEWS = ("prefix", "grown")


@dataclass(frozen=True)
class TreeDataConfig:
    """Everything that determines a dataset file (stored in it as JSON)."""

    task: str = "pendulum"
    split: str = "train"
    scene: str | None = None          # tasks with scenes: default "train" (both training families)
    problems: int = 300               # problem indices first_problem..first_problem+problems-1 of the split
    seed: int = 0                     # sampler seed of problem i: gnn_mp_envs.evaluation.problem_seed(seed, i)
    max_nodes: int | None = None      # node budget (default: the task's)
    first_problem: int = 0
    sampler: str = "uniform"          # who plans: uniform (Algorithm 1) or a learned sampler (DAgger)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    def file_name(self) -> str:
        scene = f"-{self.scene}" if self.scene else ""
        first = f"-from{self.first_problem}" if self.first_problem else ""
        return f"{self.task}{scene}-{self.split}-{self.sampler}-{self.problems}p{first}-seed{self.seed}.npz"


@dataclass
class TreeDataset:
    """Solved problems: concatenated trees and paths with per-problem offsets."""

    config: TreeDataConfig
    node_ptr: np.ndarray     # (P+1,) offsets into states/parent/tree_id
    states: np.ndarray       # (N, d) float32
    node_features: np.ndarray  # (N, 2d+1) float32, as the environment computed them
    parent: np.ndarray       # (N,) int32, local to its problem (-1 for roots)
    tree_id: np.ndarray      # (N,) int8
    path_ptr: np.ndarray     # (P+1,) offsets into path_nodes
    path_nodes: np.ndarray   # (L,) int32, local node indices, start to goal
    start: np.ndarray        # (P, d)
    goal: np.ndarray         # (P, d)
    obstacles: np.ndarray    # (P, M, 1+w) observation rows
    problem_index: np.ndarray  # (P,) index of each problem in its split
    iter_ptr: np.ndarray     # (P+1,) offsets into iter_nodes/iter_active
    iter_nodes: np.ndarray   # (I,) int32 tree size before each iteration
    iter_active: np.ndarray  # (I,) int8 the tree each iteration extended
    iter_sample: np.ndarray  # (I, d) float32 the sample (action) of each iteration
    iter_created: np.ndarray  # (I,) int32 the node its extension created (-1: blocked)

    def __len__(self) -> int:
        return len(self.start)

    def subset(self, problems: list[int]) -> "TreeDataset":
        """The dataset of the given problems only (offsets rebuilt; no problems: an empty dataset)."""
        def ragged(ptr: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
            pieces = [[a[:0], *(a[ptr[p]:ptr[p + 1]] for p in problems)] for a in arrays]
            sizes = [ptr[p + 1] - ptr[p] for p in problems]
            return (np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                    *[np.concatenate(ps) for ps in pieces])
        node_ptr, states, feats, parent, tree_id = ragged(self.node_ptr, self.states, self.node_features,
                                                          self.parent, self.tree_id)
        path_ptr, path_nodes = ragged(self.path_ptr, self.path_nodes)
        iter_ptr, nodes, active, sample, created = ragged(self.iter_ptr, self.iter_nodes, self.iter_active,
                                                          self.iter_sample, self.iter_created)
        idx = np.asarray(problems, dtype=np.int64)
        return TreeDataset(self.config, node_ptr, states, feats, parent, tree_id, path_ptr, path_nodes,
                           self.start[idx], self.goal[idx], self.obstacles[idx], self.problem_index[idx],
                           iter_ptr, nodes, active, sample, created)

    def tree(self, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a, b = self.node_ptr[p], self.node_ptr[p + 1]
        return self.states[a:b], self.parent[a:b], self.tree_id[a:b]

    def path(self, p: int) -> np.ndarray:
        return self.path_nodes[self.path_ptr[p]:self.path_ptr[p + 1]]

    def snapshots(self, p: int, view: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(rows, sizes, active, labels)`` of problem ``p``: the node rows of the graph (into its
        tree; a snapshot is the first ``sizes[t]`` of them), each snapshot's active tree and its
        label's node index. See the module docstring for the two views."""
        _, parent, tree_id = self.tree(p)
        path = self.path(p)
        if view == "prefix":
            rows = np.union1d(np.flatnonzero(parent < 0), path)            # roots + path, insertion order
            targets = [j for j in path if parent[j] >= 0]
            sizes = np.searchsorted(rows, targets)
            return rows, sizes, tree_id[targets].astype(np.int64), np.asarray(targets, np.int64)
        if view != "grown":
            raise ValueError(f"unknown view {view!r}; known: {VIEWS}")
        walks = (path, path[::-1])
        i0, i1 = self.iter_ptr[p], self.iter_ptr[p + 1]
        sizes, actives, labels = [], [], []
        for n, a in zip(self.iter_nodes[i0:i1].tolist(), self.iter_active[i0:i1].tolist()):
            label = next((g for g in walks[a] if not (g < n and tree_id[g] == a)), None)
            if label is not None:
                sizes.append(n), actives.append(a), labels.append(label)
        return (np.arange(len(parent)), np.asarray(sizes, np.int64), np.asarray(actives, np.int64),
                np.asarray(labels, np.int64))


def reindex(parent: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Parents of the rows ``keep`` (sorted) as indices into ``keep``; -1 where the parent is
    a root's none or not kept."""
    remap = np.full(len(parent), -1, dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    sub = parent[keep]
    return np.where(sub >= 0, remap[np.maximum(sub, 0)], -1).astype(np.int32)


#: Per process: the env and sampler a dataset job plans with (worker processes keep them across jobs).
_SOLVERS: dict[tuple, tuple] = {}


def _solver(config: TreeDataConfig, checkpoint: str | None) -> tuple:
    from agents.registry import load_sampler
    from gnn_mp_envs.evaluation import evaluation_env
    key = (config.to_json(), checkpoint)
    if key not in _SOLVERS:
        for env, _ in _SOLVERS.values():
            env.close()
        _SOLVERS.clear()
        env = evaluation_env(config.task, config.split, scene=config.scene, max_nodes=config.max_nodes)
        _SOLVERS[key] = (env, load_sampler(config.sampler, task=config.task, seed=0, checkpoint=checkpoint))
    return _SOLVERS[key]


def solve_problem(config: TreeDataConfig, index: int, checkpoint: str | None = None) -> tuple | None:
    """Problem ``index`` of the config's split planned by its sampler (the evaluation's seeding rule):
    ``(index, tree arrays, path, start, goal, obstacles, iteration records)``, None when unsolved.
    A pure function of its arguments, so a worker pool gives the same dataset as one process."""
    from gnn_mp_envs.evaluation import plan_problem
    env, sampler = _solver(config, checkpoint)
    base = env.unwrapped
    last: dict = {}
    roots = 2 if base.planner_name == "birrt" else 1
    iterations = [(roots, 0)]   # (tree size, active tree) before each iteration

    def keep_last(obs, _info, done) -> None:
        if done:   # live views: copy what the episode ends with
            n = int(obs["num_nodes"][0])
            last.update(features=np.array(obs["node_features"][:n]), obstacles=np.array(obs["obstacles"]))
        else:
            iterations.append((int(obs["num_nodes"][0]), int(obs["active_tree"][0])))

    samples: list[np.ndarray] = []

    def act(obs):
        samples.append(sampler.act(obs))
        return samples[-1]

    record = plan_problem(env, sampler, index, config.seed, on_step=keep_last, policy=act)
    if not record.success:
        return None
    tree = base.planner.tree
    n = len(tree)
    sizes = np.asarray(iterations + [(n, 0)], dtype=np.int64)[:, 0]
    created = np.where(sizes[1:] > sizes[:-1], sizes[:-1], -1)
    return (index, (tree.states[:n].astype(np.float32), tree.parent[:n].astype(np.int32),
                    tree.tree_id[:n].astype(np.int8), last["features"].astype(np.float32)),
            np.asarray(record.path_nodes, dtype=np.int32), base.problem.start.copy(), base.problem.goal.copy(),
            last["obstacles"], (np.asarray(iterations, dtype=np.int32), np.stack(samples).astype(np.float32),
                                created.astype(np.int32)))


def _solve_job(job: tuple) -> tuple | None:
    return solve_problem(*job)


def generate(config: TreeDataConfig, progress: bool = True, checkpoint: str | None = None,
             workers: int = 1, ray: str | None = None, pool: SharedPool | None = None) -> TreeDataset:
    """Solve the config's problems with its sampler (uniform, or a learned one from
    ``checkpoint`` for DAgger) under the evaluation's seeding rule; keep the solved ones.
    ``workers`` > 1 plans them in worker processes, ``ray`` (an address, or ``"local"``) on
    ``workers`` Ray actors (:mod:`train.workers`, as the benchmark's ``--workers`` and ``--ray``); ``pool``:
    a run's :class:`~train.workers.SharedPool` to plan on instead (its workers kept for the run's next
    batch). The problems are assembled in index order, so the dataset (and its file) is the same whatever
    the worker count or backend."""
    indices = range(config.first_problem, config.first_problem + config.problems)
    bar = tqdm(total=config.problems, desc=f"{config.task} {config.sampler} solutions", unit="problem",
               disable=not progress)
    solved: dict[int, tuple] = {}

    def finished(result: tuple | None) -> None:
        bar.update(1)
        if result is not None:
            solved[result[0]] = result

    jobs = [(config, i, checkpoint) for i in indices]
    try:
        if pool is not None:
            pool.run(jobs, finished, _solve_job)
        else:
            with SharedPool(workers, ray) as own:
                own.run(jobs, finished, _solve_job)
    except BrokenProcessPool:            # a worker process or Ray actor was killed (a signal, out of memory)
        from train.args import UsageError
        raise UsageError(f"a worker died while planning the {config.task} training problems ({len(solved)} of "
                             f"{config.problems} planned; no dataset was written): rerun, with fewer --workers if "
                             "memory ran out") from None
    finally:
        bar.close()
        for env, _ in _SOLVERS.values():
            env.close()
        _SOLVERS.clear()
    results = [solved[i] for i in sorted(solved)]
    trees = [r[1] for r in results]
    paths = [r[2] for r in results]
    starts, goals, obstacles = [r[3] for r in results], [r[4] for r in results], [r[5] for r in results]
    indices = [r[0] for r in results]
    iters = [r[6] for r in results]
    if not trees:
        raise RuntimeError(f"no {config.task} problem of {config.problems} was solved")
    sizes = [len(t[0]) for t in trees]
    return TreeDataset(
        config=config,
        node_ptr=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        states=np.concatenate([t[0] for t in trees]), node_features=np.concatenate([t[3] for t in trees]),
        parent=np.concatenate([t[1] for t in trees]), tree_id=np.concatenate([t[2] for t in trees]),
        path_ptr=np.concatenate([[0], np.cumsum([len(p) for p in paths])]).astype(np.int64),
        path_nodes=np.concatenate(paths), start=np.stack(starts).astype(np.float32),
        goal=np.stack(goals).astype(np.float32), obstacles=np.stack(obstacles).astype(np.float32),
        problem_index=np.asarray(indices, dtype=np.int64),
        iter_ptr=np.concatenate([[0], np.cumsum([len(t[0]) for t in iters])]).astype(np.int64),
        iter_nodes=np.concatenate([t[0][:, 0] for t in iters]).astype(np.int32),
        iter_active=np.concatenate([t[0][:, 1] for t in iters]).astype(np.int8),
        iter_sample=np.concatenate([t[1] for t in iters]), iter_created=np.concatenate([t[2] for t in iters]))


FIELDS = ("node_ptr", "states", "node_features", "parent", "tree_id", "path_ptr", "path_nodes", "start", "goal",
          "obstacles", "problem_index", "iter_ptr", "iter_nodes", "iter_active", "iter_sample", "iter_created")


def save(dataset: TreeDataset, path: str | Path) -> Path:
    """Write ``dataset`` (byte-reproducible, atomic)."""
    arrays = {"format_version": np.array(FORMAT_VERSION), "config_json": np.array(dataset.config.to_json())}
    arrays.update({name: getattr(dataset, name) for name in FIELDS})
    return write_npz(path, arrays)


def _check_offsets(name: str, ptr: np.ndarray, problems: int, length: int) -> None:
    if ptr.shape != (problems + 1,) or ptr[0] != 0 or np.any(np.diff(ptr) < 0) or ptr[-1] != length:
        raise ValueError(f"{name} are not offsets of {problems} problems into {length} rows")


def check_contents(data: TreeDataset) -> None:
    """``ValueError`` naming the first array whose contents do not fit the others: offsets that run
    past their arrays, node, parent or path indices outside their problem's tree, tree ids or
    iteration records out of range, non-finite states. A file that passes cannot make the
    snapshot cutter index outside a tree."""
    P, (N, d) = len(data.start), data.states.shape
    if data.goal.shape != (P, d) or data.start.shape != (P, d) or len(data.obstacles) != P \
            or data.problem_index.shape != (P,):
        raise ValueError("start, goal, obstacles and problem_index disagree on the number of problems")
    _check_offsets("node_ptr", data.node_ptr, P, N)
    if data.node_features.shape != (N, 2 * d + 1) or data.parent.shape != (N,) or data.tree_id.shape != (N,):
        raise ValueError("node_features, parent and tree_id do not match the states")
    if not np.isfinite(data.states).all():
        raise ValueError("states are not finite")
    sizes = np.diff(data.node_ptr)
    local = np.arange(N) - np.repeat(data.node_ptr[:-1], sizes)         # each node's index in its tree
    if np.any(data.parent < -1) or np.any(data.parent >= local) or np.any((data.tree_id < 0) | (data.tree_id > 1)):
        raise ValueError("parent or tree_id indices out of range (a parent must be an earlier node of its tree)")
    _check_offsets("path_ptr", data.path_ptr, P, len(data.path_nodes))
    path_size = np.repeat(sizes, np.diff(data.path_ptr))
    if np.any(data.path_nodes < 0) or np.any(data.path_nodes >= path_size):
        raise ValueError("path_nodes outside their problem's tree")
    I = len(data.iter_nodes)
    _check_offsets("iter_ptr", data.iter_ptr, P, I)
    if data.iter_active.shape != (I,) or data.iter_sample.shape != (I, d) or data.iter_created.shape != (I,):
        raise ValueError("iter_active, iter_sample and iter_created do not match iter_nodes")
    iter_size = np.repeat(sizes, np.diff(data.iter_ptr))
    if (np.any(data.iter_nodes < 0) or np.any(data.iter_nodes > iter_size) or np.any(data.iter_created < -1)
            or np.any(data.iter_created >= iter_size) or np.any((data.iter_active < 0) | (data.iter_active > 1))):
        raise ValueError("iteration records outside their problem's tree")


def load(path: str | Path) -> TreeDataset:
    """Read a file written by :func:`save`; :class:`DatasetCacheError` names a damaged file, also
    one whose arrays are readable but do not fit together (:func:`check_contents`)."""
    z = read_npz(path, FORMAT_VERSION)
    try:
        config = TreeDataConfig(**json.loads(str(z["config_json"])))
        dataset = TreeDataset(config=config, **{name: z[name] for name in FIELDS})
        check_contents(dataset)
        return dataset
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise DatasetCacheError(f"{path}: unreadable dataset file ({type(exc).__name__}: {exc})") from None


def load_or_generate(config: TreeDataConfig, directory: str | Path, progress: bool = True,
                     workers: int = 1, ray: str | None = None, pool: SharedPool | None = None) -> TreeDataset:
    """The cached dataset of ``config`` in ``directory``, generated first (by ``workers`` processes,
    or Ray actors at ``ray``, or on ``pool``: :func:`generate`) when missing or damaged."""
    path = Path(directory) / config.file_name()
    if path.exists():
        try:
            dataset = load(path)
            if dataset.config == config:
                return dataset
            log.warning("%s: generated with another config; regenerating it", path)
        except DatasetCacheError as exc:
            log.warning("%s; regenerating it", exc)
    dataset = generate(config, progress, workers=workers, ray=ray, pool=pool)
    save(dataset, path)
    return dataset
