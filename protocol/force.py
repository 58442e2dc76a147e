"""The force map: what a ``step``'s normalised force u means as an acceleration.

The simulator applies it; controllers and teachers invert it to choose a force. It lives
here, below both sides, so that neither imports the other to agree on it.
"""

from __future__ import annotations

import math

from protocol.constants import A_MAX, A_MIN

__all__ = ["accel_of_force"]


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
