"""The tree and candidate encoders, by their former import path (``from agents.encoders import
TreeEncoder``): they live on the shared network floor, :mod:`agents.nn.encoders`."""

from agents.nn.encoders import *  # noqa: F401,F403
from agents.nn.encoders import __all__  # noqa: F401
