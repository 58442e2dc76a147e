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

Unprompted hard brakes count a deceleration past ISO's 3.5 m/s² that nothing ahead asked
for in the second before: a phantom brake (a learned policy braking at a shadow in the next
lane, docs/training.md), which a 2-s window test can miss when the brake is released fast.
"""

from __future__ import annotations

import numpy as np

ISO_DECEL_WINDOW_S = 2.0  # [s] ISO 15622: mean automatic deceleration over any 2 s ...
ISO_DECEL_LIMIT_MPS2 = 3.5  # [m/s^2] ... at most this
ISO_JERK_WINDOW_S = 1.0  # [s] ISO 15622: mean jerk over any 1 s ...
ISO_JERK_LIMIT_MPS3 = 2.5  # [m/s^3] ... at most this
ACCEL_DEADBAND_MPS2 = 0.1  # [m/s^2] a sign change must cross from > +this to < -this
WINDOW_SLACK_S = 1e-6  # [s] float slack on "the window fits": logged t is k * 0.1 in floats
# A hard brake answers a threat if, within PROMPT_WINDOW_S before its onset, the time to
# collision was under PROMPT_TTC_S (the ACC's ttc_engage), the time headway under
# PROMPT_HEADWAY_S (a car cut in close ahead), or the lead braked at PROMPT_LEAD_DECEL_MPS2 or more.
PROMPT_WINDOW_S = 1.0  # [s] a perception delay's worth: a camera policy reacts late
PROMPT_TTC_S = 6.0  # [s]
PROMPT_HEADWAY_S = 1.0  # [s]
PROMPT_LEAD_DECEL_MPS2 = 2.0  # [m/s^2]

__all__ = [
    "ACCEL_DEADBAND_MPS2",
    "ISO_DECEL_LIMIT_MPS2",
    "ISO_DECEL_WINDOW_S",
    "ISO_JERK_LIMIT_MPS3",
    "ISO_JERK_WINDOW_S",
    "decel_window_share",
    "jerk_window_share",
    "sign_changes_per_min",
    "unprompted_hard_brakes",
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


def unprompted_hard_brakes(
    t: np.ndarray,
    accel: np.ndarray,
    gap: np.ndarray,
    v_host: np.ndarray,
    v_lead: np.ndarray,
    limit_mps2: float = ISO_DECEL_LIMIT_MPS2,
) -> int:
    """Hard brakes that nothing ahead asked for.

    An onset is a row whose acceleration is below ``-limit_mps2`` after a row that is not.
    It is prompted if at any row from :data:`PROMPT_WINDOW_S` before it up to it the time to
    collision ``gap / (v_host - v_lead)`` was under :data:`PROMPT_TTC_S` (closing in), the
    time headway ``gap / v_host`` under :data:`PROMPT_HEADWAY_S`, or the lead decelerated
    (from one row to the next) by :data:`PROMPT_LEAD_DECEL_MPS2` or more.

    Args:
        t: time [s], strictly increasing.
        accel: the host's acceleration [m/s^2] at each row.
        gap: the gap [m]; v_host, v_lead: speeds [m/s].
        limit_mps2: the deceleration that counts as hard [m/s^2], > 0.

    Returns:
        The number of unprompted onsets.
    """
    if t.size < 2:
        return 0
    closing = v_host - v_lead
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc_short = (closing > 0.0) & (np.maximum(gap, 0.0) < PROMPT_TTC_S * closing)
        headway_short = np.maximum(gap, 0.0) < PROMPT_HEADWAY_S * v_host
    lead_decel = np.concatenate([[0.0], -np.diff(v_lead) / np.diff(t)])
    threat = ttc_short | headway_short | (lead_decel >= PROMPT_LEAD_DECEL_MPS2)
    hard = accel < -limit_mps2
    onsets = np.flatnonzero(hard[1:] & ~hard[:-1]) + 1
    first = np.searchsorted(t, t[onsets] - PROMPT_WINDOW_S - WINDOW_SLACK_S)  # each onset's look-back starts here
    threats = np.concatenate([[0], np.cumsum(threat)])  # threat rows before each row
    return int(np.count_nonzero(threats[onsets + 1] == threats[first]))
