"""Every metric of a run: gap keeping, safety, comfort, distance, fuel or energy.

:func:`evaluate_run` turns a run log (see :mod:`energy.runlog`) and a vehicle into
one flat dict. Keys carry their unit (``_m``, ``_s``, ``_mps2``, ``_g_per_mi``...).
Time averages weight each row by the time until the next row (the last row by the
previous step), so a log with a 0.02 s or 0.1 s period, or an uneven one, is
averaged over time; for an even period this is the plain mean over rows.

Fuel, emissions and energy are evaluated on the host speed trace (v_host over t),
so that they agree with the distance; acceleration and jerk statistics use the
logged ``accel`` column.

A settling period at the start (``settle_s``, default :data:`SETTLE_S`) is left out
of the comfort figures only (acceleration, jerk, force, the ISO 15622 windows and
sign changes; see :mod:`energy.comfort`): every run starts inside the 55 m target,
so the start says little about how a controller rides. Gap RMSE stays over the whole
run, as in the paper's Tables 3 and 4, and so do energy and the safety figures
(collisions, minimum gap, TTC, headway, maximum speed), because the most dangerous
moment of a run, a stopped car ahead, can be its start. So do the unprompted hard
brakes: a full brake at engagement, behind a lead that asks for none, is a phantom
brake too, and the count's own test for a threat ahead already excuses a start that
needs one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from energy import cmem, comfort, ev, units
from energy.runlog import RunLog, read_run_log

DESIRED_GAP_M = 55.0  # [m] the paper's desired gap; gap RMSE is taken against it
TIME_GAP_S = 1.8  # [s] default t_gap of d_ref = max(v t_gap, d_safe): the shipped ACC's
D_SAFE_M = 5.0  # [m] default d_safe of the same reference
TTC_THRESHOLD_S = 4.0  # [s] a common critical time-to-collision
HEADWAY_MIN_SPEED_MPS = 0.5  # [m/s] below this, time headway is not defined (standstill)
HEADWAY_BINS_S = (0.0, 1.0, 2.0, 3.0, 4.0, np.inf)  # [s] edges of the headway distribution
SETTLE_S = 15.0  # [s] default start left out of the comfort figures (runs start at 55 m)

VEHICLE_NAMES = ("corolla", "average", "leaf")
"""Vehicles :func:`evaluate_run` accepts by name."""
SCENARIO_VEHICLES = {"ice": "corolla", "ev": "leaf"}
"""The vehicle each simulator scenario's host is scored as, unless another is asked for."""

Metrics = dict[str, float | int | str | None]


def _weights(t: np.ndarray) -> np.ndarray:
    dt = np.diff(t)
    return np.append(dt, dt[-1])


def _wmean(x: np.ndarray, w: np.ndarray) -> float:
    return float(np.sum(x * w) / np.sum(w))


def _rms(x: np.ndarray, w: np.ndarray) -> float:
    return float(np.sqrt(_wmean(x**2, w)))


def evaluate_run(
    log: RunLog | str | Path,
    vehicle: str | cmem.CmemVehicle | ev.LeafVtCpem,
    *,
    desired_gap_m: float = DESIRED_GAP_M,
    time_gap_s: float = TIME_GAP_S,
    d_safe_m: float = D_SAFE_M,
    ttc_threshold_s: float = TTC_THRESHOLD_S,
    settle_s: float = SETTLE_S,
) -> Metrics:
    """Every metric of one run.

    Args:
        log: a validated :class:`RunLog`, or the path of a run log CSV.
        vehicle: ``"corolla"``, ``"average"`` (CMEM, ICE) or ``"leaf"`` (EV), or a
            parameter set.
        desired_gap_m: fixed target of ``gap_rmse_55m_m`` [m] (the paper's 55 m).
        time_gap_s: t_gap of the time-gap reference d_ref = max(v_host t_gap, d_safe) [s].
        d_safe_m: d_safe of that reference [m].
        ttc_threshold_s: TTC below which time counts as critical [s].
        settle_s: time at the start left out of the comfort figures [s]; they are
            None when fewer than two rows remain (a window share: less than one window).

    Returns:
        A flat dict; values are floats, ints, strings or None (undefined, e.g. no
        closing-in for TTC). ICE vehicles add fuel_g_per_mi, co2/co/hc/nox_g_per_mi and
        mpg; the Leaf adds energy_kj_per_mi (eq. 6, regeneration negative),
        energy_wh_per_mi, and from VT-CPEM energy_vtcpem_kj_per_mi and
        regen_vtcpem_kj_per_mi (energy returned by regeneration, >= 0).

    Raises:
        RunLogError: the log file is invalid (see :func:`read_run_log`).
        KeyError: unknown vehicle name.
        ValueError: an option is negative, NaN or infinite.
    """
    for name, x in (("desired_gap_m", desired_gap_m), ("time_gap_s", time_gap_s),
                    ("d_safe_m", d_safe_m), ("ttc_threshold_s", ttc_threshold_s),
                    ("settle_s", settle_s)):  # fmt: skip
        if not (np.isfinite(x) and x >= 0.0):
            raise ValueError(f"{name} must be a finite number >= 0, got {x}")
    if not isinstance(log, RunLog):
        log = read_run_log(log)
    t, v, gap = log.t, log.v_host, log.gap
    w = _weights(t)
    distance_m = log.distance_m
    out: Metrics = {
        "rows": int(t.size),
        "duration_s": float(t[-1] - t[0]),
        "control_period_s": float(np.median(np.diff(t))),
        "distance_m": distance_m,
        "distance_mi": units.m_to_mi(distance_m),
        "mean_speed_mps": distance_m / float(t[-1] - t[0]),
        "speed_max_mps": float(v.max()),
        "collisions": int(np.sum(np.diff(np.concatenate([[0.0], log.collision])) > 0)),
        "gap_min_m": float(gap.min()),
    }

    with np.errstate(over="ignore"):  # an absurd t_gap or target gives inf, not a warning
        d_ref = np.maximum(v * time_gap_s, d_safe_m)
        out |= {
            "gap_mean_m": _wmean(gap, w),
            "gap_rmse_55m_m": _rms(gap - desired_gap_m, w),
            "gap_rmse_time_gap_m": _rms(gap - d_ref, w),
        }
    out |= {
        "desired_gap_m": desired_gap_m,
        "time_gap_s": time_gap_s,
        "d_safe_m": d_safe_m,
    }

    closing = v - log.v_lead  # [m/s] > 0 when the host closes in
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0.0, np.maximum(gap, 0.0) / closing, np.inf)
    out["ttc_min_s"] = float(ttc.min()) if np.isfinite(ttc).any() else None
    out["ttc_under_threshold_share"] = _wmean((ttc < ttc_threshold_s).astype(float), w)
    out["ttc_threshold_s"] = ttc_threshold_s

    moving = v > HEADWAY_MIN_SPEED_MPS
    if moving.any():
        hw, hww = gap[moving] / v[moving], w[moving]
        out["headway_min_s"] = float(hw.min())
        out["headway_mean_s"] = _wmean(hw, hww)
        order = np.argsort(hw)
        cdf = np.cumsum(hww[order]) / np.sum(hww)
        for q in (5, 50, 95):
            out[f"headway_p{q:02d}_s"] = float(hw[order][np.searchsorted(cdf, q / 100.0)])
        for lo, hi in zip(HEADWAY_BINS_S[:-1], HEADWAY_BINS_S[1:], strict=True):
            key = (
                f"headway_share_{lo:g}_{hi:g}s"
                if np.isfinite(hi)
                else f"headway_share_over_{lo:g}s"
            )
            out[key] = float(np.sum(hww[(hw >= lo) & (hw < hi)]) / np.sum(hww))
    else:
        out["headway_min_s"] = out["headway_mean_s"] = None

    out |= comfort_metrics(log, settle_s)
    out |= _energy(t, v, vehicle)
    return out


