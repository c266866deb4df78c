"""Maze2D: the unit square with walls that leave narrow passages, and its scene families.

Modules: :mod:`~gnn_mp_envs.tasks.maze2d.task` (maps, the problem, the default generator and its
family, also the critical-sample section's maps), :mod:`~gnn_mp_envs.tasks.maze2d.scenes` (the
scene families; :class:`Maze2DScenesTask` is the registered ``maze2d`` task).
"""

from gnn_mp_envs.tasks.maze2d.scenes import (
    ANGLED_KINDS,
    MIXED_KINDS,
    SCENE_FAMILIES,
    Maze2DScenesTask,
    connected,
    families,
    square_symmetry,
    turned,
    walls_as_boxes,
)
from gnn_mp_envs.tasks.maze2d.task import (
    ENDPOINT_MARGIN,
    STEP_SIZE,
    Maze2DProblem,
    Maze2DTask,
    MazeMap,
    box_corners,
    maze_rows,
    random_maze,
    render_maze2d,
    sample_endpoints,
)

__all__ = ["ANGLED_KINDS", "ENDPOINT_MARGIN", "MIXED_KINDS", "SCENE_FAMILIES", "STEP_SIZE", "Maze2DProblem",
           "Maze2DScenesTask", "Maze2DTask", "MazeMap", "box_corners", "connected", "families", "maze_rows",
           "random_maze", "render_maze2d", "sample_endpoints", "square_symmetry", "turned", "walls_as_boxes"]
