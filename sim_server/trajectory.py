"""Lead-vehicle speed trajectories, sampled at the physics rate.

* ICE (paper eq. 7): ``v(t) = 30 + 0.3 * sum_i A_i sin(2 w_i t)``, A_i in {-1, +1},
  w_i ~ U(0, 1), then held inside Table 2's speed and acceleration limits.
  ``test-1``..``test-4`` are four fixed groups of (A, w), written down below.
* EV: windows of real-world GPS speed traces (package data ``data/real_world``,
  CMAP 2007 survey; not the paper's non-public SR-91 Leaf data), linearly
  interpolated from 1 Hz and held inside Table 2's EV limits.
* Any speed trace given as times and speeds (a user's CSV): driven as given, not
  held inside Table 2's bands, but refused beyond physical limits (negative or
  above 70 m/s speeds, accelerations beyond 1 g between samples).
* Lead scenarios (``stopped``, ``brake-stop``, ...): see :mod:`sim_server.scenarios`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from protocol.scenarios import (
    LEAD_SCENARIOS,
    RANDOM_DURATION,
    TEST_DURATION,
    TEST_TRAJECTORIES,
    TRACE_ACCEL_LIMIT,
    TRACE_SPEED_MAX,
    TRAJECTORIES,
    check_trace_size,
)
from sim_server.errors import ScenarioError, TrajectoryError

__all__ = [
    "Limits",
    "LIMITS",
    "ICE_TEST_PARAMS",
    "EV_TEST_WINDOWS",
    "TEST_DURATION",
    "RANDOM_DURATION",
    "eq7_speed",
    "limit",
    "ice_trajectory",
    "ev_window",
    "from_trace",
    "user_trace",
    "build",
]



@dataclass(frozen=True)
class Limits:
    """Table 2 of the paper for one scenario."""

    v_min: float  # [m/s] lead speed range
    v_max: float
    a_min: float  # [m/s^2] lead acceleration range
    a_max: float
    v0_lead: tuple[float, float]  # [m/s] initial lead speed range
    v0_host: tuple[float, float]  # [m/s] initial host speed range
    gap0: tuple[float, float]  # [m] initial gap range


LIMITS = {
    "ice": Limits(27.0, 33.0, -3.5, 3.5, (27.0, 33.0), (25.0, 30.0), (25.0, 35.0)),
    "ev": Limits(0.0, 30.0, -5.5, 3.5, (11.2, 15.6), (11.0, 16.0), (25.0, 35.0)),
}

# (A_1..A_10, w_1..w_10) of the four ICE test trajectories. Drawn once with
# numpy.random.default_rng(2019) and frozen here, so they never change.
ICE_TEST_PARAMS: dict[str, tuple[tuple[int, ...], tuple[float, ...]]] = {
    "test-1": ((-1, -1, -1, -1, 1, -1, -1, 1, 1, -1),
               (0.4307, 0.4565, 0.6518, 0.6866, 0.5293, 0.8805, 0.7654, 0.3864, 0.7003, 0.5528)),
    "test-2": ((1, 1, 1, 1, -1, 1, 1, -1, 1, 1),
               (0.8196, 0.6234, 0.2623, 0.8192, 0.1296, 0.7577, 0.3306, 0.3004, 0.113, 0.1475)),
    "test-3": ((1, 1, 1, 1, -1, 1, 1, 1, 1, -1),
               (0.0514, 0.487, 0.2979, 0.6186, 0.9985, 0.3744, 0.3311, 0.127, 0.5618, 0.643)),
    "test-4": ((1, -1, -1, -1, 1, 1, -1, -1, -1, 1),
               (0.1023, 0.19, 0.8971, 0.1623, 0.7206, 0.5341, 0.7759, 0.5259, 0.2306, 0.468)),
}  # fmt: skip

# The four EV test windows: (trace file, start t_s). Each is 240 s of continuous
# 1 Hz driving that starts inside Table 2's EV initial lead speed range; they were
# picked for variety: free flow with a stop, congestion, and stop-and-go.
EV_TEST_WINDOWS: dict[str, tuple[str, float]] = {
    "test-1": ("cmap_4033363_3_2007-08-22.csv", 36392.0),
    "test-2": ("cmap_4108468_1_2007-06-22.csv", 34122.0),
    "test-3": ("cmap_4115766_1_2007-03-28.csv", 29638.0),
    "test-4": ("cmap_4116813_1_2007-04-05.csv", 42425.0),
}
EV_TRACE_FILES = (
    "cmap_4033363_3_2007-08-22.csv",
    "cmap_4107032_1_2007-05-23.csv",
    "cmap_4108468_1_2007-06-22.csv",
    "cmap_4108468_1_2007-06-25.csv",
    "cmap_4115766_1_2007-03-28.csv",
    "cmap_4115957_1_2007-04-09.csv",
    "cmap_4116721_2_2007-04-09.csv",
    "cmap_4116813_1_2007-04-05.csv",
)


def eq7_speed(a: np.ndarray, w: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Paper eq. 7: lead speed [m/s] at times ``t`` [s] before limiting."""
    return 30.0 + 0.3 * np.sin(2.0 * np.outer(t, w)) @ a


