"""Using predicted critical samples: plan on a sparse Halton graph augmented with them.

The paper's motivation (Sec. "Learning Critical Samples") is that critical nodes composed
with a sparse graph make planning cheaper than on the dense graph. This module measures it:
the same r-disc planner (all edges checked, then Dijkstra) on

* ``sparse``: the first ``SPARSE_NODES`` Halton points,
* ``augmented``: the sparse points plus predicted critical states (given as arrays, so this
  module stays numpy-only), connected within the same radius,
* ``dense``: the 2,000-node graph the labels were computed on.

Time is wall time of edge collision checks plus the search; ``edges_checked`` counts the
segment tests, which is the machine-independent cost.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from gnn_mp_envs.critical.bottleneck import shortest_path
from gnn_mp_envs.critical.halton import DENSE_NODES, RADIUS_FACTOR, SPARSE_NODES, default_radius, halton_points
from gnn_mp_envs.tasks.maze2d import MazeMap

#: Sparse-graph radius multiplier: the same rule as the dense graph (r ~= 0.130 for 200 nodes).
#: With 1.0 (r ~= 0.163) the sparse graph alone already solves ~80% of problems (100-problem
#: probe: sparse 0.80, sparse + ground-truth labels 0.95); with 0.8 it is 0.53 vs 0.83.
SPARSE_RADIUS_FACTOR = RADIUS_FACTOR


@dataclass
class PlanResult:
    """Outcome of one r-disc graph search; ``path`` is (K, 2) states from start to goal."""

    success: bool
    cost: float
    path: np.ndarray
    seconds: float
    edges_checked: int
    num_nodes: int


def plan_rdisc(maze: MazeMap, start: np.ndarray, goal: np.ndarray, nodes: np.ndarray,
               radius: float) -> PlanResult:
    """Shortest collision-free path over ``nodes`` + start + goal with edges within ``radius``."""
    t0 = time.perf_counter()
    nodes = np.asarray(nodes, dtype=np.float64).reshape(-1, 2)
    nodes = nodes[maze.is_free(nodes)] if len(nodes) else nodes
    pts = np.vstack([nodes, start[None], goal[None]])
    pairs = cKDTree(pts).query_pairs(radius, output_type="ndarray")
    ok = maze.segments_free(pts[pairs[:, 0]], pts[pairs[:, 1]]) if len(pairs) else np.zeros(0, bool)
    e = pairs[ok]
    w = np.maximum(np.linalg.norm(pts[e[:, 0]] - pts[e[:, 1]], axis=1), 1e-9)
    n = len(pts)
    m = csr_matrix((np.concatenate([w, w]), (np.concatenate([e[:, 0], e[:, 1]]),
                                             np.concatenate([e[:, 1], e[:, 0]]))), shape=(n, n))
    cost, path = shortest_path(m, n - 2, n - 1)
    seconds = time.perf_counter() - t0
    return PlanResult(bool(path), cost, pts[path] if path else np.zeros((0, 2)), seconds,
                      int(len(pairs)), n)


def path_is_valid(maze: MazeMap, path: np.ndarray) -> bool:
    """Every segment of ``path`` is collision free (used by tests and evaluation)."""
    if len(path) < 2:
        return False
    return bool(maze.segments_free(path[:-1], path[1:]).all())


def compare_planners(maze: MazeMap, start: np.ndarray, goal: np.ndarray,
                     predicted: dict[str, np.ndarray], sparse_nodes: int = SPARSE_NODES,
                     dense_nodes: int = DENSE_NODES) -> dict[str, PlanResult]:
    """Sparse, dense and one augmented search per entry of ``predicted`` (name -> (k, 2))."""
    sparse = halton_points(sparse_nodes)
    r_sparse = default_radius(sparse_nodes, factor=SPARSE_RADIUS_FACTOR)
    out = {"sparse": plan_rdisc(maze, start, goal, sparse, r_sparse),
           "dense": plan_rdisc(maze, start, goal, halton_points(dense_nodes), default_radius(dense_nodes))}
    for name, states in predicted.items():
        out[name] = plan_rdisc(maze, start, goal, np.vstack([sparse, np.reshape(states, (-1, 2))]), r_sparse)
    return out


def summarize(results: list[dict[str, PlanResult]]) -> dict[str, dict[str, float]]:
    """Success rate, mean cost over problems every method solved, mean time and edge checks."""
    names = list(results[0]) if results else []
    solved_by_all = [r for r in results if all(r[k].success for k in names)]
    out = {}
    for k in names:
        out[k] = {
            "success_rate": float(np.mean([r[k].success for r in results])),
            "mean_cost_common": float(np.mean([r[k].cost for r in solved_by_all])) if solved_by_all else float("nan"),
            "mean_cost_solved": float(np.mean([r[k].cost for r in results if r[k].success]))
            if any(r[k].success for r in results) else float("nan"),
            "mean_seconds": float(np.mean([r[k].seconds for r in results])),
            "mean_edges_checked": float(np.mean([r[k].edges_checked for r in results])),
            "mean_nodes": float(np.mean([r[k].num_nodes for r in results])),
        }
    out["_common"] = {"problems": len(results), "solved_by_all": len(solved_by_all)}
    return out
