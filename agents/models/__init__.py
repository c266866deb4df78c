"""Learned models; :mod:`agents.models.critical` holds the critical-sample networks."""

from agents.models.critical import (MODELS, CriticalCNN, CriticalCVAE, CriticalGAT, CriticalGNN,
                                    CriticalGNNCVAE, GraphPoolRegressor, build_model)

__all__ = ["MODELS", "CriticalCNN", "CriticalCVAE", "CriticalGAT", "CriticalGNN",
           "CriticalGNNCVAE", "GraphPoolRegressor", "build_model"]
