"""Small helpers shared by the environments, the learned agents and the entry points (numpy-free)."""

from gnn_mp_envs.utils.io import atomic_path, atomic_write_bytes, atomic_write_text

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text"]
