"""RL samplers: policies as plain modules (``policies``), backbones by name (``backbones``), the SB3
features extractor (``sb3``), the TorchRL actor and value (``torchrl``), policies as samplers (``sampler``)."""
