"""Tree samplers of Algorithm 1: torch models (``models``, ``scorer``), their incremental engines
(``engine`` on ``compiled`` and ``kernels``) and the samplers built on them (``samplers``)."""
