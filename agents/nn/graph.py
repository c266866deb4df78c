"""The single converter from the padded tree observation to PyTorch Geometric graphs.

Every model that reads the tree (GNN, GAT, GNN-CVAE samplers, SB3 and TorchRL feature
extractors) goes through :func:`to_pyg`, so the padding convention lives in one place.

The conversion is vectorised over any leading batch shape: the real nodes of each element
are its prefix rows ``0..num_nodes-1`` (see :mod:`gnn_mp_envs.envs.observation`), so the
node rows are gathered with one boolean mask, graph offsets come from a cumulative sum and
the tree edges from one ``nonzero`` over the padded ``parent`` block. No Python loop over
batch elements. :func:`to_pyg_per_graph` is the obvious per-element reference (used by the
tests and ``python -m tools.bench_sampler``).
"""

from __future__ import annotations

from typing import Mapping, NamedTuple

import numpy as np
import torch
from torch_geometric.data import Batch, Data

#: Graph-level entries copied from the observation, one row per graph.
GRAPH_KEYS = ("start", "goal", "active_tree")


def _as_tensor(x, dtype=None) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    return t.to(dtype) if dtype is not None else t


def _as_index(x) -> torch.Tensor:
    """Integer view of an index-valued entry that may arrive as float (SB3 casts every Box)."""
    t = _as_tensor(x)
    if t.is_floating_point():
        t = t.round()
    return t.long()


def tree_edge_index(parent: torch.Tensor, num_nodes: int) -> torch.Tensor:
    """Undirected edge index (2, 2E) of the tree edges among the first ``num_nodes`` rows.

    Children in index order, each edge in both directions next to each other: row 0 is
    ``[p_a, a, p_b, b, ...]`` and row 1 ``[a, p_a, b, p_b, ...]``. Parents outside
    ``0..num_nodes-1`` (roots, padding, corrupt rows) give no edge.
    """
    parent = _as_index(parent)[:num_nodes]
    child = torch.nonzero((parent >= 0) & (parent < num_nodes), as_tuple=False).flatten()
    src = parent[child]
    return torch.stack([torch.stack([src, child], 1).view(-1), torch.stack([child, src], 1).view(-1)])


def real_node_counts(obs: Mapping) -> torch.Tensor:
    """Number of real nodes per element, flattened to ``(B,)`` over the leading batch shape.

    ``num_nodes`` when positive, otherwise ``mask.sum()``: a batched TorchRL reset may hand
    over rows whose ``num_nodes`` entry is zeroed.
    """
    n = _as_index(obs["num_nodes"]).reshape(-1)
    if bool((n <= 0).any()):
        mask = _as_tensor(obs["mask"])
        from_mask = mask.reshape(n.shape[0], -1).sum(-1).round().long() if mask.is_floating_point() \
            else mask.reshape(n.shape[0], -1).sum(-1).long()
        n = torch.where(n > 0, n, from_mask)
    return n


class TreeGraph(NamedTuple):
    """The tensors of :func:`to_pyg`'s graph, without PyG's container (what encoders compute on).

    ``x``, ``pos``, ``edge_index``, ``batch`` and ``ptr`` as in the ``Batch``; per graph ``start``,
    ``goal`` ``(B, d)``, ``active_tree`` ``(B,)`` and ``counts`` (real nodes); ``edge_ptr`` the
    slice of each graph's edges; ``batch_shape`` the observation's leading shape (``()``: one
    graph, whose ``batch`` is all zeros and ``ptr`` ``[0, n]``).
    """

    x: torch.Tensor
    pos: torch.Tensor
    edge_index: torch.Tensor
    batch: torch.Tensor
    ptr: torch.Tensor
    counts: torch.Tensor
    start: torch.Tensor
    goal: torch.Tensor
    active_tree: torch.Tensor
    edge_ptr: torch.Tensor
    batch_shape: torch.Size


