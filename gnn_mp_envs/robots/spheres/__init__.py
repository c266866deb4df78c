"""The compiled sphere checker: a robot's sphere model (:mod:`.model`: the file format; :mod:`.build`:
the builder that covers the collision meshes), forward kinematics and motion bounds
(:mod:`.kinematics`), the kernel (:mod:`.kernel`: one configuration or a whole edge per compiled call)
and the checker objects (:mod:`.checker`). Importing this package compiles nothing; the kernel
compiles (or loads from numba's cache) on its first call."""

from gnn_mp_envs.robots.spheres.model import MODEL_FORMAT, SphereModel, SphereModelError, load_sphere_model

__all__ = ["MODEL_FORMAT", "SphereModel", "SphereModelError", "load_sphere_model"]
