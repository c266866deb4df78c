"""Tree samplers of Algorithm 1: torch models (``models``, ``scorer``: heads over the shared causal
trunk of :mod:`agents.nn.causal`), their incremental engines (``engine`` on ``compiled`` and the numpy
twins of :mod:`agents.nn.twins`), the samplers built on them (``samplers``), the candidate priors
they give a picker (``prior``) and the GNN as an RL backbone (``backbone``)."""