def limit(v_target: np.ndarray, dt: float, lim: Limits) -> np.ndarray:
    """Follow ``v_target`` as closely as Table 2's speed and acceleration limits allow.

    Args:
        v_target: wanted speeds [m/s], one per physics step.
        dt: physics step [s].
        lim: the scenario's limits.

    Returns:
        Speeds [m/s] whose steps stay within ``[a_min, a_max] * dt``.
    """
    target = np.clip(v_target, lim.v_min, lim.v_max)
    out = np.empty_like(target)
    v = target[0]
    lo, hi = lim.a_min * dt, lim.a_max * dt
    for i, want in enumerate(target.tolist()):
        v += min(max(want - v, lo), hi)
        out[i] = v
    return out


def ice_trajectory(a: np.ndarray, w: np.ndarray, duration: float, dt: float) -> np.ndarray:
    """An eq. 7 trajectory of ``duration`` seconds sampled every ``dt``."""
    t = np.arange(int(round(duration / dt)) + 1) * dt
    return limit(eq7_speed(np.asarray(a, float), np.asarray(w, float), t), dt, LIMITS["ice"])


@lru_cache(maxsize=16)
def _load_trace(name: str) -> tuple[np.ndarray, np.ndarray]:
    text = resources.files("sim_server").joinpath("data", "real_world", name).read_text()
    data = np.loadtxt(text.splitlines()[1:], delimiter=",", dtype=float, ndmin=2)
    return data[:, 0], data[:, 1]


