"""The constant r-disc Halton graph that supports every critical-sample problem.

The paper covers the unit square with one fixed, dense r-disc Halton graph (2,000 nodes
in 2-D); a planning problem only changes the node features and which edges are valid.
Halton points are deterministic and low-dispersion (Janson et al. 2018), so the graph is
identical on every machine without a seed.

Radius: ``default_radius(n, d)`` is ``RADIUS_FACTOR`` times the r-disc connectivity rate
``(log n / n) ** (1 / d)``. With ``RADIUS_FACTOR = 0.8`` the 2,000-node 2-D graph has
r ~= 0.049 (mean degree ~15) and is connected; the 200-node sparse planning graph gets
r ~= 0.13 and is connected too (both asserted by tests). ``halton_graph`` raises if the
graph it builds is not connected, so a bad radius cannot slip through silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import qmc

#: Radius multiplier of the connectivity rate (see module docstring).
RADIUS_FACTOR = 0.8
#: Default size of the dense critical-sample graph (the paper's 2,000 nodes).
DENSE_NODES = 2000
#: Default size of the sparse planning graph.
SPARSE_NODES = 200


def halton_points(n: int, d: int = 2, skip: int = 1) -> np.ndarray:
    """The unscrambled Halton sequence (n, d) in the unit hypercube (scipy's ``qmc.Halton``: bases
    2, 3, 5, ... per dimension); ``skip`` drops the first points (the default, 1, the origin)."""
    sequence = qmc.Halton(d=d, scramble=False)
    if skip:
        sequence.fast_forward(skip)
    return sequence.random(n)


def default_radius(n: int, d: int = 2, factor: float = RADIUS_FACTOR) -> float:
    """r-disc radius ``factor * (log n / n) ** (1/d)``: dense enough to be connected."""
    return float(factor * (np.log(n) / n) ** (1.0 / d))


@dataclass(frozen=True)
class HaltonGraph:
    """Nodes (N, d) and undirected edges (E, 2) with ``edges[:, 0] < edges[:, 1]``."""

    nodes: np.ndarray
    edges: np.ndarray
    radius: float

    @property
    def num_nodes(self) -> int:
        return int(len(self.nodes))

    def edge_lengths(self) -> np.ndarray:
        return np.linalg.norm(self.nodes[self.edges[:, 1]] - self.nodes[self.edges[:, 0]], axis=1)


def halton_graph(n: int = DENSE_NODES, d: int = 2, radius: float | None = None) -> HaltonGraph:
    """The r-disc Halton graph; raises if it is not connected (the radius is too small)."""
    nodes = halton_points(n, d)
    r = default_radius(n, d) if radius is None else float(radius)
    pairs = cKDTree(nodes).query_pairs(r, output_type="ndarray").astype(np.int64)
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    if not is_connected(n, pairs):
        raise ValueError(f"the {n}-node Halton graph with radius {r:.4f} is not connected")
    return HaltonGraph(nodes, pairs, r)


def is_connected(n: int, edges: np.ndarray) -> bool:
    """Whether the undirected graph on ``n`` nodes is a single component."""
    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(adj, directed=False)[0] == 1
