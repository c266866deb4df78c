import gnn_mp_envs  # noqa: F401  (registers the environments)
