"""Learned models: :mod:`agents.models.critical` (critical samples on a fixed graph),
:mod:`agents.models.tree_samplers` (samplers over the growing tree: GNN, CVAE, GNN-CVAE) and
:mod:`agents.models.tree_scorer` (the GNN sample scorer, the pendulum's GNN head)."""

from agents.models.critical import (MODELS, CriticalCNN, CriticalCVAE, CriticalGAT, CriticalGNN,
                                    CriticalGNNCVAE, GraphPoolRegressor, build_model)
from agents.models.tree_samplers import TreeCVAE, TreeGNN, TreeGNNCVAE
from agents.models.tree_scorer import TreeGNNScorer

__all__ = ["MODELS", "CriticalCNN", "CriticalCVAE", "CriticalGAT", "CriticalGNN",
           "CriticalGNNCVAE", "GraphPoolRegressor", "TreeCVAE", "TreeGNN", "TreeGNNCVAE", "TreeGNNScorer",
           "build_model"]
