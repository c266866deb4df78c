"""Problem indices -> model inputs (graph batches or occupancy images), one adapter for all models."""

from __future__ import annotations

import numpy as np
import torch

from agents.critical.data import graph_batch, image_batch, label_positions, occupancy_images
from agents.critical.models import MODELS, NODE_FEATURES, NODE_FEATURES_WITH_POSITION
from gnn_mp_envs.critical.dataset import CriticalProblems
from gnn_mp_envs.critical.halton import HaltonGraph


class Inputs:
    """Turns problem indices into model inputs; caches occupancy images for the CNNs.

    Graph inputs: ``x``, ``edge_index``, ``batch``, ``pos``, all labels ``y`` with ``owner``
    (the problem of each label) and ``label_index`` (the labels' node rows in the batch).
    Image inputs: ``image``, ``y``, ``owner``, the graph's node positions ``pos`` (N, 2) and
    ``label_index`` (rows of the flattened (B * N) node scores). Both carry ``size``.
    """

    def __init__(self, problems: CriticalProblems, graph: HaltonGraph, kind: str,
                 with_position: bool = False, all_edges: bool = False) -> None:
        self.problems, self.graph, self.kind = problems, graph, kind
        self.with_position, self.all_edges = with_position, all_edges
        self.occupancy = occupancy_images(problems) if kind == "image" else None

    def label_index(self, idx: np.ndarray) -> torch.Tensor:
        """The label nodes of problems ``idx`` as rows of a batch of graphs (problem-major)."""
        n, ptr = self.graph.num_nodes, self.problems.label_ptr
        lab = [self.problems.label_nodes[ptr[i]:ptr[i + 1]] + k * n for k, i in enumerate(idx)]
        return torch.from_numpy(np.concatenate(lab).astype(np.int64))

    def __call__(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        if self.kind == "graph":
            b = graph_batch(self.problems, self.graph, idx, self.with_position, self.all_edges)
            return {"x": b.x, "edge_index": b.edge_index, "batch": b.batch, "pos": b.pos,
                    "y": b.y, "owner": b.y_batch, "size": len(idx), "label_index": self.label_index(idx)}
        ys = [label_positions(self.problems, self.graph, int(i)) for i in idx]
        # pos / label_index: the graph's nodes, where a heat-map CNN is read and trained
        return {"image": image_batch(self.occupancy[idx], self.problems.start[idx], self.problems.goal[idx]),
                "y": torch.from_numpy(np.concatenate(ys).astype(np.float32)),
                "owner": torch.repeat_interleave(torch.arange(len(ys)), torch.tensor([len(v) for v in ys])),
                "size": len(idx), "pos": self.pos, "label_index": self.label_index(idx)}

    @property
    def pos(self) -> torch.Tensor:
        return torch.from_numpy(self.graph.nodes.astype(np.float32))


def uses_position(model: torch.nn.Module) -> bool:
    """Whether a graph model reads the 7 node features (``x_n`` appended) rather than 5."""
    return getattr(model, "in_channels", NODE_FEATURES) == NODE_FEATURES_WITH_POSITION


def inputs_for(model: torch.nn.Module, name: str, problems: CriticalProblems, graph: HaltonGraph) -> Inputs:
    """The input builder matching a model's family, feature width and edge mode."""
    kind = MODELS[name][1]
    if kind != "graph":
        return Inputs(problems, graph, kind)
    return Inputs(problems, graph, kind, uses_position(model), getattr(model, "edges", "valid") == "all")
