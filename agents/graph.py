"""The graph conversion, by its former import path (``from agents.graph import to_pyg``): it lives on
the shared network floor, :mod:`agents.nn.graph`."""

from agents.nn.graph import (  # noqa: F401
    GRAPH_KEYS,
    TreeGraph,
    knn_edge_index,
    real_node_counts,
    to_pyg,
    to_pyg_per_graph,
    tree_edge_index,
    tree_graph,
)

__all__ = ["GRAPH_KEYS", "TreeGraph", "knn_edge_index", "real_node_counts", "to_pyg", "to_pyg_per_graph",
           "tree_edge_index", "tree_graph"]
