"""Everything learned: imports ``gnn_mp_envs``, never the reverse.

- ``agents.graph``: padded observation (any batch shape) -> PyG ``Batch``; k-NN edges.
- ``agents.encoders``: ``TreeEncoder`` / ``EncoderModule``, the GNN every model shares.
- ``agents.samplers``: the sampler interface and registry (``load_sampler``), ``LearnedSampler``.
- ``agents.torchrl``: ``make_actor`` / ``make_value`` over the encoder (TorchRL).
- ``agents.sb3``: ``TreeFeaturesExtractor`` (Stable-Baselines3).

Submodules are imported on use: ``import agents`` pulls in neither PyTorch Geometric nor
TorchRL nor SB3.
"""
