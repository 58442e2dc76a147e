"""Time/speed traces: validation and the interval kinematics every model integrates.

A trace is sampled speeds ``v[i]`` at times ``t[i]``. The models work per interval
``[t[i], t[i+1]]`` with the mean speed and the constant acceleration that join the
two samples. That choice makes ``M v a dt`` integrate exactly to the change of
kinetic energy, and the distance is the trapezoid rule, whatever the sample period
(1 s for the EPA cycles, 0.02 s or 0.1 s for run logs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from energy.errors import TraceError


@dataclass(frozen=True)
class Intervals:
    """Per-interval kinematics of a trace; arrays have one entry per interval."""

    dt: np.ndarray
    """Interval duration [s]."""
    v: np.ndarray
    """Mean speed over the interval [m/s]."""
    a: np.ndarray
    """Constant acceleration over the interval [m/s^2]."""

    @property
    def distance_m(self) -> float:
        """Distance travelled [m]."""
        return float(np.sum(self.v * self.dt))

    @property
    def duration_s(self) -> float:
        """Duration [s]."""
        return float(np.sum(self.dt))


def validate_trace(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Check a trace and return it as float arrays.

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], finite and >= 0.

    Returns:
        (t, v) as 1-D float64 arrays.

    Raises:
        TraceError: shapes differ, fewer than two samples, NaN/inf, negative speed,
            or time not strictly increasing (the first offending sample is named).
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    if t.ndim != 1 or v.shape != t.shape:
        raise TraceError(f"t and v must be 1-D arrays of equal length, got {t.shape} and {v.shape}")
    if t.size < 2:
        raise TraceError(f"need at least 2 samples, got {t.size}")
    for name, x in (("t", t), ("v", v)):
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise TraceError(f"{name} is not finite ({x[bad[0]]})", int(bad[0]))
    neg = np.flatnonzero(v < 0)
    if neg.size:
        raise TraceError(f"negative speed {v[neg[0]]} m/s", int(neg[0]))
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise TraceError(f"time not strictly increasing ({t[i - 1]} s then {t[i]} s)", i)
    return t, v


def intervals(t: np.ndarray, v: np.ndarray) -> Intervals:
    """Per-interval duration, mean speed and acceleration of a trace.

    Args:
        t: sample times [s].
        v: speeds [m/s].

    Raises:
        TraceError: see :func:`validate_trace`.
    """
    t, v = validate_trace(t, v)
    dt = np.diff(t)
    return Intervals(dt=dt, v=0.5 * (v[1:] + v[:-1]), a=np.diff(v) / dt)


def positive_distance(distance_m: float) -> float:
    """``distance_m`` [m], which must be positive for per-mile figures.

    Raises:
        TraceError: it is not (no distance travelled).
    """
    if not distance_m > 0.0:
        raise TraceError("zero distance travelled: per-mile figures are undefined")
    return distance_m
