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

A log is scored in segments of :data:`energy.runlog.SEGMENT_ROWS` rows
(:mod:`energy.segments`), a file as it is read, so that a long one fits in memory: each
metric is made of sums, counts and extremes per segment, added in order at the end, with
state carried from one segment to the next (the deceleration windows' ∫a dt, the last sign
outside the deadband) and context rows around a segment for what needs a row's neighbours
(the next row's time for the weights, the row before for intervals, jerk and onsets,
:data:`AHEAD_S` for the ISO windows, the prompt window before a hard brake). Kept to the
end: every dt (8 B a row, the median control period) and every moving row's headway and
weight (16 B a row, the weighted percentiles). A log of one segment is scored by the very
numpy operations on the very arrays of a whole-log computation; over several, the sums
differ from a whole-log sum by rounding only, and the rest agree exactly.
"""

from __future__ import annotations

import functools
import operator
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from energy import cmem, comfort, ev, runlog, units
from energy.runlog import RunLog, iter_run_log
from energy.segments import Segment, segments

DESIRED_GAP_M = 55.0  # [m] the paper's desired gap; gap RMSE is taken against it
TIME_GAP_S = 1.8  # [s] default t_gap of d_ref = max(v t_gap, d_safe): the shipped ACC's
D_SAFE_M = 5.0  # [m] default d_safe of the same reference
TTC_THRESHOLD_S = 4.0  # [s] a common critical time-to-collision
HEADWAY_MIN_SPEED_MPS = 0.5  # [m/s] below this, time headway is not defined (standstill)
HEADWAY_BINS_S = (0.0, 1.0, 2.0, 3.0, 4.0, np.inf)  # [s] edges of the headway distribution
SETTLE_S = 15.0  # [s] default start left out of the comfort figures (runs start at 55 m)
AHEAD_S = max(comfort.ISO_DECEL_WINDOW_S, comfort.ISO_JERK_WINDOW_S)  # [s] a segment's look-ahead: the windows

VEHICLE_NAMES = ("corolla", "average", "leaf")
"""Vehicles :func:`evaluate_run` accepts by name."""
SCENARIO_VEHICLES = {"ice": "corolla", "ev": "leaf"}
"""The vehicle each simulator scenario's host is scored as, unless another is asked for."""

Metrics = dict[str, float | int | str | None]


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
    parts = (
        _Run(desired_gap_m, time_gap_s, d_safe_m, ttc_threshold_s),
        _Comfort(settle_s),
        _Energy(vehicle),
    )
    _score(log, parts)
    return {k: v for p in parts for k, v in p.result().items()}


def comfort_metrics(log: RunLog, settle_s: float = SETTLE_S) -> Metrics:
    """The comfort figures of :func:`evaluate_run`: rows from ``settle_s`` on, but the
    unprompted hard brakes over the whole run."""
    part = _Comfort(settle_s)
    _score(log, (part,))
    return part.result()


class _Part(Protocol):
    def add(self, seg: Segment) -> None: ...
    def result(self) -> Metrics: ...


def _score(log: RunLog | str | Path, parts: Iterable[_Part]) -> None:
    """Feed the log's segments to each part, in order, streaming a file."""
    rows = runlog.SEGMENT_ROWS  # read now: tests shrink it
    chunks = log.chunks(rows) if isinstance(log, RunLog) else iter_run_log(log, rows)
    for seg in segments(chunks, rows, comfort.prompt_window_start, AHEAD_S):
        for part in parts:
            part.add(seg)


def _weights(seg: Segment) -> np.ndarray:
    """Each core row's weight [s]: the time until the next row; the log's last row's is
    the step before it."""
    t, c0, c1 = seg.rows.t, seg.c0, seg.c1
    if c1 < t.size:
        return np.diff(t[c0 : c1 + 1])
    dt = np.diff(t[c0:c1])
    return np.append(dt, dt[-1]) if dt.size else t[c1 - 1 : c1] - t[c1 - 2 : c1 - 1]


def _with_prev(seg: Segment) -> slice:
    """The core rows and the row before them (the intervals that end in the core)."""
    return slice(seg.c0 - (seg.c0 > 0), seg.c1)


def _total(parts: list[Any]) -> Any:
    """The segments' parts added in order (one segment: its part itself)."""
    return functools.reduce(operator.add, parts)