def tree_graph(obs: Mapping, features: str = "node_features") -> TreeGraph:
    """The padded observation (any leading batch shape) as graph tensors: the conversion of
    :func:`to_pyg`, which wraps this result in a PyG ``Batch`` / ``Data``."""
    feats = _as_tensor(obs[features], torch.float32)
    batch_shape = feats.shape[:-2]
    if len(batch_shape) == 0:      # one graph: plain slicing has less fixed overhead (4x at 1,000 nodes)
        return _one_graph(obs, feats)
    N, F = feats.shape[-2:]
    B = int(np.prod(batch_shape))
    feats = feats.reshape(B, N, F)
    nodes = _as_tensor(obs["nodes"], torch.float32).reshape(B, N, -1)
    parent = _as_index(obs["parent"]).reshape(B, N)
    counts = real_node_counts(obs).clamp(0, N)
    d = nodes.shape[-1]
    start = _as_tensor(obs["start"], torch.float32).reshape(B, d)
    goal = _as_tensor(obs["goal"], torch.float32).reshape(B, d)
    active_tree = _as_index(obs["active_tree"]).reshape(B)

    dev = feats.device
    ptr = torch.zeros(B + 1, dtype=torch.long, device=dev)
    torch.cumsum(counts, 0, out=ptr[1:])
    total = int(ptr[-1])
    graph = torch.arange(B, device=dev)
    batch = torch.repeat_interleave(graph, counts, output_size=total)
    # Row of each real node in the flattened (B * N) padded block: graph b's nodes are rows
    # b*N .. b*N + counts[b] - 1. Per-node values of per-graph quantities come from
    # repeat_interleave, and rows are gathered with index_select: both several times faster
    # than advanced or boolean indexing.
    first = ptr[:-1]                                                # first node id of each graph
    if total == B * N:                                              # every element full: views
        x, pos, par = feats.reshape(-1, F), nodes.reshape(B * N, -1), parent.reshape(-1)
        is_child = (par >= 0) & (par < N)
    else:
        rows = torch.arange(total, device=dev) + torch.repeat_interleave(graph * N - first, counts,
                                                                         output_size=total)
        x = feats.reshape(-1, F).index_select(0, rows)
        pos = nodes.reshape(B * N, -1).index_select(0, rows)
        par = parent.reshape(-1).index_select(0, rows)
        is_child = (par >= 0) & (par < torch.repeat_interleave(counts, counts, output_size=total))

    # Tree edges: real nodes whose parent is a real node of the same graph, sorted by graph,
    # each edge in both directions next to each other (the order of tree_edge_index), so
    # graph b's edges are the slice edge_ptr[b]:edge_ptr[b+1].
    child = torch.nonzero(is_child).squeeze(1)                     # global node ids, sorted
    src = (par + torch.repeat_interleave(first, counts, output_size=total)).index_select(0, child)
    m = child.numel()
    pairs = torch.empty(2, m, 2, dtype=torch.long, device=dev)
    pairs[0, :, 0] = src
    pairs[0, :, 1] = child
    pairs[1, :, 0] = child
    pairs[1, :, 1] = src
    edge_index = pairs.view(2, 2 * m)
    edge_ptr = 2 * torch.searchsorted(child, ptr)
    return TreeGraph(x, pos, edge_index, batch, ptr, counts, start, goal, active_tree, edge_ptr, batch_shape)


def to_pyg(obs: Mapping, features: str = "node_features") -> Data | Batch:
    """Padded observation (any leading batch shape) -> PyG ``Batch`` (unbatched: ``Data``).

    ``obs`` is a numpy dict, a dict of tensors or a ``TensorDict`` with the keys of
    :data:`gnn_mp_envs.envs.observation.OBSERVATION_KEYS`, each with the same leading batch
    shape ``S`` (possibly empty, possibly more than one dimension; the ``B = prod(S)`` graphs
    are numbered in row-major order). Integer entries (``parent``, ``num_nodes``, ``mask``,
    ``active_tree``) may be floats.

    The result holds ``x`` (the ``features`` rows of the real nodes, float32), ``pos`` (their
    states), ``edge_index`` (tree edges, both directions, as :func:`tree_edge_index` orders
    them per graph), ``batch`` and ``ptr``, and per graph ``start`` and ``goal`` ``(B, d)``
    and ``active_tree`` ``(B,)``; it equals ``Batch.from_data_list`` of the per-graph
    ``Data`` (``get_example``/``to_data_list`` work). An unbatched observation returns one
    ``Data`` whose ``start``/``goal`` are ``(1, d)`` and ``active_tree`` ``(1,)``.
    """
    g = tree_graph(obs, features)
    if len(g.batch_shape) == 0:
        return Data(x=g.x, pos=g.pos, edge_index=g.edge_index, start=g.start, goal=g.goal,
                    active_tree=g.active_tree, num_nodes=int(g.counts[0]))
    B, total, dev = g.counts.numel(), int(g.ptr[-1]), g.x.device
    out = Batch(_base_cls=Data, x=g.x, edge_index=g.edge_index, pos=g.pos, start=g.start, goal=g.goal,
                active_tree=g.active_tree, num_nodes=total, batch=g.batch, ptr=g.ptr)
    # Bookkeeping that Batch.from_data_list writes, so get_example / to_data_list work.
    graph_ptr = torch.arange(B + 1, device=dev)
    zeros = torch.zeros(B, dtype=torch.long, device=dev)
    out._slice_dict = {"x": g.ptr, "edge_index": g.edge_ptr, "pos": g.ptr,
                       "start": graph_ptr, "goal": graph_ptr, "active_tree": graph_ptr}
    out._inc_dict = {"x": zeros, "edge_index": g.ptr[:-1], "pos": zeros,
                     "start": zeros, "goal": zeros, "active_tree": zeros}
    out._num_graphs = B
    out._store._num_nodes = g.counts.tolist()
    return out


