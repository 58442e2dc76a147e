"""Longitudinal vehicle model: normalised force to acceleration, speed in [0, set speed]."""

from __future__ import annotations

import math

from protocol.constants import A_MAX, A_MIN
from protocol.force import accel_of_force  # the map lives below both sides; re-exported here

__all__ = ["A_MIN", "A_MAX", "accel_of_force", "advance_speed"]


def advance_speed(v: float, a: float, dt: float, v_max: float = math.inf) -> float:
    """Speed [m/s] after ``dt`` [s] at acceleration ``a`` [m/s^2], clamped to [0, v_max].

    ``v_max`` is the cruise set speed: the host's speed limiter, like a production
    ACC's, cuts the commanded acceleration so the speed never passes it. Braking
    is never limited.
    """
    return min(max(0.0, v + a * dt), v_max)
