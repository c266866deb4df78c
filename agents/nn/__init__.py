"""The shared network floor: the pieces every learned method builds on, importing no method.

- ``graph``: padded observation (any batch shape) -> PyG ``Batch`` / graph tensors; k-NN edges;
- ``encoders``: ``TreeEncoder`` (PyG convolutions over the tree), ``CandidateEncoder`` (a picker's
  candidates) and the registry of encoders by name (``ENCODERS``, ``encoder_from_space``);
- ``causal``: the causal tree GNN trunk (``CausalTreeTrunk``, ``RelativeConv``, ``causal_knn``)
  that the tree samplers' models are heads over;
- ``twins``: numpy twins of torch layers (float64 for the tree engines, float32 for the RL policies);
- ``priors``: candidate priors by the checkpoint kind of the model they read (how a picker reaches
  a supervised model's prior without importing its method).

A method names another's class only as a registry entry (``"module:attribute"``, imported on first
use), never in an import (``tests/test_architecture.py``).
"""