class _Kept:
    """A float64 array kept to the end of a log, grown in place (``realloc``): the C library
    moves a large block's pages without copying them (glibc's ``mremap``), and the block goes
    back to the system whole when freed, where a list of segments' arrays joined at the end
    would need twice the memory and leave the heap in pieces."""

    def __init__(self) -> None:
        self.a = np.empty(0)
        self.n = 0

    def extend(self, x: np.ndarray) -> None:
        if self.n + x.size > self.a.size:
            self.a.resize(max(self.a.size * 3 // 2, self.n + x.size), refcheck=False)
        self.a[self.n : self.n + x.size] = x
        self.n += x.size

    def take(self) -> np.ndarray:
        """The values, as one array (no copy); the keeper is left empty."""
        a, n = self.a, self.n
        self.a, self.n = np.empty(0), 0
        a.resize(n, refcheck=False)
        return a


class _Run:
    """Gap keeping, safety and distance. Per segment: sums and extremes. Kept for the end:
    every interval's dt (8 B a row, for the median) and every moving row's headway and
    weight (16 B a row, for the weighted percentiles)."""

    def __init__(self, desired_gap_m: float, time_gap_s: float, d_safe_m: float, ttc_threshold_s: float):
        self.desired_gap_m, self.time_gap_s, self.d_safe_m = desired_gap_m, time_gap_s, d_safe_m
        self.ttc_threshold_s = ttc_threshold_s
        self.rows, self.ttc_defined = 0, False
        self.t_first = self.t_last = np.nan
        self.sums: dict[str, list[Any]] = defaultdict(list)
        self.v_max: list[Any] = []
        self.gap_min: list[Any] = []
        self.ttc_min: list[Any] = []
        self.dt, self.headway, self.headway_w = _Kept(), _Kept(), _Kept()

    def add(self, seg: Segment) -> None:
        log, core, prev = seg.rows, slice(seg.c0, seg.c1), _with_prev(seg)
        t, v, gap = log.t[core], log.v_host[core], log.gap[core]
        w = _weights(seg)
        self.t_first = t[0] if seg.first else self.t_first
        self.t_last = log.t[-1] if seg.end else self.t_last
        self.rows += t.size
        tp, vp = log.t[prev], log.v_host[prev]
        self.dt.extend(np.diff(tp))
        collision = log.collision[prev] if seg.c0 else np.concatenate([[0.0], log.collision[core]])
        closing = v - log.v_lead[core]  # [m/s] > 0 when the host closes in
        with np.errstate(divide="ignore", invalid="ignore"):
            ttc = np.where(closing > 0.0, np.maximum(gap, 0.0) / closing, np.inf)
        self.ttc_defined = self.ttc_defined or bool(np.isfinite(ttc).any())
        with np.errstate(over="ignore"):  # an absurd t_gap or target gives inf, not a warning
            d_ref = np.maximum(v * self.time_gap_s, self.d_safe_m)
            parts = {
                "w": np.sum(w),
                "distance": np.sum(0.5 * (vp[1:] + vp[:-1]) * np.diff(tp)),
                "onsets": np.sum(np.diff(collision) > 0),
                "gap": np.sum(gap * w),
                "gap_55": np.sum((gap - self.desired_gap_m) ** 2 * w),
                "gap_ref": np.sum((gap - d_ref) ** 2 * w),
                "ttc_under": np.sum((ttc < self.ttc_threshold_s).astype(float) * w),
            }
        for k, x in parts.items():
            self.sums[k].append(x)
        self.v_max.append(v.max())
        self.gap_min.append(gap.min())
        self.ttc_min.append(ttc.min())
        moving = v > HEADWAY_MIN_SPEED_MPS
        self.headway.extend(gap[moving] / v[moving])
        self.headway_w.extend(w[moving])

    def result(self) -> Metrics:
        with np.errstate(over="ignore"):
            s = {k: _total(x) for k, x in self.sums.items()}
        distance_m, duration_s = float(s["distance"]), float(self.t_last - self.t_first)
        out: Metrics = {
            "rows": self.rows,
            "duration_s": duration_s,
            "control_period_s": self._control_period(),
            "distance_m": distance_m,
            "distance_mi": units.m_to_mi(distance_m),
            "mean_speed_mps": distance_m / duration_s,
            "speed_max_mps": float(max(self.v_max)),
            "collisions": int(s["onsets"]),
            "gap_min_m": float(min(self.gap_min)),
            "gap_mean_m": float(s["gap"] / s["w"]),
            "gap_rmse_55m_m": float(np.sqrt(float(s["gap_55"] / s["w"]))),
            "gap_rmse_time_gap_m": float(np.sqrt(float(s["gap_ref"] / s["w"]))),
            "desired_gap_m": self.desired_gap_m,
            "time_gap_s": self.time_gap_s,
            "d_safe_m": self.d_safe_m,
            "ttc_min_s": float(min(self.ttc_min)) if self.ttc_defined else None,
            "ttc_under_threshold_share": float(s["ttc_under"] / s["w"]),
            "ttc_threshold_s": self.ttc_threshold_s,
        }
        return out | self._headway()

    def _control_period(self) -> float:
        """The median dt [s], the kept dt freed (sorted in place: no copy)."""
        return float(np.median(self.dt.take(), overwrite_input=True))

    def _headway(self) -> Metrics:
        """The headway figures, from the kept arrays, freed as they go (the peak: 32 B a
        moving row, while the weights are sorted)."""
        hw, hww = self.headway.take(), self.headway_w.take()
        if hw.size == 0:
            return {"headway_min_s": None, "headway_mean_s": None}
        total = np.sum(hww)
        out: Metrics = {"headway_min_s": float(hw.min()), "headway_mean_s": float(np.sum(hw * hww) / total)}
        shares = {}
        for lo, hi in zip(HEADWAY_BINS_S[:-1], HEADWAY_BINS_S[1:], strict=True):
            key = f"headway_share_{lo:g}_{hi:g}s" if np.isfinite(hi) else f"headway_share_over_{lo:g}s"
            shares[key] = float(np.sum(hww[(hw >= lo) & (hw < hi)]) / total)
        order = np.argsort(hw)
        cdf = hww[order]
        del hww
        np.cumsum(cdf, out=cdf)
        cdf /= total
        for q in (5, 50, 95):
            out[f"headway_p{q:02d}_s"] = float(hw[order[np.searchsorted(cdf, q / 100.0)]])
        return out | shares


class _Comfort:
    """The comfort figures, rows from the settle cut on (known from the first segment), and
    the unprompted hard brakes of every row. Carried from segment to segment: the ISO
    deceleration windows' integral ∫a dt and the last sign outside the deadband."""

    KEYS = ("accel_rms_mps2", "jerk_rms_mps3", "jerk_max_mps3", "force_rms",
            "iso_decel_window_share", "iso_jerk_window_share", "accel_sign_changes_per_min")  # fmt: skip

    def __init__(self, settle_s: float):
        self.settle_s = settle_s
        self.cut = np.inf  # [s] the first time the figures count
        self.brakes = self.kept = self.changes = self.sign = 0
        self.t_first: Any = None  # [s] the first kept row's time
        self.t_last: Any = None  # [s] the log's last
        self.dv = 0.0  # [m/s] ∫a dt from the first kept row to the next core's first row
        self.sums: dict[str, list[Any]] = defaultdict(list)
        self.jerk_max: list[Any] = []
        self.windows = {"decel": [0, 0], "jerk": [0, 0]}  # over the limit, all

    def add(self, seg: Segment) -> None:
        log, c0, c1 = seg.rows, seg.c0, seg.c1
        t, a = log.t, log.accel
        if seg.first:
            self.cut = t[0] + self.settle_s - comfort.WINDOW_SLACK_S
        self.t_last = t[-1] if seg.end else self.t_last
        self.brakes += comfort.unprompted_onsets(t[:c1], a[:c1], log.gap[:c1], log.v_host[:c1], log.v_lead[:c1], max(c0, 1))
        first_kept = int(np.searchsorted(t, self.cut))
        k = max(c0, first_kept)  # the kept core rows: k .. c1 - 1
        if k >= c1:
            return
        self.t_first = t[k] if self.t_first is None else self.t_first
        self.kept += c1 - k
        w = _weights(seg)[k - c0 :]
        j0 = k - 1 if k > first_kept else k  # the interval from the row before, if kept
        dt = np.diff(t[j0:c1])
        jerk = np.diff(a[j0:c1]) / dt  # [m/s^3]
        parts = {"w": np.sum(w), "accel": np.sum(a[k:c1] ** 2 * w), "force": np.sum(log.force[k:c1] ** 2 * w)}
        if jerk.size:
            parts |= {"jerk": np.sum(jerk**2 * dt), "dt": np.sum(dt)}
            self.jerk_max.append(np.max(np.abs(jerk)))
        for key, x in parts.items():
            self.sums[key].append(x)
        self._windows(t[k:], a[k:], c1 - k, seg.end)
        changes, self.sign = comfort.sign_changes(a[k:c1], self.sign)
        self.changes += changes

    def _windows(self, t: np.ndarray, a: np.ndarray, m: int, end: bool) -> None:
        """The ISO windows that start at the first ``m`` rows of ``t`` (all of them unless the
        log ends within the look-ahead; the rest is context)."""
        n = {}
        for name, window_s in (("decel", comfort.ISO_DECEL_WINDOW_S), ("jerk", comfort.ISO_JERK_WINDOW_S)):
            n[name] = int(np.count_nonzero(t[:m] + window_s <= t[-1] + comfort.WINDOW_SLACK_S)) if end else m
        over, dv = comfort.decel_windows_over(t, a, n["decel"], self.dv)
        self.dv = dv[m] if m < t.size else self.dv
        for name, count in (("decel", over), ("jerk", comfort.jerk_windows_over(t, a, n["jerk"]))):
            self.windows[name][0] += count
            self.windows[name][1] += n[name]

    def result(self) -> Metrics:
        out: Metrics = {"settle_s": self.settle_s, "unprompted_hard_brakes": self.brakes}
        if self.kept < 2:
            return out | dict.fromkeys(self.KEYS)
        s = {k: _total(x) for k, x in self.sums.items()}
        (d_over, d_all), (j_over, j_all) = self.windows["decel"], self.windows["jerk"]
        return out | {
            "accel_rms_mps2": float(np.sqrt(float(s["accel"] / s["w"]))),
            "jerk_rms_mps3": float(np.sqrt(float(s["jerk"] / s["dt"]))),
            "jerk_max_mps3": float(max(self.jerk_max)),
            "force_rms": float(np.sqrt(float(s["force"] / s["w"]))),
            "iso_decel_window_share": d_over / d_all if d_all else None,
            "iso_jerk_window_share": j_over / j_all if j_all else None,
            "accel_sign_changes_per_min": self.changes / ((self.t_last - self.t_first) / 60.0),
        }


class _Energy:
    """Fuel and emissions (ICE) or battery energy (EV): the models' sums over each
    segment's intervals, divided by the distance at the end."""

    def __init__(self, vehicle: str | cmem.CmemVehicle | ev.LeafVtCpem):
        if isinstance(vehicle, str):
            if vehicle not in VEHICLE_NAMES:
                raise KeyError(f"unknown vehicle {vehicle!r}; known: {', '.join(VEHICLE_NAMES)}")
            vehicle = ev.LEAF if vehicle == "leaf" else cmem.VEHICLES[vehicle]
        self.vehicle = vehicle
        self.parts: list[Any] = []

    def add(self, seg: Segment) -> None:
        prev = _with_prev(seg)
        t, v = seg.rows.t[prev], seg.rows.v_host[prev]
        if t.size < 2:  # no interval: a one-row log's only segment
            return
        if isinstance(self.vehicle, ev.LeafVtCpem):
            self.parts.append((ev.eq6_totals(t, v), ev.vtcpem_totals(t, v, self.vehicle)))
        else:
            self.parts.append(cmem.interval_totals(t, v, self.vehicle))

    def result(self) -> Metrics:
        if isinstance(self.vehicle, ev.LeafVtCpem):
            fit = ev.totals_per_mile(ev.EQ6, _total([p[0] for p in self.parts]))
            phys = ev.totals_per_mile(ev.VTCPEM, _total([p[1] for p in self.parts]))
            return {
                "vehicle": "leaf",
                "energy_kj_per_mi": fit.energy_kj_per_mi,
                "energy_wh_per_mi": fit.energy_wh_per_mi,
                "regen_vtcpem_kj_per_mi": phys.regen_kj_per_mi,
                "energy_vtcpem_kj_per_mi": phys.energy_kj_per_mi,
            }
        r = cmem.totals_per_mile(_total(self.parts), self.vehicle.name)
        return {
            "vehicle": self.vehicle.name,
            "fuel_g_per_mi": r.fuel_g_per_mi,
            "co2_g_per_mi": r.co2_g_per_mi,
            "co_g_per_mi": r.co_g_per_mi,
            "hc_g_per_mi": r.hc_g_per_mi,
            "nox_g_per_mi": r.nox_g_per_mi,
            "mpg": r.mpg,
        }
