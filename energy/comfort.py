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

from typing import TypeVar

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

F = TypeVar("F", float, np.ndarray)

__all__ = [
    "ACCEL_DEADBAND_MPS2",
    "ISO_DECEL_LIMIT_MPS2",
    "ISO_DECEL_WINDOW_S",
    "ISO_JERK_LIMIT_MPS3",
    "ISO_JERK_WINDOW_S",
    "decel_window_share",
    "decel_windows_over",
    "jerk_window_share",
    "jerk_windows_over",
    "prompt_window_start",
    "sign_changes",
    "sign_changes_per_min",
    "unprompted_hard_brakes",
    "unprompted_onsets",
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
    n = window_starts(t, window_s).size
    if n == 0:
        return None
    return decel_windows_over(t, accel, n, 0.0, window_s, limit_mps2)[0] / n


def decel_windows_over(
    t: np.ndarray,
    accel: np.ndarray,
    n_starts: int,
    dv0: float = 0.0,
    window_s: float = ISO_DECEL_WINDOW_S,
    limit_mps2: float = ISO_DECEL_LIMIT_MPS2,
) -> tuple[int, np.ndarray]:
    """Of the windows that start at the first ``n_starts`` rows, those whose mean
    deceleration exceeds ``limit_mps2``; ``t`` must reach each window's end (or the
    trace's end). A segment of a long trace passes the integral so far as ``dv0``.

    Returns:
        The count, and ``dv`` [m/s]: ``dv0 + ∫a dt`` from ``t[0]`` at each row.
    """
    # one sequential sum from dv0, so that segments chained by it give the whole trace's dv
    dv = np.cumsum(np.concatenate([[dv0], accel[1:] * np.diff(t)]))
    starts = t[:n_starts]
    mean_a = (np.interp(starts + window_s, t, dv) - np.interp(starts, t, dv)) / window_s
    return int(np.count_nonzero(-mean_a > limit_mps2)), dv


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
    n = window_starts(t, window_s).size
    if n == 0:
        return None
    return jerk_windows_over(t, accel, n, window_s, limit_mps3) / n


def jerk_windows_over(
    t: np.ndarray,
    accel: np.ndarray,
    n_starts: int,
    window_s: float = ISO_JERK_WINDOW_S,
    limit_mps3: float = ISO_JERK_LIMIT_MPS3,
) -> int:
    """Of the windows that start at the first ``n_starts`` rows, the number whose mean jerk
    exceeds ``limit_mps3``; ``t`` must reach each window's end (or the trace's end)."""
    starts = t[:n_starts]
    mean_jerk = np.abs(np.interp(starts + window_s, t, accel) - np.interp(starts, t, accel))
    return int(np.count_nonzero(mean_jerk / window_s > limit_mps3))


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
    changes = sign_changes(accel, 0, deadband_mps2)[0]
    return changes / ((t[-1] - t[0]) / 60.0)


def sign_changes(
    accel: np.ndarray, last_sign: int = 0, deadband_mps2: float = ACCEL_DEADBAND_MPS2
) -> tuple[int, int]:
    """Sign changes of acceleration (see :func:`sign_changes_per_min`) after a row of sign
    ``last_sign`` (1, -1; 0 for none).

    Returns:
        The count, and the last sign outside the band (``last_sign`` if none is).
    """
    sign = np.where(accel > deadband_mps2, 1, np.where(accel < -deadband_mps2, -1, 0))
    outside = sign[sign != 0]  # the band keeps the last sign: drop its rows
    if last_sign:
        outside = np.concatenate([[last_sign], outside])
    changes = int(np.count_nonzero(np.diff(outside)))
    return changes, int(outside[-1]) if outside.size else 0


def prompt_window_start(t: F) -> F:
    """Where the look-back of a hard brake at time ``t`` [s] begins [s] (see
    :func:`unprompted_hard_brakes`)."""
    return t - PROMPT_WINDOW_S - WINDOW_SLACK_S


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
    return unprompted_onsets(t, accel, gap, v_host, v_lead, 1, limit_mps2)


def unprompted_onsets(
    t: np.ndarray,
    accel: np.ndarray,
    gap: np.ndarray,
    v_host: np.ndarray,
    v_lead: np.ndarray,
    lo: int,
    limit_mps2: float = ISO_DECEL_LIMIT_MPS2,
) -> int:
    """The unprompted onsets (see :func:`unprompted_hard_brakes`) at rows ``lo`` (>= 1) on.
    The rows before ``lo`` are context: they must reach back past
    :func:`prompt_window_start` of row ``lo``'s time, or be the trace's first rows."""
    closing = v_host - v_lead
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc_short = (closing > 0.0) & (np.maximum(gap, 0.0) < PROMPT_TTC_S * closing)
        headway_short = np.maximum(gap, 0.0) < PROMPT_HEADWAY_S * v_host
    lead_decel = np.concatenate([[0.0], -np.diff(v_lead) / np.diff(t)])
    threat = ttc_short | headway_short | (lead_decel >= PROMPT_LEAD_DECEL_MPS2)
    hard = accel < -limit_mps2
    onsets = np.flatnonzero(hard[lo:] & ~hard[lo - 1 : -1]) + lo
    first = np.searchsorted(t, prompt_window_start(t[onsets]))  # each onset's look-back starts here
    threats = np.concatenate([[0], np.cumsum(threat)])  # threat rows before each row
    return int(np.count_nonzero(threats[onsets + 1] == threats[first]))
