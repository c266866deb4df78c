"""Ground-truth critical nodes: LEGO's Bottleneck Node algorithm on the Halton graph.

Kumar et al. (2019, Alg. 1): take the shortest feasible path on the graph; for each node
on it, delete that node (and its edges) and search again; the nodes whose deletion raises
the path cost the most (or disconnects start from goal) are the bottleneck nodes.

Efficiency: one Dijkstra from the start and one from the goal on the full graph give,
for every node, the cost of the best path through it (``d_s + d_g``). Deleting a node
can only matter if it lies on the shortest path, so only path nodes are re-searched; and a
re-search is one ``scipy.sparse.csgraph.dijkstra`` with the deleted node's edge weights set
to infinity (no matrix rebuild). Path interior nodes are re-searched at most
``max_candidates`` at a time, chosen as the nodes with the fewest near-optimal detours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from gnn_mp_envs.critical.halton import HaltonGraph
from gnn_mp_envs.tasks.maze2d import MazeMap


@dataclass
class ProblemGraph:
    """The constant graph restricted to one map, plus start (index N) and goal (N + 1)."""

    node_free: np.ndarray       # (N,) bool
    edge_free: np.ndarray       # (E,) bool over the constant graph's edges
    matrix: csr_matrix          # (N + 2, N + 2) symmetric edge lengths, valid edges only
    start_index: int
    goal_index: int


def valid_edges(graph: HaltonGraph, maze: MazeMap) -> tuple[np.ndarray, np.ndarray]:
    """Free nodes (N,) and collision-free edges (E,) of the constant graph on ``maze``."""
    node_free = maze.is_free(graph.nodes)
    e = graph.edges
    edge_free = node_free[e[:, 0]] & node_free[e[:, 1]]
    idx = np.flatnonzero(edge_free)
    edge_free[idx] = maze.segments_free(graph.nodes[e[idx, 0]], graph.nodes[e[idx, 1]])
    return node_free, edge_free


def problem_graph(graph: HaltonGraph, maze: MazeMap, start: np.ndarray, goal: np.ndarray,
                  node_free: np.ndarray | None = None,
                  edge_free: np.ndarray | None = None) -> ProblemGraph:
    """Valid part of the graph with start and goal attached to free nodes within the radius."""
    if node_free is None or edge_free is None:
        node_free, edge_free = valid_edges(graph, maze)
    n = graph.num_nodes
    e = graph.edges[edge_free]
    w = graph.edge_lengths()[edge_free]
    rows, cols, weights = [e[:, 0]], [e[:, 1]], [w]
    for index, point in ((n, start), (n + 1, goal)):
        dist = np.linalg.norm(graph.nodes - point, axis=1)
        near = np.flatnonzero((dist <= graph.radius) & node_free)
        ok = near[maze.segments_free(np.repeat(point[None], len(near), 0), graph.nodes[near])]
        rows.append(np.full(len(ok), index))
        cols.append(ok)
        weights.append(np.maximum(dist[ok], 1e-9))  # zero weights would read as "no edge"
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    matrix = csr_matrix((np.concatenate([w, w]), (np.concatenate([r, c]), np.concatenate([c, r]))),
                        shape=(n + 2, n + 2))
    return ProblemGraph(node_free, edge_free, matrix, n, n + 1)


def shortest_path(matrix: csr_matrix, source: int, target: int) -> tuple[float, list[int]]:
    """Cost and node list of the shortest path (``inf`` and ``[]`` when disconnected)."""
    dist, pred = dijkstra(matrix, directed=False, indices=source, return_predecessors=True)
    if not np.isfinite(dist[target]):
        return float("inf"), []
    path = [target]
    while path[-1] != source:
        path.append(int(pred[path[-1]]))
    return float(dist[target]), path[::-1]


@dataclass
class BottleneckResult:
    """Shortest path, per-interior-node cost increase on deletion, and the chosen labels."""

    cost: float
    path: list[int]
    candidates: np.ndarray      # interior path nodes that were re-searched
    increase: np.ndarray        # cost increase when each candidate is deleted (inf: disconnects)
    labels: np.ndarray          # graph node indices of the bottleneck nodes


def _without_node(matrix: csr_matrix, node: int, rows: np.ndarray) -> csr_matrix:
    """The graph with every edge at ``node`` made infinitely long (i.e. deleted)."""
    data = matrix.data.copy()
    data[(rows == node) | (matrix.indices == node)] = np.inf
    return csr_matrix((data, matrix.indices, matrix.indptr), shape=matrix.shape)


def bottleneck_nodes(pg: ProblemGraph, rel_tol: float = 0.0,
                     max_candidates: int | None = None) -> BottleneckResult:
    """LEGO's Bottleneck Node algorithm.

    Labels are the interior path nodes whose deletion increases the cost by at least
    ``(1 - rel_tol)`` times the largest increase (``rel_tol = 0``: only the maximisers);
    nodes whose deletion disconnects start and goal always rank first.
    """
    m = pg.matrix
    cost, path = shortest_path(m, pg.start_index, pg.goal_index)
    if not path:
        return BottleneckResult(cost, [], np.zeros(0, int), np.zeros(0), np.zeros(0, int))
    interior = np.array(path[1:-1], dtype=np.int64)
    if max_candidates is not None and len(interior) > max_candidates:
        interior = _fewest_detours(m, pg, interior, cost)[:max_candidates]
    rows = np.repeat(np.arange(m.shape[0]), np.diff(m.indptr))
    increase = np.empty(len(interior))
    for i, node in enumerate(interior):
        d = dijkstra(_without_node(m, int(node), rows), directed=False, indices=pg.start_index)
        increase[i] = d[pg.goal_index] - cost
    labels = _select_labels(interior, increase, rel_tol)
    return BottleneckResult(cost, path, interior, increase, labels)


def _select_labels(nodes: np.ndarray, increase: np.ndarray, rel_tol: float) -> np.ndarray:
    """Nodes within ``rel_tol`` of the largest increase (all disconnecting nodes if any)."""
    if len(nodes) == 0:
        return nodes
    if np.isinf(increase).any():
        return nodes[np.isinf(increase)]
    top = increase.max()
    if top <= 1e-12:
        return nodes[:0]
    return nodes[increase >= (1.0 - rel_tol) * top - 1e-12]


def _fewest_detours(m: csr_matrix, pg: ProblemGraph, nodes: np.ndarray, cost: float) -> np.ndarray:
    """Order path nodes by how few other nodes lie on near-optimal paths at the same depth.

    Uses the two full-graph Dijkstras: a node with few alternatives at its distance from the
    start (a narrow passage) is likely to be a bottleneck, so it is re-searched first.
    """
    d = dijkstra(m, directed=False, indices=[pg.start_index, pg.goal_index])
    through = d[0] + d[1]
    near = np.flatnonzero(through <= cost * 1.05)
    depth = d[0][near]
    width = np.array([np.sum(np.abs(depth - d[0][v]) <= 0.02) for v in nodes])
    return nodes[np.argsort(width, kind="stable")]
