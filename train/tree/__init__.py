"""``gnn-mp train sampler``: the learned tree samplers of Algorithm 1, read top to bottom.

:mod:`.data` (uniform solutions of training problems, cached), :mod:`.items` (runs as tensors),
:mod:`.adapters` (the model-specific part: build, items, loss), :mod:`.training` (the loop, DAgger,
evaluation, the run shell of :mod:`train.run`), :mod:`.cli`.
"""