def _check_trace(t_s: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t_s = np.asarray(t_s, dtype=float)
    v = np.asarray(v, dtype=float)
    if t_s.ndim != 1 or t_s.shape != v.shape or len(t_s) < 2:
        raise TrajectoryError(f"a trace needs matching 1-D times and speeds, at least 2 samples; got {t_s.shape} and {v.shape}")
    bad = np.flatnonzero(~np.isfinite(t_s) | ~np.isfinite(v))
    if bad.size:
        raise TrajectoryError(f"trace sample {bad[0]} is not finite")
    bad = np.flatnonzero(v < 0)
    if bad.size:
        raise TrajectoryError(f"trace sample {bad[0]} has negative speed {v[bad[0]]}")
    bad = np.flatnonzero(np.diff(t_s) <= 0)
    if bad.size:
        raise TrajectoryError(f"trace time is not increasing at sample {bad[0] + 1}")
    return t_s, v


def _resample(t_s: np.ndarray, v: np.ndarray, dt: float, duration: float | None) -> np.ndarray:
    span = t_s[-1] - t_s[0]
    if duration is not None:
        span = min(span, duration)
    t = t_s[0] + np.arange(int(np.floor(span / dt + 1e-9)) + 1) * dt
    return np.interp(t, t_s, v)


def from_trace(t_s: np.ndarray, v: np.ndarray, dt: float, lim: Limits, duration: float | None = None) -> np.ndarray:
    """Resample a speed trace to the physics rate and hold it inside ``lim``.

    For the packaged real-world windows, which stand in for the paper's EV data
    and so keep to its Table 2.

    Args:
        t_s: strictly increasing sample times [s].
        v: speeds [m/s], finite and non-negative.
        dt: physics step [s].
        lim: the scenario's limits.
        duration: how much of the trace to use [s]; all of it if None.

    Raises:
        TrajectoryError: naming the first bad sample.
    """
    t_s, v = _check_trace(t_s, v)
    return limit(_resample(t_s, v, dt, duration), dt, lim)


def user_trace(t_s: np.ndarray, v: np.ndarray, dt: float) -> np.ndarray:
    """A user's lead trace, resampled to the physics rate and driven as given.

    Linear interpolation between samples, so the lead's acceleration is the
    trace's own. No scenario band applies (a 0-27 m/s cycle stays one); a trace a
    car cannot drive is refused instead.

    Args:
        t_s: strictly increasing sample times [s].
        v: speeds [m/s], in 0..TRACE_SPEED_MAX.
        dt: physics step [s].

    Raises:
        TrajectoryError: one line naming the first bad sample and the limit.
    """
    t_s, v = _check_trace(t_s, v)
    try:
        check_trace_size(len(t_s), float(t_s[-1] - t_s[0]))  # before resampling it at dt
    except ValueError as exc:
        raise TrajectoryError(str(exc)) from None
    bad = np.flatnonzero(v > TRACE_SPEED_MAX)
    if bad.size:
        raise TrajectoryError(f"trace sample {bad[0]} has speed {v[bad[0]]:g} m/s, above the {TRACE_SPEED_MAX:g} m/s limit")
    a = np.diff(v) / np.diff(t_s)
    bad = np.flatnonzero(np.abs(a) > TRACE_ACCEL_LIMIT)
    if bad.size:
        i = int(bad[0])
        raise TrajectoryError(
            f"trace samples {i}-{i + 1} accelerate at {a[i]:.3g} m/s^2, beyond the physical limit of "
            f"+-{TRACE_ACCEL_LIMIT:g} m/s^2 (1 g)"
        )
    return _resample(t_s, v, dt, None)


def ev_window(name: str, start: float, duration: float, dt: float) -> np.ndarray:
    """``duration`` seconds of a packaged real-world trace from ``start`` [s]."""
    t_s, v = _load_trace(name)
    sel = (t_s >= start) & (t_s <= start + duration)
    return from_trace(t_s[sel], v[sel], dt, LIMITS["ev"], duration)


def random_ev_window(rng: np.random.Generator, duration: float) -> tuple[str, int, int]:
    """Pick a training window of a packaged trace: ``(file, first row, last row)``.

    Continuous 1 Hz driving that starts inside Table 2's EV initial speed range and
    shares no second with a test window, so training never sees the test data.
    """
    lim = LIMITS["ev"]
    for _ in range(1000):
        name = EV_TRACE_FILES[int(rng.integers(len(EV_TRACE_FILES)))]
        t_s, v = _load_trace(name)
        i = int(rng.integers(0, len(t_s) - int(duration) - 1))
        j = i + int(duration)
        held_out = any(f == name and t_s[i] < start + TEST_DURATION and start < t_s[j] for f, start in EV_TEST_WINDOWS.values())
        if t_s[j] - t_s[i] == duration and lim.v0_lead[0] <= v[i] <= lim.v0_lead[1] and not held_out:
            return name, i, j
    raise TrajectoryError("no usable window found in the real-world traces")


def _random_ev_window(rng: np.random.Generator, duration: float, dt: float) -> np.ndarray:
    name, i, j = random_ev_window(rng, duration)
    t_s, v = _load_trace(name)
    return from_trace(t_s[i : j + 1], v[i : j + 1], dt, LIMITS["ev"], duration)


def build(
    scenario: str,
    trajectory: str,
    rng: np.random.Generator,
    dt: float,
    *,
    trace: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Lead speeds [m/s], one per physics step, for a scenario and trajectory name.

    Args:
        scenario: "ice" or "ev".
        trajectory: "test-1".."test-4", "random" (drawn from ``rng``) or "trace";
            lead scenarios are built by :mod:`sim_server.scenarios`.
        rng: the episode's generator.
        dt: physics step [s].
        trace: (times [s], speeds [m/s]) when ``trajectory == "trace"``.

    Raises:
        ScenarioError: unknown scenario.
        TrajectoryError: unknown trajectory or bad trace.
    """
    if scenario not in LIMITS:
        raise ScenarioError(f"unknown scenario {scenario!r}; expected one of {sorted(LIMITS)}")
    if trajectory == "trace":
        if trace is None:
            raise TrajectoryError("trajectory 'trace' needs trace times and speeds")
        return user_trace(trace[0], trace[1], dt)
    if trajectory == "random":
        if scenario == "ice":
            a = rng.choice(np.array([-1.0, 1.0]), size=10)
            w = rng.uniform(0.0, 1.0, size=10)
            return ice_trajectory(a, w, RANDOM_DURATION, dt)
        return _random_ev_window(rng, RANDOM_DURATION, dt)
    if trajectory in TEST_TRAJECTORIES:
        return _test_trajectory(scenario, trajectory, dt).copy()
    if trajectory in LEAD_SCENARIOS:
        raise TrajectoryError(f"lead scenario {trajectory!r} is built by sim_server.scenarios, not trajectory.build")
    raise TrajectoryError(f"unknown trajectory {trajectory!r}; expected one of {', '.join(TRAJECTORIES)} or trace")


@lru_cache(maxsize=16)
def _test_trajectory(scenario: str, trajectory: str, dt: float) -> np.ndarray:
    # Fixed trajectories are built once per process: resets stay fast.
    if scenario == "ice":
        signs, freqs = ICE_TEST_PARAMS[trajectory]
        return ice_trajectory(np.array(signs, float), np.array(freqs, float), TEST_DURATION, dt)
    name, start = EV_TEST_WINDOWS[trajectory]
    return ev_window(name, start, TEST_DURATION, dt)
