"""ISO 15622 windows, jerk and sign changes on traces computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from energy.comfort import (
    ISO_DECEL_LIMIT_MPS2,
    ISO_JERK_LIMIT_MPS3,
    decel_window_share,
    jerk_window_share,
    sign_changes_per_min,
    unprompted_hard_brakes,
    window_starts,
)

DT = 0.1  # [s] the simulator's control period


def _t(end_s: float, dt: float = DT) -> np.ndarray:
    return np.arange(round(end_s / dt) + 1) * dt  # k * dt, as the simulator logs time


def test_iso_limits_are_the_standards() -> None:
    assert ISO_DECEL_LIMIT_MPS2 == 3.5 and ISO_JERK_LIMIT_MPS3 == 2.5


def test_windows_slide_at_the_log_rate() -> None:
    t = _t(10.0)
    assert window_starts(t, 2.0).size == 81  # starts 0.0 .. 8.0
    assert window_starts(t, 1.0).size == 91
    assert decel_window_share(_t(1.5), np.zeros(16)) is None  # shorter than 2 s


@pytest.mark.parametrize(("accel", "share"), [(-4.0, 1.0), (-3.0, 0.0), (4.0, 0.0)])
def test_constant_acceleration(accel: float, share: float) -> None:
    t = _t(10.0)
    a = np.full(t.size, accel)
    assert decel_window_share(t, a) == share  # only deceleration counts
    assert jerk_window_share(t, a) == 0.0
    assert sign_changes_per_min(t, a) == 0.0


def test_decel_pulse_is_averaged_over_two_seconds() -> None:
    t = _t(10.0)
    a = np.where((t > 1.0 + 1e-9) & (t <= 3.0 + 1e-9), -4.0, 0.0)  # -4 m/s² over (1, 3] s
    # A window [s, s+2] overlaps the pulse by 2 - |s - 1| s: its mean deceleration
    # 4 (2 - |s - 1|) / 2 exceeds 3.5 only for |s - 1| < 0.25: s = 0.8 .. 1.2.
    assert decel_window_share(t, a) == pytest.approx(5 / 81)
    a_short = np.where((t > 1.0 + 1e-9) & (t <= 2.0 + 1e-9), -5.0, 0.0)  # 1 s at -5
    assert decel_window_share(t, a_short) == 0.0  # at most 2.5 m/s² over any 2 s


def test_decel_window_is_the_speed_drop_of_a_simulator_log() -> None:
    rng = np.random.default_rng(0)
    t = _t(30.0)
    a = np.concatenate([[0.0], rng.uniform(-6.0, 2.0, t.size - 1)])
    v = 30.0 + np.concatenate([[0.0], np.cumsum(a[1:] * DT)])  # a[k] = (v[k] - v[k-1]) / dt
    starts = np.arange(t.size - 20)
    drop = -(v[starts + 20] - v[starts]) / 2.0
    assert decel_window_share(t, a) == pytest.approx(np.mean(drop > 3.5))


def test_jerk_ramp() -> None:
    t = _t(10.0)
    assert jerk_window_share(t, 3.0 * t) == 1.0
    assert jerk_window_share(t, 2.0 * t) == 0.0
    assert jerk_window_share(t, -3.0 * t) == 1.0  # the size of the change counts
    # 3 m/s³ for 5 s, then held: |a(s+1) - a(s)| = 3 (5 - s) > 2.5 for s < 4.17,
    # so windows starting at 0.0 .. 4.1 exceed: 42 of 91.
    assert jerk_window_share(t, 3.0 * np.minimum(t, 5.0)) == pytest.approx(42 / 91)


def test_oscillation_faster_than_the_window_passes_the_iso_jerk_test() -> None:
    t = _t(10.0)
    a = np.where(np.arange(t.size) % 2 == 0, 1.0, -1.0)  # ±1 m/s² every 0.1 s
    assert jerk_window_share(t, a) == 0.0  # a(t + 1 s) = a(t): the literal ISO test
    assert sign_changes_per_min(t, a) == pytest.approx(100 / (10 / 60))  # caught here


def test_sign_changes_square_wave() -> None:
    t = _t(60.0)
    a = np.where(np.floor(t + 1e-9) % 2 == 0, 1.0, -1.0)  # flips at every whole second
    assert sign_changes_per_min(t, a) == pytest.approx(60.0)
    assert sign_changes_per_min(t, 0.05 * a) == 0.0  # inside the 0.1 m/s² deadband


@pytest.mark.parametrize(
    ("a", "changes"),
    [
        ([0.5, 0.0, -0.05, 0.5], 0),  # dips into the band only
        ([0.5, 0.0, -0.5], 1),  # the band keeps the last sign
        ([0.0, -0.5, 0.05, -0.2, 0.3, 0.0, -0.11], 2),
        ([0.0, 0.0, 0.0], 0),
    ],
)
def test_sign_change_deadband(a: list[float], changes: int) -> None:
    t = np.arange(len(a)) * 1.0  # changes per minute = changes * 60 / (n - 1)
    assert sign_changes_per_min(t, np.array(a)) == pytest.approx(changes * 60.0 / (len(a) - 1))


def _following(n: int = 100, dt: float = 0.1) -> dict[str, np.ndarray]:
    """10 s behind a steady lead at 25 m/s, 55 m back: nothing ahead asks for a brake."""
    t = np.arange(n) * dt
    return {"t": t, "accel": np.zeros(n), "gap": np.full(n, 55.0), "v_host": np.full(n, 25.0), "v_lead": np.full(n, 25.0)}


def test_a_hard_brake_behind_a_steady_lead_is_unprompted() -> None:
    run = _following()
    run["accel"][50:54] = -5.5  # a phantom full brake for 0.4 s
    run["accel"][70] = -4.0  # and a second, one row long
    assert unprompted_hard_brakes(**run) == 2
    run["accel"][50:54] = -3.5  # at the limit, not past it
    assert unprompted_hard_brakes(**run) == 1
    assert unprompted_hard_brakes(**_following()) == 0


@pytest.mark.parametrize("threat", ["ttc", "headway", "lead_brakes"])
def test_a_hard_brake_that_answers_a_threat_in_the_second_before_is_prompted(threat: str) -> None:
    run = _following()
    run["accel"][50:54] = -5.5
    if threat == "ttc":  # closing at 10 m/s from 55 m: 5.5 s to collision, 0.9 s before the brake
        run["v_host"][41] = 35.0
    elif threat == "headway":  # a car cut in 20 m ahead at 25 m/s: 0.8 s headway
        run["gap"][45:] = 20.0
    else:  # the lead sheds 0.3 m/s in 0.1 s: 3 m/s^2
        run["v_lead"][48:] = 24.7
    assert unprompted_hard_brakes(**run) == 0
    run = _following()
    run["accel"][50:54] = -5.5
    run["v_host"][38] = 35.0  # the same threat 1.2 s before: outside the window
    assert unprompted_hard_brakes(**run) == 1