def comfort_metrics(log: RunLog, settle_s: float = SETTLE_S) -> Metrics:
    """The comfort figures of :func:`evaluate_run`: rows from ``settle_s`` on, but the
    unprompted hard brakes over the whole run."""
    keep = log.t >= log.t[0] + settle_s - comfort.WINDOW_SLACK_S
    t, accel, force = log.t[keep], log.accel[keep], log.force[keep]
    out: Metrics = {
        "settle_s": settle_s,
        "unprompted_hard_brakes": comfort.unprompted_hard_brakes(log.t, log.accel, log.gap, log.v_host, log.v_lead),
    }
    keys = ("accel_rms_mps2", "jerk_rms_mps3", "jerk_max_mps3", "force_rms",
            "iso_decel_window_share", "iso_jerk_window_share", "accel_sign_changes_per_min")  # fmt: skip
    if t.size < 2:
        return out | dict.fromkeys(keys)
    w = _weights(t)
    jerk = np.diff(accel) / np.diff(t)  # [m/s^3]
    return out | {
        "accel_rms_mps2": _rms(accel, w),
        "jerk_rms_mps3": _rms(jerk, np.diff(t)),
        "jerk_max_mps3": float(np.max(np.abs(jerk))),
        "force_rms": _rms(force, w),
        "iso_decel_window_share": comfort.decel_window_share(t, accel),
        "iso_jerk_window_share": comfort.jerk_window_share(t, accel),
        "accel_sign_changes_per_min": comfort.sign_changes_per_min(t, accel),
    }


def _energy(
    t: np.ndarray, v: np.ndarray, vehicle: str | cmem.CmemVehicle | ev.LeafVtCpem
) -> Metrics:
    if isinstance(vehicle, str):
        if vehicle not in VEHICLE_NAMES:
            raise KeyError(f"unknown vehicle {vehicle!r}; known: {', '.join(VEHICLE_NAMES)}")
        vehicle = ev.LEAF if vehicle == "leaf" else cmem.VEHICLES[vehicle]
    if isinstance(vehicle, ev.LeafVtCpem):
        fit = ev.eq6_per_mile(t, v)
        phys = ev.vtcpem_per_mile(t, v, vehicle)
        return {
            "vehicle": "leaf",
            "energy_kj_per_mi": fit.energy_kj_per_mi,
            "energy_wh_per_mi": fit.energy_wh_per_mi,
            "regen_vtcpem_kj_per_mi": phys.regen_kj_per_mi,
            "energy_vtcpem_kj_per_mi": phys.energy_kj_per_mi,
        }
    r = cmem.per_mile(t, v, vehicle)
    return {
        "vehicle": vehicle.name,
        "fuel_g_per_mi": r.fuel_g_per_mi,
        "co2_g_per_mi": r.co2_g_per_mi,
        "co_g_per_mi": r.co_g_per_mi,
        "hc_g_per_mi": r.hc_g_per_mi,
        "nox_g_per_mi": r.nox_g_per_mi,
        "mpg": r.mpg,
    }
