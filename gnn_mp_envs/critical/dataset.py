"""Seeded critical-sample datasets on the constant Halton graph, cached as npz.

What is generated (defaults, see :class:`DatasetConfig`):

* ``labelled.npz``: 400 Maze2D maps x 12 start/goal pairs = 4,800 problems. Each problem's
  labels are its bottleneck nodes with ``rel_tol = 0.5`` (every path node whose deletion
  raises the path cost by at least half the largest increase). That gives ~3.2 labels per
  problem, i.e. ~15,000 labelled (problem, critical node) samples, the paper's size. The
  paper had 400 problems with ~37 labels each; we reach 15k with more start/goal pairs per
  map instead of a looser tolerance, because loose tolerances label nodes far from any
  passage. Split by map (never by pair): maps ``i % 10 < 8`` train, ``8`` val, ``9`` test.
* ``eval_test.npz``: 300 further in-distribution problems (one per map).
* ``eval_blob.npz``: 300 problems whose maps also carry ``num_blobs`` random blobs, a
  corruption never seen in training (robustness).
* ``eval_{test,blob}_seed<S>.npz``: fresh evaluation problems drawn from seed ``S``
  (:func:`eval_config`; ``gnn-mp critical evaluate --eval-seed S``).

Problem ``i`` of a stream draws everything from ``default_rng([seed, stream, i])``, so the
same seed gives identical arrays; files are written with fixed zip timestamps so they are
byte-identical too. Node/edge validity is stored bit-packed; features are derived at load
time (``agents/critical_data.py``), keeping this module numpy-only.

Caches are written to a unique temporary file beside the target and renamed into place
(:func:`gnn_mp_envs.utils.io.atomic_path`), so concurrent generators never share a file and
readers never see half a file. A cache that cannot be read (empty, truncated, CRC errors,
not an npz, missing arrays, another format version, contents that do not fit together:
out-of-range labels, offsets past the arrays) raises :class:`DatasetCacheError` from
:func:`load_problems`; :func:`load_or_generate` and :func:`generate_all` then log a one-line
warning naming the file and regenerate it.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from gnn_mp_envs.critical.bottleneck import bottleneck_nodes, problem_graph
from gnn_mp_envs.critical.halton import DENSE_NODES, HaltonGraph, halton_graph
from gnn_mp_envs.tasks.base import SPLIT_SEEDS
from gnn_mp_envs.tasks.maze2d import MazeMap, random_maze, sample_endpoints
from gnn_mp_envs.utils.npz import DAMAGED, DatasetCacheError, read_npz, write_npz

log = logging.getLogger(__name__)

#: Bump when the stored arrays change meaning; loaders refuse other versions.
FORMAT_VERSION = 1
#: Seed-sequence stream of the blob-corrupted evaluation maps (train/val/test use SPLIT_SEEDS).
BLOB_STREAM = 3
#: Split codes of the labelled set.
SPLIT_CODES = {"train": 0, "val": 1, "test": 2}


@dataclass
class DatasetConfig:
    """Everything that determines the generated files (stored in each file as json)."""

    seed: int = 0
    num_maps: int = 400
    pairs_per_map: int = 12
    rel_tol: float = 0.5
    eval_problems: int = 300
    num_blobs: int = 4
    num_walls: tuple[int, int] = (1, 3)
    graph_nodes: int = DENSE_NODES
    max_candidates: int | None = None

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)


@dataclass
class CriticalProblems:
    """A set of problems on one graph, with their bottleneck labels (flat + ``label_ptr``)."""

    walls: list[np.ndarray]
    blobs: list[np.ndarray]
    start: np.ndarray           # (P, 2)
    goal: np.ndarray            # (P, 2)
    node_free: np.ndarray       # (P, N) bool
    edge_free: np.ndarray       # (P, E) bool
    label_ptr: np.ndarray       # (P + 1,)
    label_nodes: np.ndarray     # (L,) graph node indices
    path_cost: np.ndarray       # (P,)
    map_index: np.ndarray       # (P,)
    split: np.ndarray           # (P,) SPLIT_CODES
    config: DatasetConfig = field(default_factory=DatasetConfig)

    def __len__(self) -> int:
        return int(len(self.start))

    def maze(self, i: int) -> MazeMap:
        return MazeMap(self.walls[i], self.blobs[i])

    def labels_of(self, i: int) -> np.ndarray:
        return self.label_nodes[self.label_ptr[i]:self.label_ptr[i + 1]]

    def subset(self, index: np.ndarray) -> "CriticalProblems":
        index = np.asarray(index, dtype=np.int64)
        counts = np.diff(self.label_ptr)[index]
        nodes = [self.labels_of(int(i)) for i in index]
        return CriticalProblems(
            [self.walls[i] for i in index], [self.blobs[i] for i in index],
            self.start[index], self.goal[index], self.node_free[index], self.edge_free[index],
            np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            np.concatenate(nodes).astype(np.int64) if nodes else np.zeros(0, np.int64),
            self.path_cost[index], self.map_index[index], self.split[index], self.config)

    def split_subset(self, name: str) -> "CriticalProblems":
        return self.subset(np.flatnonzero(self.split == SPLIT_CODES[name]))


def _solve(graph: HaltonGraph, maze: MazeMap, start: np.ndarray, goal: np.ndarray,
           rel_tol: float, max_candidates: int | None):
    pg = problem_graph(graph, maze, start, goal)
    res = bottleneck_nodes(pg, rel_tol=rel_tol, max_candidates=max_candidates)
    return pg, res


def _map_problems(rng: np.random.Generator, graph: HaltonGraph, cfg: DatasetConfig,
                  num_blobs: int, pairs: int, max_tries: int = 50) -> list[tuple]:
    """``pairs`` labelled problems on one random map (redrawing the map if it is unusable)."""
    for _ in range(max_tries):
        maze, axis = random_maze(rng, cfg.num_walls, num_blobs)
        out = []
        for _ in range(pairs * 5):
            try:
                start, goal = sample_endpoints(rng, maze, axis)
            except RuntimeError:
                break
            pg, res = _solve(graph, maze, start, goal, cfg.rel_tol, cfg.max_candidates)
            if len(res.labels):
                out.append((maze, start, goal, pg.node_free, pg.edge_free, res.labels, res.cost))
            if len(out) == pairs:
                return out
    raise RuntimeError("could not generate a solvable map; check the generator settings")


def _collect(rows: list[tuple], map_index: list[int], split: list[int],
             cfg: DatasetConfig) -> CriticalProblems:
    counts = [len(r[5]) for r in rows]
    return CriticalProblems(
        walls=[r[0].walls for r in rows], blobs=[r[0].blobs for r in rows],
        start=np.array([r[1] for r in rows]), goal=np.array([r[2] for r in rows]),
        node_free=np.array([r[3] for r in rows]), edge_free=np.array([r[4] for r in rows]),
        label_ptr=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        label_nodes=np.concatenate([r[5] for r in rows]).astype(np.int64),
        path_cost=np.array([r[6] for r in rows]), map_index=np.array(map_index, dtype=np.int64),
        split=np.array(split, dtype=np.int8), config=cfg)


def map_split(i: int) -> int:
    """The split code (:data:`SPLIT_CODES`) of labelled map ``i``: every tenth map from the ninth is
    validation (8, 18, ...), from the tenth test (9, 19, ...), the rest training."""
    return SPLIT_CODES["val"] if i % 10 == 8 else SPLIT_CODES["test"] if i % 10 == 9 else SPLIT_CODES["train"]


def check_has_split(cfg: DatasetConfig, split: str, why: str) -> None:
    """A one-line ``ValueError`` when the labelled set of ``cfg`` is too small to hold a map of
    ``split`` (``"val"``, ``"test"``; checked before any data is generated)."""
    first = next(i for i in range(10) if map_split(i) == SPLIT_CODES[split])
    if cfg.num_maps <= first:
        raise ValueError(f"--num-maps {cfg.num_maps}: {why}, and the labelled set's {split} maps are every tenth "
                         f"from map {first}: use --num-maps {first + 1} or more")


def generate_labelled(cfg: DatasetConfig, graph: HaltonGraph | None = None,
                      progress: bool = True) -> CriticalProblems:
    """The labelled train/val/test set: ``num_maps`` maps x ``pairs_per_map`` problems."""
    graph = graph or halton_graph(cfg.graph_nodes)
    rows, maps, splits = [], [], []
    for i in tqdm(range(cfg.num_maps), desc="labelled maps", disable=not progress):
        rng = np.random.default_rng([cfg.seed, SPLIT_SEEDS["train"], i])
        got = _map_problems(rng, graph, cfg, 0, cfg.pairs_per_map)
        code = map_split(i)
        rows += got
        maps += [i] * len(got)
        splits += [code] * len(got)
    return _collect(rows, maps, splits, cfg)


def generate_eval(cfg: DatasetConfig, kind: str, graph: HaltonGraph | None = None,
                  num_problems: int | None = None, progress: bool = True) -> CriticalProblems:
    """``kind='test'``: in-distribution problems; ``kind='blob'``: blob-corrupted maps."""
    if kind not in ("test", "blob"):
        raise ValueError(f"kind must be 'test' or 'blob', got {kind!r}")
    graph = graph or halton_graph(cfg.graph_nodes)
    stream = SPLIT_SEEDS["test"] if kind == "test" else BLOB_STREAM
    blobs = 0 if kind == "test" else cfg.num_blobs
    n = cfg.eval_problems if num_problems is None else int(num_problems)
    rows = []
    for i in tqdm(range(n), desc=f"eval {kind}", disable=not progress):
        rows += _map_problems(np.random.default_rng([cfg.seed, stream, i]), graph, cfg, blobs, 1)
    return _collect(rows, list(range(n)), [SPLIT_CODES["test"]] * n, cfg)


# ----------------------------------------------------------------------------- storage


def _pad(arrays: list[np.ndarray], width: int) -> np.ndarray:
    m = max([len(a) for a in arrays] + [0])
    out = np.full((len(arrays), m, width), np.nan)
    for i, a in enumerate(arrays):
        out[i, :len(a)] = a
    return out


def save_problems(problems: CriticalProblems, path: str | Path) -> None:
    """Write an npz with a format version and the generating config (byte-reproducible)."""
    write_npz(path, {
        "format_version": np.array(FORMAT_VERSION),
        "seed": np.array(problems.config.seed),
        "config_json": np.array(problems.config.to_json()),
        "walls": _pad(problems.walls, 4), "blobs": _pad(problems.blobs, 3),
        "start": problems.start, "goal": problems.goal,
        "num_nodes": np.array(problems.node_free.shape[1]),
        "num_edges": np.array(problems.edge_free.shape[1]),
        "node_free_bits": np.packbits(problems.node_free, axis=1),
        "edge_free_bits": np.packbits(problems.edge_free, axis=1),
        "label_ptr": problems.label_ptr, "label_nodes": problems.label_nodes,
        "path_cost": problems.path_cost, "map_index": problems.map_index, "split": problems.split,
    })


@lru_cache(maxsize=4)
def _graph_edges(num_nodes: int) -> int:
    return len(halton_graph(num_nodes).edges)


def check_problems(problems: CriticalProblems) -> None:
    """``ValueError`` naming the first array whose contents do not fit: another number of
    problems than the others, node or edge validity of another graph than ``config.graph_nodes``'s,
    label offsets past the labels, label nodes outside the graph, unknown split codes,
    non-finite or out-of-square endpoints. A file that passes cannot make training or
    evaluation index outside the graph."""
    P, n = len(problems.start), problems.config.graph_nodes
    per_problem = {"goal": problems.goal.shape[:1], "node_free": problems.node_free.shape[:1],
                   "edge_free": problems.edge_free.shape[:1], "path_cost": problems.path_cost.shape,
                   "map_index": problems.map_index.shape, "split": problems.split.shape,
                   "walls": (len(problems.walls),), "blobs": (len(problems.blobs),)}
    for name, shape in per_problem.items():
        if shape != (P,):
            raise ValueError(f"{name} holds {shape[0] if shape else 0} problems, start {P}")
    if problems.start.shape != (P, 2) or problems.goal.shape != (P, 2):
        raise ValueError("start and goal are not (problems, 2)")
    ends = np.concatenate([problems.start, problems.goal])
    if not (np.isfinite(ends).all() and (ends >= 0).all() and (ends <= 1).all()):
        raise ValueError("start or goal outside the unit square")
    if problems.node_free.shape[1] != n or problems.edge_free.shape[1] != _graph_edges(n):
        raise ValueError(f"node/edge validity of another graph than the {n}-node Halton graph")
    ptr, labels = problems.label_ptr, problems.label_nodes
    if ptr.shape != (P + 1,) or ptr[0] != 0 or np.any(np.diff(ptr) < 0) or ptr[-1] != len(labels):
        raise ValueError(f"label_ptr are not offsets of {P} problems into {len(labels)} labels")
    if np.any(labels < 0) or np.any(labels >= n):
        raise ValueError(f"label nodes outside the {n}-node graph")
    if not np.isin(problems.split, list(SPLIT_CODES.values())).all():
        raise ValueError(f"split codes other than {sorted(SPLIT_CODES.values())}")


def load_problems(path: str | Path) -> CriticalProblems:
    """Read an npz written by :func:`save_problems`.

    Raises :class:`DatasetCacheError` (one line naming the file) for other format versions,
    damaged files (empty, truncated, CRC errors, not an npz, missing arrays) and readable files
    whose contents do not fit (:func:`check_problems`), and ``FileNotFoundError`` for a missing one.
    """
    path = Path(path)
    z = read_npz(path, FORMAT_VERSION)
    try:
        cfg_dict = json.loads(str(z["config_json"]))
        cfg_dict["num_walls"] = tuple(cfg_dict["num_walls"])
        cfg = DatasetConfig(**cfg_dict)
        walls = [w[~np.isnan(w[:, 0])] for w in z["walls"]]
        blobs = [b[~np.isnan(b[:, 0])] for b in z["blobs"]]
        n, e = int(z["num_nodes"]), int(z["num_edges"])
        problems = CriticalProblems(
            walls, blobs, z["start"], z["goal"],
            np.unpackbits(z["node_free_bits"], axis=1, count=n).astype(bool),
            np.unpackbits(z["edge_free_bits"], axis=1, count=e).astype(bool),
            z["label_ptr"], z["label_nodes"], z["path_cost"], z["map_index"], z["split"], cfg)
        check_problems(problems)
        return problems
    except DAMAGED as exc:
        raise DatasetCacheError(f"{path}: unreadable dataset file ({type(exc).__name__}: {exc})") from None


def _cached(path: Path, cfg: DatasetConfig) -> CriticalProblems | None:
    """The problems cached at ``path`` if it holds ``cfg``'s; None (after a one-line warning
    for a damaged or outdated file) if it must be (re)generated."""
    if not path.exists():
        return None
    try:
        problems = load_problems(path)
    except DatasetCacheError as exc:
        log.warning("%s; regenerating it", exc)
        return None
    return problems if problems.config == cfg else None


FILES = {"labelled": "labelled.npz", "test": "eval_test.npz", "blob": "eval_blob.npz"}


def generate_all(cfg: DatasetConfig, out_dir: str | Path, progress: bool = True,
                 overwrite: bool = False) -> dict[str, Path]:
    """Generate (or keep, if cached with the same config) the three dataset files."""
    out_dir = Path(out_dir)
    graph = halton_graph(cfg.graph_nodes)
    paths = {}
    for key, name in FILES.items():
        path = out_dir / name
        paths[key] = path
        if not overwrite and _cached(path, cfg) is not None:
            continue
        if key == "labelled":
            problems = generate_labelled(cfg, graph, progress)
        else:
            problems = generate_eval(cfg, key, graph, progress=progress)
        save_problems(problems, path)
    return paths


def eval_config(cfg: DatasetConfig, eval_seed: int | None) -> DatasetConfig:
    """The config whose evaluation streams give the problems of ``eval_seed``.

    Evaluation problem ``i`` comes from ``default_rng([seed, stream, i])``; a fresh evaluation
    seed S draws them from ``[S, stream, i]`` instead (same generator, other problems: the
    labelled set uses stream 0, so no evaluation seed reproduces a training problem).
    ``None`` or the data seed itself give the default evaluation sets.
    """
    return cfg if eval_seed is None else replace(cfg, seed=int(eval_seed))


def cache_path(cfg: DatasetConfig, out_dir: str | Path, key: str, eval_seed: int | None = None) -> Path:
    """``labelled.npz`` / ``eval_test.npz`` / ``eval_blob.npz``, or ``eval_<set>_seed<S>.npz``
    for an evaluation seed other than the data seed."""
    name = FILES[key]
    if key != "labelled" and eval_seed is not None and int(eval_seed) != cfg.seed:
        name = name.replace(".npz", f"_seed{int(eval_seed)}.npz")
    return Path(out_dir) / name


def load_or_generate(cfg: DatasetConfig, out_dir: str | Path, key: str,
                     progress: bool = True, eval_seed: int | None = None) -> CriticalProblems:
    """One cached file, generated first if missing, damaged or generated with another config.

    ``eval_seed`` (evaluation sets only): draw the problems from that seed
    (:func:`eval_config`), cached as ``eval_<set>_seed<S>.npz``.
    """
    path = cache_path(cfg, out_dir, key, eval_seed)
    if key != "labelled":
        cfg = eval_config(cfg, eval_seed)
    problems = _cached(path, cfg)
    if problems is not None:
        return problems
    graph = halton_graph(cfg.graph_nodes)
    problems = (generate_labelled(cfg, graph, progress) if key == "labelled"
                else generate_eval(cfg, key, graph, progress=progress))
    save_problems(problems, path)
    return problems
