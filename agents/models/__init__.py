"""Learned models: :mod:`agents.models.critical` (critical samples on a fixed graph) and
:mod:`agents.models.tree_samplers` (samplers over the growing tree: GNN, CVAE, GNN-CVAE)."""

from agents.models.critical import (MODELS, CriticalCNN, CriticalCVAE, CriticalGAT, CriticalGNN,
                                    CriticalGNNCVAE, GraphPoolRegressor, build_model)
from agents.models.tree_samplers import TreeCVAE, TreeGNN, TreeGNNCVAE

__all__ = ["MODELS", "CriticalCNN", "CriticalCVAE", "CriticalGAT", "CriticalGNN",
           "CriticalGNNCVAE", "GraphPoolRegressor", "TreeCVAE", "TreeGNN", "TreeGNNCVAE", "build_model"]
