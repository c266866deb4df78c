"""Numpy critical-sample problems -> PyG ``Data`` batches and CNN image tensors.

Kept apart from :mod:`gnn_mp_envs.critical` so the environment package never imports torch.
Graph inputs use only the valid edges of each problem (both directions); nodes inside
obstacles keep their features (indicator 1) but have no edges.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor
from torch_geometric.data import Batch, Data

from gnn_mp_envs.critical.dataset import CriticalProblems
from gnn_mp_envs.critical.halton import HaltonGraph

#: CNN image side (pixels); a 0.035-wide gap is ~2 px.
IMAGE_SIZE = 64
#: Width (pixels) of the Gaussian bumps that mark start and goal in the CNN input.
ENDPOINT_SIGMA_PX = 1.5


def node_features(nodes: np.ndarray, start: np.ndarray, goal: np.ndarray,
                  node_free: np.ndarray, with_position: bool = False) -> np.ndarray:
    """Paper eq. featurestate: ``[x_init - x_n, x_goal - x_n, obstacle indicator]`` (N, 5).

    ``with_position`` appends the node's own position ``x_n`` (N, 7), which the paper's text
    allows ("its own xy position, x_init and x_goal") and which lets the filters localise.
    """
    cols = [start[None] - nodes, goal[None] - nodes, (~node_free)[:, None].astype(np.float64)]
    if with_position:
        cols.append(nodes)
    return np.concatenate(cols, 1).astype(np.float32)


def edge_index_of(graph: HaltonGraph, edge_free: np.ndarray) -> Tensor:
    """Both directions of the problem's valid edges, shape (2, 2E')."""
    e = graph.edges[edge_free]
    return torch.from_numpy(np.concatenate([e, e[:, ::-1]]).T.copy())


def label_positions(problems: CriticalProblems, graph: HaltonGraph, i: int) -> np.ndarray:
    """The bottleneck labels of problem ``i`` as states (L, 2)."""
    return graph.nodes[problems.labels_of(i)]


def to_data(problems: CriticalProblems, graph: HaltonGraph, i: int, with_position: bool = False,
            all_edges: bool = False) -> Data:
    """One problem as a PyG graph: ``x``, ``edge_index``, ``pos`` and all labels ``y`` (L, 2).

    ``all_edges``: every edge of the fixed graph instead of the problem's valid ones.
    """
    x = node_features(graph.nodes, problems.start[i], problems.goal[i], problems.node_free[i],
                      with_position)
    free = np.ones(len(graph.edges), bool) if all_edges else problems.edge_free[i]
    return Data(x=torch.from_numpy(x), edge_index=edge_index_of(graph, free),
                pos=torch.from_numpy(graph.nodes.astype(np.float32)),
                y=torch.from_numpy(label_positions(problems, graph, i).astype(np.float32)))


def graph_batch(problems: CriticalProblems, graph: HaltonGraph, indices: np.ndarray,
                with_position: bool = False, all_edges: bool = False) -> Batch:
    """A PyG batch; ``y_batch`` maps each label to its graph (several labels per problem).

    Building a 16-problem batch takes ~11 ms, negligible next to the model pass, so
    batches are built on the fly rather than cached (cached edge indices of the 3,840
    training problems would take ~1.7 GB).
    """
    return Batch.from_data_list([to_data(problems, graph, int(i), with_position, all_edges) for i in indices],
                                follow_batch=["y"])


def occupancy_images(problems: CriticalProblems, size: int = IMAGE_SIZE) -> np.ndarray:
    """Occupancy of every problem's map (P, size, size) as uint8 (compact to keep in memory)."""
    return np.stack([problems.maze(i).occupancy(size) for i in range(len(problems))]).astype(np.uint8)


def image_batch(occupancy: np.ndarray, start: np.ndarray, goal: np.ndarray) -> Tensor:
    """CNN input (B, 3, H, W): occupancy plus Gaussian bumps at start and goal (row 0 is y=0)."""
    b, h, w = occupancy.shape
    c = (torch.arange(h, dtype=torch.float32) + 0.5) / h
    yy, xx = torch.meshgrid(c, c, indexing="ij")
    sigma = ENDPOINT_SIGMA_PX / h

    def bump(p: np.ndarray) -> Tensor:
        p = torch.as_tensor(p, dtype=torch.float32)
        d2 = (xx[None] - p[:, 0, None, None]) ** 2 + (yy[None] - p[:, 1, None, None]) ** 2
        return torch.exp(-d2 / (2 * sigma ** 2))

    occ = torch.from_numpy(occupancy.astype(np.float32))
    return torch.stack([occ, bump(start), bump(goal)], 1)


def labels_batch(problems: CriticalProblems, graph: HaltonGraph,
                 indices: np.ndarray) -> tuple[Tensor, Tensor]:
    """All labels of the given problems (L, 2) and the problem each belongs to (L,)."""
    ys = [label_positions(problems, graph, int(i)) for i in indices]
    y = torch.from_numpy(np.concatenate(ys).astype(np.float32))
    owner = torch.repeat_interleave(torch.arange(len(ys)), torch.tensor([len(v) for v in ys]))
    return y, owner
