"""Everything learned: imports ``gnn_mp_envs``, never the reverse; never imports ``train``.

Shared floor:

- ``agents.samplers``: the sampler interface, its one base (``Sampler``, ``ModelSampler``: one
  uniform / goal / model mixture, one seeded stream) and the classical samplers;
- ``agents.registry``: ``load_sampler(name, task=...)``, bounds from the task's ``TaskSpec``;
- ``agents.checkpoints``: the one checkpoint format (``weights_only=True``) and the shipped weights;
- ``agents.graph``: padded observation (any batch shape) -> PyG ``Batch``; k-NN edges;
- ``agents.encoders``: ``TreeEncoder``, a PyG graph encoder of the tree observation.

One folder per method:

- ``agents.tree``: the tree samplers of Algorithm 1 (GNN, GNN scorer, CVAE, GNN-CVAE): torch
  models (``models``, ``scorer``), their incremental numpy engines (``engine``, ``kernels``) and
  the samplers (``samplers``);
- ``agents.rl``: RL policies (``policies``), backbones, the SB3 features extractor (``sb3``), the
  TorchRL actor and value (``torchrl``) and the policies as samplers (``sampler``);
- ``agents.critical``: critical-sample models on the fixed Halton graph and their data adapter.

Submodules are imported on use: ``import agents`` pulls in neither PyTorch Geometric nor
TorchRL nor SB3.
"""
