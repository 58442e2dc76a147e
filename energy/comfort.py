"""Ride comfort of an acceleration trace: the ISO 15622 window tests and oscillation.

The limits are ISO 15622 (ACC performance requirements), as at highway speed:

* the mean automatic deceleration over any 2 s must not exceed 3.5 m/s²;
* the mean rate of change of acceleration (jerk) over any 1 s must not exceed 2.5 m/s³.

A run is scored by the share of its windows that break a limit. Windows slide at
the log's own rate: one window starts at every row whose window fits before the
last row. The acceleration ``a[k]`` of a run log is the host's mean acceleration
over the control period that ends at row ``k`` (``(v[k] - v[k-1]) / Δt``), so it is
held over ``(t[k-1], t[k]]``:

* mean deceleration of a window ``[t, t+T]``: ``-(∫a dt) / T`` with that hold, which
  on a simulator log equals ``-(v(t+T) - v(t)) / T``;
* mean jerk of a window ``[t, t+T]``: ``|a(t+T) - a(t)| / T``, the literal "mean rate
  of change" (``a`` between rows by linear interpolation). An oscillation faster than
  the window can pass this test; jerk RMS and the sign changes below catch it.

Sign changes count an acceleration that swings from above ``+deadband`` to below
``-deadband`` or back (a hysteresis), so noise around zero is not counted.
"""

from __future__ import annotations

import numpy as np

ISO_DECEL_WINDOW_S = 2.0  # [s] ISO 15622: mean automatic deceleration over any 2 s ...
ISO_DECEL_LIMIT_MPS2 = 3.5  # [m/s^2] ... at most this
ISO_JERK_WINDOW_S = 1.0  # [s] ISO 15622: mean jerk over any 1 s ...
ISO_JERK_LIMIT_MPS3 = 2.5  # [m/s^3] ... at most this
ACCEL_DEADBAND_MPS2 = 0.1  # [m/s^2] a sign change must cross from > +this to < -this
WINDOW_SLACK_S = 1e-6  # [s] float slack on "the window fits": logged t is k * 0.1 in floats

__all__ = [
    "ACCEL_DEADBAND_MPS2",
    "ISO_DECEL_LIMIT_MPS2",
    "ISO_DECEL_WINDOW_S",
    "ISO_JERK_LIMIT_MPS3",
    "ISO_JERK_WINDOW_S",
    "decel_window_share",
    "jerk_window_share",
    "sign_changes_per_min",
    "window_starts",
]


def window_starts(t: np.ndarray, window_s: float) -> np.ndarray:
    """Start times [s] of the sliding windows of length ``window_s`` [s] that fit in ``t``."""
    return t[t + window_s <= t[-1] + WINDOW_SLACK_S]


def decel_window_share(
    t: np.ndarray,
    accel: np.ndarray,
    window_s: float = ISO_DECEL_WINDOW_S,
    limit_mps2: float = ISO_DECEL_LIMIT_MPS2,
) -> float | None:
    """Share of windows whose mean deceleration exceeds ``limit_mps2``.

    Args:
        t: time [s], strictly increasing.
        accel: acceleration [m/s^2], ``accel[k]`` held over ``(t[k-1], t[k]]``.
        window_s: window length [s].
        limit_mps2: deceleration limit [m/s^2], > 0.

    Returns:
        The share in [0, 1], or None when the trace is shorter than one window.
    """
    starts = window_starts(t, window_s)
    if starts.size == 0:
        return None
    dv = np.concatenate([[0.0], np.cumsum(accel[1:] * np.diff(t))])  # [m/s] ∫a dt from t[0]
    mean_a = (np.interp(starts + window_s, t, dv) - np.interp(starts, t, dv)) / window_s
    return float(np.mean(-mean_a > limit_mps2))


def jerk_window_share(
    t: np.ndarray,
    accel: np.ndarray,
    window_s: float = ISO_JERK_WINDOW_S,
    limit_mps3: float = ISO_JERK_LIMIT_MPS3,
) -> float | None:
    """Share of windows whose mean jerk ``|a(t+T) - a(t)| / T`` exceeds ``limit_mps3``.

    Args:
        t: time [s], strictly increasing.
        accel: acceleration [m/s^2] at each row.
        window_s: window length T [s].
        limit_mps3: jerk limit [m/s^3].

    Returns:
        The share in [0, 1], or None when the trace is shorter than one window.
    """
    starts = window_starts(t, window_s)
    if starts.size == 0:
        return None
    mean_jerk = np.abs(np.interp(starts + window_s, t, accel) - np.interp(starts, t, accel))
    return float(np.mean(mean_jerk / window_s > limit_mps3))


def sign_changes_per_min(
    t: np.ndarray, accel: np.ndarray, deadband_mps2: float = ACCEL_DEADBAND_MPS2
) -> float | None:
    """Sign changes of acceleration per minute, with a deadband.

    Args:
        t: time [s], strictly increasing.
        accel: acceleration [m/s^2].
        deadband_mps2: a change counts only from ``> +deadband`` to ``< -deadband`` or
            back [m/s^2]; rows inside the band keep the last sign.

    Returns:
        Changes per minute of ``t[-1] - t[0]``, or None for fewer than two rows.
    """
    if t.size < 2:
        return None
    sign = np.where(accel > deadband_mps2, 1, np.where(accel < -deadband_mps2, -1, 0))
    outside = sign[sign != 0]  # the band keeps the last sign: drop its rows
    changes = int(np.count_nonzero(np.diff(outside)))
    return changes / ((t[-1] - t[0]) / 60.0)