#: The arrays of ``TreePlanningEnv.export_tree``, the input of :func:`tree_data`.
TREE_KEYS = ("states", "parent", "tree_id", "cost", "controls", "edges", "start", "goal", "path_nodes")


def tree_data(tree: Mapping) -> Data:
    """A tree exported by ``TreePlanningEnv.export_tree`` (or loaded back from ``np.savez``) as a
    PyTorch Geometric ``Data``: ``pos`` the node states (float64, exact), ``x`` the same as float32
    (what a model reads), ``edge_index`` the tree edges in both directions (the order of
    :func:`tree_edge_index`, as :func:`to_pyg`), and per node ``parent``, ``tree_id``, ``cost``,
    ``controls``; ``start`` and ``goal`` ``(1, d)``; ``path_nodes`` the returned path (empty
    until solved)."""
    missing = [k for k in TREE_KEYS if k not in tree]
    if missing:
        raise ValueError(f"tree_data: not an export_tree() result, missing {missing}")
    states = torch.as_tensor(np.asarray(tree["states"], dtype=np.float64))
    n = states.shape[0]
    parent = torch.as_tensor(np.asarray(tree["parent"], dtype=np.int64))
    if states.dim() != 2 or parent.shape != (n,):
        raise ValueError(f"tree_data: states must be (n, d) and parent (n,), got {tuple(states.shape)} and "
                         f"{tuple(parent.shape)}")
    return Data(x=states.float(), pos=states, edge_index=tree_edge_index(parent, n), parent=parent,
                tree_id=torch.as_tensor(np.asarray(tree["tree_id"], dtype=np.int64)),
                cost=torch.as_tensor(np.asarray(tree["cost"], dtype=np.float64)),
                controls=torch.as_tensor(np.asarray(tree["controls"], dtype=np.float64)),
                start=torch.as_tensor(np.asarray(tree["start"], dtype=np.float64)).reshape(1, -1),
                goal=torch.as_tensor(np.asarray(tree["goal"], dtype=np.float64)).reshape(1, -1),
                path_nodes=torch.as_tensor(np.asarray(tree["path_nodes"], dtype=np.int64)), num_nodes=n)


def to_pyg_per_graph(obs: Mapping, features: str = "node_features") -> Data | Batch:
    """Reference for :func:`to_pyg`: one ``Data`` per element, then ``Batch.from_data_list``.

    Slow for batches (a Python loop over them); kept for ``python -m tools.bench_sampler``. An
    unbatched observation takes the same path in both.
    """
    feats = _as_tensor(obs[features], torch.float32)
    batch_shape = feats.shape[:-2]
    if len(batch_shape) == 0:
        return to_pyg(obs, features)
    B = int(np.prod(batch_shape))
    flat = {k: _as_tensor(obs[k]).reshape(B, *_as_tensor(obs[k]).shape[len(batch_shape):])
            for k in obs.keys()}
    return Batch.from_data_list([to_pyg({k: v[b] for k, v in flat.items()}, features) for b in range(B)])


