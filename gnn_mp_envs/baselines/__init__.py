"""Reference planners outside the planner core (OMPL), run on the same problems and checkers."""

from gnn_mp_envs.baselines.ompl_runner import OMPLUnavailableError, ompl_available, run_ompl

__all__ = ["OMPLUnavailableError", "ompl_available", "run_ompl"]
