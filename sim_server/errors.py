"""Errors of the simulator server."""

from __future__ import annotations

__all__ = ["SimError", "TrajectoryError", "ScenarioError", "InitialConditionError"]


class SimError(Exception):
    """Base class of every error raised by :mod:`sim_server`."""


class TrajectoryError(ValueError, SimError):
    """A lead trajectory that cannot be built: unknown name or bad trace data."""


class ScenarioError(ValueError, SimError):
    """An unknown scenario name."""


class InitialConditionError(ValueError, SimError):
    """A reset's host speed, gap or set speed outside its allowed range."""
