from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from energy_log_rows import make_log_rows

from energy import COROLLA_2022, LEAF, RunLog, evaluate_run, load_cycle, read_run_log
from energy.cmem import per_mile
from energy.ev import eq6_per_mile

ICE_KEYS = {"fuel_g_per_mi", "co2_g_per_mi", "co_g_per_mi", "hc_g_per_mi", "nox_g_per_mi"}
COMMON_KEYS = {
    "distance_m", "distance_mi", "collisions", "gap_rmse_55m_m", "gap_rmse_time_gap_m", "ttc_min_s",
    "ttc_under_threshold_share", "headway_mean_s", "headway_p50_s", "accel_rms_mps2", "jerk_rms_mps3",
    "jerk_max_mps3", "force_rms", "speed_max_mps", "gap_min_m", "headway_min_s", "settle_s",
    "iso_decel_window_share", "iso_jerk_window_share", "accel_sign_changes_per_min",
}  # fmt: skip


def _log(**cols: np.ndarray) -> RunLog:
    n = cols["t"].size
    base = {
        "frame": np.arange(n, dtype=float),
        "accel": np.zeros(n),
        "force": np.zeros(n),
        "collision": np.zeros(n),
    }
    return RunLog(path="mem", **(base | cols))  # type: ignore[arg-type]


def test_gap_rmse_both_references(write_log: Callable[..., Path]) -> None:
    m = evaluate_run(write_log(make_log_rows(v=20.0, gap=50.0)), "corolla")
    assert m["gap_rmse_55m_m"] == pytest.approx(5.0)
    assert m["gap_rmse_time_gap_m"] == pytest.approx(50.0 - 1.8 * 20.0)
    m = evaluate_run(
        write_log(make_log_rows(v=2.0, gap=50.0)), "corolla", time_gap_s=2.0, d_safe_m=10.0
    )
    assert m["gap_rmse_time_gap_m"] == pytest.approx(40.0)  # d_ref = max(4, 10)


def test_ttc_and_headway() -> None:
    t = np.arange(0.0, 10.0, 0.1)  # 100 rows
    v_host = np.full(t.size, 20.0)
    v_lead = np.where(t < 5.0, 20.0, 18.0)  # closing at 2 m/s in the second half
    gap = np.where(t < 5.0, 60.0, 6.0)  # TTC 3 s in the second half
    m = evaluate_run(_log(t=t, v_host=v_host, v_lead=v_lead, gap=gap), "corolla")
    assert m["ttc_min_s"] == pytest.approx(3.0)
    assert m["ttc_under_threshold_share"] == pytest.approx(0.5)
    assert m["headway_mean_s"] == pytest.approx((3.0 + 0.3) / 2)
    assert m["headway_share_0_1s"] == pytest.approx(0.5)
    assert m["headway_share_2_3s"] == pytest.approx(0.0)
    assert m["headway_share_3_4s"] == pytest.approx(0.5)


def test_no_closing_gives_no_ttc(write_log: Callable[..., Path]) -> None:
    m = evaluate_run(write_log(make_log_rows()), "leaf")
    assert m["ttc_min_s"] is None and m["ttc_under_threshold_share"] == 0.0


def test_comfort_metrics_and_collisions() -> None:
    t = np.arange(0.0, 2.0, 0.5)  # 4 rows, 0.5 s
    accel = np.array([0.0, 1.0, 1.0, -1.0])
    collision = np.array([0.0, 1.0, 1.0, 0.0])
    m = evaluate_run(
        _log(t=t, v_host=np.full(4, 10.0), v_lead=np.full(4, 10.0), gap=np.full(4, 30.0), accel=accel,
             force=np.array([0.0, 0.5, 0.5, -0.5]), collision=collision),
        "corolla", settle_s=0.0,
    )  # fmt: skip
    assert m["accel_rms_mps2"] == pytest.approx(np.sqrt(3 / 4))
    assert m["jerk_max_mps3"] == pytest.approx(4.0)  # (-1 - 1) / 0.5
    assert m["jerk_rms_mps3"] == pytest.approx(np.sqrt((4 + 0 + 16) / 3))
    assert m["force_rms"] == pytest.approx(np.sqrt(0.75 / 4))
    assert m["collisions"] == 1
    assert m["distance_m"] == pytest.approx(15.0)


def test_uneven_period_is_time_weighted() -> None:
    t = np.array([0.0, 1.0, 1.1, 1.2])  # row 0 holds for 1 s, the others 0.1 s
    gap = np.array([55.0, 45.0, 45.0, 45.0])
    m = evaluate_run(
        _log(t=t, v_host=np.full(4, 10.0), v_lead=np.full(4, 10.0), gap=gap), "corolla"
    )
    assert m["gap_rmse_55m_m"] == pytest.approx(np.sqrt(100 * 0.3 / 1.3))
    assert m["control_period_s"] == pytest.approx(0.1)


@pytest.mark.parametrize("dt", [0.02, 0.1])
def test_energy_matches_the_models_on_a_cycle(dt: float) -> None:
    c = load_cycle("hwfet")
    t = np.arange(0.0, c.t[-1] + dt / 2, dt)
    v = np.interp(t, c.t, c.v)
    log = _log(t=t, v_host=v, v_lead=v, gap=np.full(t.size, 55.0), accel=np.gradient(v, t))
    ice, bev = evaluate_run(log, "corolla"), evaluate_run(log, "leaf")
    assert ice["co2_g_per_mi"] == pytest.approx(per_mile(t, v, COROLLA_2022).co2_g_per_mi)
    assert ice["co2_g_per_mi"] == pytest.approx(164.6, rel=0.05)  # the cycle, resampled
    assert bev["energy_kj_per_mi"] == pytest.approx(eq6_per_mile(t, v).energy_kj_per_mi)
    assert bev["energy_wh_per_mi"] == pytest.approx(bev["energy_kj_per_mi"] / 3.6)
    assert bev["regen_vtcpem_kj_per_mi"] > 0.0
    assert ice["distance_mi"] == pytest.approx(10.26, rel=2e-3)
    assert LEAF.aux_power_w == 700.0


