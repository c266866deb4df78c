"""Critical samples on a constant Halton graph (paper Sec. "Learning Critical Samples with GNNs").

numpy/scipy only: graph (:mod:`.halton`), ground truth (:mod:`.bottleneck`), seeded cached
datasets (:mod:`.dataset`) and planning with predicted samples (:mod:`.planning`). Models
and training live in ``agents/models/critical.py`` and ``train/critical/``.
"""

from gnn_mp_envs.critical.bottleneck import BottleneckResult, bottleneck_nodes, problem_graph, valid_edges
from gnn_mp_envs.critical.dataset import (CriticalProblems, DatasetCacheError, DatasetConfig, load_problems,
                                          save_problems)
from gnn_mp_envs.critical.halton import HaltonGraph, halton_graph, halton_points

__all__ = ["BottleneckResult", "bottleneck_nodes", "problem_graph", "valid_edges",
           "DatasetConfig", "DatasetCacheError", "CriticalProblems", "load_problems", "save_problems",
           "HaltonGraph", "halton_graph", "halton_points"]
