"""The single converter from the padded tree observation to PyTorch Geometric graphs.

Every model that reads the tree (GNN, GAT, GNN-CVAE samplers, SB3 and TorchRL feature
extractors) goes through :func:`to_pyg`, so the padding convention lives in one place.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch
from torch_geometric.data import Batch, Data


def _as_tensor(x, dtype=None) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    return t.to(dtype) if dtype is not None else t


def tree_edge_index(parent: torch.Tensor, num_nodes: int) -> torch.Tensor:
    """Undirected edge index (2, 2E) of the tree edges among the first ``num_nodes`` rows."""
    parent = parent[:num_nodes].long()
    child = torch.nonzero(parent >= 0, as_tuple=False).flatten()
    src = parent[child]
    return torch.stack([torch.cat([src, child]), torch.cat([child, src])])


def to_pyg(obs: Mapping, features: str = "node_features") -> Data | Batch:
    """Padded observation (unbatched or with one leading batch dim) -> ``Data`` or ``Batch``.

    Node features ``x`` are the observation's ``features`` rows of the real nodes; ``pos``
    holds their states; graph-level ``start``, ``goal`` and ``active_tree`` are kept
    with a leading graph dimension so batched models can read them per graph.
    """
    feats = _as_tensor(obs[features], torch.float32)
    if feats.dim() == 2:
        return _one_graph(obs, feats, None)
    return Batch.from_data_list([_one_graph(obs, feats[b], b) for b in range(feats.shape[0])])


def _one_graph(obs: Mapping, feats: torch.Tensor, b: int | None) -> Data:
    def get(key, dtype=None):
        t = _as_tensor(obs[key], dtype)
        return t if b is None else t[b]

    n = int(get("num_nodes").reshape(-1)[0])
    if n <= 0:  # a batched TorchRL reset may hand over zero-padded rows; fall back to the mask
        n = int(get("mask").sum())
    return Data(
        x=feats[:n],
        pos=get("nodes", torch.float32)[:n],
        edge_index=tree_edge_index(get("parent"), n),
        start=get("start", torch.float32).reshape(1, -1),
        goal=get("goal", torch.float32).reshape(1, -1),
        active_tree=get("active_tree", torch.long).reshape(1),
        num_nodes=n,
    )