def test_every_metric_is_present(write_log: Callable[..., Path]) -> None:
    path = write_log(make_log_rows())
    ice = evaluate_run(path, "corolla")
    assert COMMON_KEYS | ICE_KEYS <= ice.keys() and ice["vehicle"] == "corolla"
    assert ICE_KEYS <= evaluate_run(read_run_log(path), "average").keys()
    bev = evaluate_run(path, "leaf")
    assert COMMON_KEYS | {"energy_kj_per_mi", "energy_wh_per_mi"} <= bev.keys()


def test_unknown_vehicle(write_log: Callable[..., Path]) -> None:
    with pytest.raises(KeyError, match="unknown vehicle"):
        evaluate_run(write_log(make_log_rows()), "prius")


def _settle_run() -> RunLog:
    """30 s at 0.1 s: ±1.5 m/s² flips every second for the first 15 s, then steady at 20 m/s;
    the gap is 8 m (TTC 4 s, headway 0.4 s) at t = 1 s and 55 m elsewhere."""
    t = np.arange(301) * 0.1
    accel = np.where(t < 15.0 - 1e-9, np.where(np.floor(t + 1e-9) % 2 == 0, 1.5, -1.5), 0.0)
    v_host = np.where(np.abs(t - 1.0) < 1e-9, 22.0, 20.0)
    gap = np.where(np.abs(t - 1.0) < 1e-9, 8.0, 55.0)
    return _log(t=t, v_host=v_host, v_lead=np.full(t.size, 20.0), gap=gap, accel=accel)


def test_settle_cuts_the_comfort_figures_only() -> None:
    whole = evaluate_run(_settle_run(), "corolla", settle_s=0.0)
    settled = evaluate_run(_settle_run(), "corolla")  # the default 15 s
    assert settled["settle_s"] == 15.0 and whole["settle_s"] == 0.0
    assert whole["accel_sign_changes_per_min"] == pytest.approx(14 / 0.5)  # t = 1 .. 14 s in 30 s
    # 14 flips of 3 m/s² and the last 1.5 -> 0, each in 0.1 s, over 300 intervals
    assert whole["jerk_rms_mps3"] == pytest.approx(np.sqrt((14 * 30**2 + 15**2) / 300))
    # |a(s + 1) - a(s)| = 3 m/s³ for the windows that start at s = 0.0 .. 13.9 (from
    # 14.0 on, a(s + 1) = 0 and the change is 1.5): 140 of 291
    assert whole["iso_jerk_window_share"] == pytest.approx(140 / 291)
    for key in ("accel_sign_changes_per_min", "jerk_rms_mps3", "jerk_max_mps3",
                "accel_rms_mps2", "iso_jerk_window_share", "iso_decel_window_share"):  # fmt: skip
        assert settled[key] == 0.0, key
    for key in ("gap_rmse_55m_m", "gap_min_m", "ttc_min_s", "headway_min_s", "speed_max_mps",
                "fuel_g_per_mi", "collisions"):  # fmt: skip
        assert settled[key] == whole[key], key
    assert settled["gap_min_m"] == 8.0 and settled["ttc_min_s"] == pytest.approx(4.0)
    assert settled["headway_min_s"] == pytest.approx(8.0 / 22.0)
    assert settled["speed_max_mps"] == 22.0


def test_settle_longer_than_the_run_leaves_comfort_undefined() -> None:
    m = evaluate_run(_settle_run(), "corolla", settle_s=30.0)  # one row left
    assert m["jerk_rms_mps3"] is None and m["iso_jerk_window_share"] is None
    assert m["gap_rmse_55m_m"] > 0.0
    m = evaluate_run(_settle_run(), "corolla", settle_s=29.5)  # 6 rows: under one 1-s window
    assert m["jerk_rms_mps3"] == 0.0 and m["iso_jerk_window_share"] is None


def test_unprompted_hard_brakes_count_from_engagement_whatever_the_settle() -> None:
    """A full brake at 2 s, 55 m behind a steady lead: inside the settle, still a phantom brake."""
    t = np.arange(301) * 0.1
    accel = np.where(np.abs(t - 2.0) < 0.05, -6.0, 0.0)
    run = _log(t=t, v_host=np.full(t.size, 20.0), v_lead=np.full(t.size, 20.0), gap=np.full(t.size, 55.0), accel=accel)
    for settle in (0.0, 15.0, 30.0):  # 30 s leaves the comfort figures undefined, not this count
        m = evaluate_run(run, "corolla", settle_s=settle)
        assert m["unprompted_hard_brakes"] == 1, settle
    assert evaluate_run(run, "corolla")["iso_decel_window_share"] == 0.0  # the brake is left out of the comfort figures


@pytest.mark.parametrize("option", ["time_gap_s", "d_safe_m", "settle_s", "desired_gap_m"])
@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_bad_options_are_refused(option: str, value: float) -> None:
    with pytest.raises(ValueError, match=f"{option} must be a finite number >= 0"):
        evaluate_run(_settle_run(), "corolla", **{option: value})
