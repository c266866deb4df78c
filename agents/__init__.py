"""Everything learned: imports ``gnn_mp_envs``, never the reverse; never imports ``train``.

Shared floor:

- ``agents.samplers``: the sampler interface, its one base (``Sampler``, ``ModelSampler``: one
  uniform / goal / model mixture, one seeded stream) and the classical samplers;
- ``agents.registry``: ``load_sampler(name, task=...)``, bounds from the task's ``TaskSpec``;
- ``agents.checkpoints``: the one checkpoint format (``weights_only=True``) and the shipped weights;
- ``agents.nn``: the shared network pieces: graph conversion (``graph``), the encoders and their
  registry by name (``encoders``), the causal tree GNN trunk (``causal``), numpy twins of torch
  layers (``twins``), candidate priors by model kind (``priors``).

One folder per method (no method imports another; the shared floor imports no method):

- ``agents.tree``: the tree samplers of Algorithm 1 (GNN, GNN scorer, CVAE, GNN-CVAE): torch
  models (``models``, ``scorer``), their incremental numpy engines (``engine``, ``compiled``), the
  samplers (``samplers``), the candidate priors (``prior``) and the GNN as an RL backbone (``backbone``);
- ``agents.rl``: RL policies (``policies``), the TensorDict encoder module (``backbones``), the SB3
  features extractor (``sb3``), the TorchRL actor and value (``torchrl``) and the policies as
  samplers (``sampler``);
- ``agents.critical``: critical-sample models on the fixed Halton graph and their data adapter.

Submodules are imported on use: ``import agents`` pulls in neither PyTorch Geometric nor
TorchRL nor SB3.
"""
