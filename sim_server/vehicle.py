"""Longitudinal vehicle model: normalised force to acceleration, speed in [0, set speed]."""

from __future__ import annotations

import math

from protocol.constants import A_MAX, A_MIN

__all__ = ["A_MIN", "A_MAX", "accel_of_force", "advance_speed"]



def accel_of_force(u: float) -> float:
    """Map the normalised force u in [-1, 1] to a commanded acceleration [m/s^2].

    The map is linear on each side of zero, so u = 0 coasts at constant speed
    (road load is the energy model's business, not the controller's).

    Raises:
        ValueError: if u is not finite or outside [-1, 1].
    """
    if not (math.isfinite(u) and -1.0 <= u <= 1.0):
        raise ValueError(f"force {u!r} is not a finite number in [-1, 1]")
    return u * A_MAX if u >= 0.0 else -u * A_MIN


def advance_speed(v: float, a: float, dt: float, v_max: float = math.inf) -> float:
    """Speed [m/s] after ``dt`` [s] at acceleration ``a`` [m/s^2], clamped to [0, v_max].

    ``v_max`` is the cruise set speed: the host's speed limiter, like a production
    ACC's, cuts the commanded acceleration so the speed never passes it. Braking
    is never limited.
    """
    return min(max(0.0, v + a * dt), v_max)
