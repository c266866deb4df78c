"""Tree samplers of Algorithm 1: torch models (``models``, ``scorer``), their incremental numpy engines
(``engine`` on ``kernels``) and the samplers built on them (``samplers``)."""