def _one_graph(obs: Mapping, feats: torch.Tensor) -> TreeGraph:
    n = int(_as_index(obs["num_nodes"]).reshape(-1)[0])
    if n <= 0:  # a batched TorchRL reset may hand over zero-padded rows; fall back to the mask
        n = int(_as_tensor(obs["mask"]).sum())
    n = min(n, feats.shape[0])
    edge_index = tree_edge_index(obs["parent"], n)
    return TreeGraph(
        x=feats[:n],
        pos=_as_tensor(obs["nodes"], torch.float32)[:n],
        edge_index=edge_index,
        batch=torch.zeros(n, dtype=torch.long, device=feats.device),
        ptr=torch.tensor([0, n], device=feats.device),
        counts=torch.tensor([n], device=feats.device),
        start=_as_tensor(obs["start"], torch.float32).reshape(1, -1),
        goal=_as_tensor(obs["goal"], torch.float32).reshape(1, -1),
        active_tree=_as_index(obs["active_tree"]).reshape(1),
        edge_ptr=torch.tensor([0, edge_index.shape[1]], device=feats.device),
        batch_shape=torch.Size(),
    )


def knn_edge_index(pos: torch.Tensor, batch: torch.Tensor | None = None, k: int = 8, loop: bool = False,
                   max_block: int = 1 << 22) -> torch.Tensor:
    """Edges (2, E) from each node's ``k`` nearest neighbours within its own graph.

    Like PyG's ``knn_graph`` (flow ``source_to_target``: row 0 holds the neighbour, row 1
    the centre node), but without torch-cluster: the graphs are laid out as a padded
    ``(B, N, d)`` block and distances come from ``torch.cdist`` + ``topk``, computed for
    as many graphs (and, for one large graph, as many query rows) at a time as fit in
    ``max_block`` distance entries. ``batch`` must be sorted (as in every PyG batch); a
    graph with ``n <= k`` nodes links each node to all the others. ``loop=True`` counts a
    node as its own neighbour. Euclidean distance on ``pos`` (angles are not wrapped).
    """
    if pos.dim() != 2:
        raise ValueError(f"pos must be (num_nodes, d), got shape {tuple(pos.shape)}")
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    total = pos.shape[0]
    if total == 0:
        return torch.empty(2, 0, dtype=torch.long, device=pos.device)
    if batch is None:
        batch = torch.zeros(total, dtype=torch.long, device=pos.device)
    counts = torch.bincount(batch)
    B = counts.numel()
    ptr = torch.zeros(B + 1, dtype=torch.long, device=pos.device)
    torch.cumsum(counts, 0, out=ptr[1:])
    N = int(counts.max())
    kk = min(k, N if loop else N - 1)
    if kk <= 0:
        return torch.empty(2, 0, dtype=torch.long, device=pos.device)
    local = torch.arange(total, device=pos.device) - ptr[batch]
    dense = pos.new_zeros(B, N, pos.shape[1])
    dense[batch, local] = pos
    real = torch.zeros(B, N, dtype=torch.bool, device=pos.device)
    real[batch, local] = True

    rows = max(1, min(N, max_block // N))             # query rows per block
    graphs = max(1, max_block // (rows * N))          # graphs per block
    inf = float("inf")
    src_parts, dst_parts = [], []
    for g0 in range(0, B, graphs):
        g1 = min(B, g0 + graphs)
        keys = dense[g0:g1]
        base = ptr[g0:g1, None, None]                 # first node id of each graph
        padded = not bool(real[g0:g1].all())
        for r0 in range(0, N, rows):
            r1 = min(N, r0 + rows)
            dist = torch.cdist(dense[g0:g1, r0:r1], keys)           # (G, R, N)
            if padded:
                dist.masked_fill_(~real[g0:g1, None, :], inf)
            if not loop:                                            # entries (r, r): a strided view
                torch.diagonal(dist, offset=r0, dim1=1, dim2=2).fill_(inf)
            val, idx = dist.topk(kk, dim=-1, largest=False)        # (G, R, kk)
            src = idx + base
            dst = (torch.arange(r0, r1, device=pos.device)[None, :, None] + base).expand_as(idx)
            keep = torch.isfinite(val)
            if padded:
                keep &= real[g0:g1, r0:r1, None]
            if bool(keep.all()):
                src_parts.append(src.reshape(-1))
                dst_parts.append(dst.reshape(-1))
            else:
                src_parts.append(src[keep])
                dst_parts.append(dst[keep])
    return torch.stack([torch.cat(src_parts), torch.cat(dst_parts)])
