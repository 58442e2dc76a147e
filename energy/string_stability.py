"""String stability of a platoon: how speed changes grow from the lead to the last car.

A platoon is a common time base ``t`` [s] (N samples), the speeds ``v`` [m/s] of its
cars, lead first, as an array ``[n_cars, N]``, and the gaps ``gaps`` [m] of each
follower to the car directly ahead, ``[n_cars - 1, N]`` (row i: car i + 1 behind car i).
NaN marks a gap in the recording (the OpenACC files have some); every figure is taken
over the samples where the signals it compares are finite.

* :func:`amplification`: per pair (car i to car i + 1) and lead to last, the ratio of
  speed deviation (speed minus its mean) and of acceleration, in RMS (L2) and peak
  (L-infinity), after the first fifth of the run (:data:`SKIP_FRACTION`), which holds
  the platoon's own settling from its start.
* :func:`spectral_gain`: Welch's cross-spectral estimate of a follower's speed-to-speed
  gain |P_xy / P_xx| over the band where the input speed has energy.
* :func:`safety`: each follower's minimum gap and minimum time-to-collision.
* :func:`platoon_energy`: each car's fuel (ICE, CMEM) or battery energy (EV, eq. 6)
  and the platoon's totals.
* :func:`string_stability`: all of these as one flat dict, keys carrying their unit.

A platoon is string-stable in the L2 sense when no ratio exceeds 1 (Ploeg et al. 2014);
the frequency-domain gain is the same statement per frequency.
Depends on numpy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from energy import cmem, ev

__all__ = [
    "SKIP_FRACTION",
    "BAND_FRACTION",
    "Ratios",
    "Amplification",
    "SpectralGain",
    "CarSafety",
    "CarEnergy",
    "amplification",
    "spectral_gain",
    "welch",
    "safety",
    "platoon_energy",
    "string_stability",
]

SKIP_FRACTION = 0.2  # [-] the first fifth of a run is left out of the amplification figures
BAND_FRACTION = 0.1  # [-] the band: frequencies where the input's power is at least this share of its peak
MIN_SEGMENTS = 3  # Welch segments (50 % overlap) the default segment length leaves at least


class Ratios(NamedTuple):
    """Amplification from one car to another (output over input), each [-]."""

    speed_rms: float  # RMS of speed deviation
    speed_peak: float  # peak |speed deviation|
    accel_rms: float  # RMS of acceleration
    accel_peak: float  # peak |acceleration|


class Amplification(NamedTuple):
    """Per pair (``pairs[i]``: car i to car i + 1) and lead to last."""

    pairs: tuple[Ratios, ...]
    lead_to_last: Ratios
    lead_speed_dev_rms: float  # [m/s] the lead's own RMS speed deviation in the window
    last_speed_dev_rms: float  # [m/s] the last car's


class SpectralGain(NamedTuple):
    """A follower's speed-to-speed gain estimated from data."""

    freqs: np.ndarray  # [Hz] the frequencies of the band
    gain: np.ndarray  # [-] |H| at those frequencies
    coherence: np.ndarray  # [-] squared coherence there (1: a linear, noise-free relation)
    peak: float  # [-] the largest gain in the band
    mean: float  # [-] the gain averaged over the band, weighted by the input's power


class CarSafety(NamedTuple):
    """One follower's closest approach to the car ahead."""

    min_gap_m: float  # [m]
    min_ttc_s: float  # [s] inf when it never closed in


class CarEnergy(NamedTuple):
    """One car's consumption over the run (the lead's too)."""

    vehicle: str  # "corolla", "average" or "leaf"
    distance_m: float  # [m]
    fuel_g: float  # [g] CMEM fuel; 0 for an EV
    energy_kj: float  # [kJ] net battery energy (eq. 6); 0 for an ICE car


def _window(n: int, skip_fraction: float) -> slice:
    if not 0.0 <= skip_fraction < 1.0:
        raise ValueError(f"skip_fraction must be in [0, 1), got {skip_fraction!r}")
    return slice(int(n * skip_fraction), n)


def _ratio(out: float, inp: float) -> float:
    if inp > 0.0:
        return out / inp
    return float("inf") if out > 0.0 else float("nan")


def _accel(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Acceleration [m/s^2] per sample by central differences; NaN next to a NaN speed."""
    return np.gradient(v, t)


def _ratios(t: np.ndarray, v_in: np.ndarray, v_out: np.ndarray) -> tuple[Ratios, float, float]:
    """Ratios of ``v_out`` to ``v_in`` over their common finite samples, and both RMS deviations."""
    a_in, a_out = _accel(t, v_in), _accel(t, v_out)
    ok = np.isfinite(v_in) & np.isfinite(v_out)
    ok_a = np.isfinite(a_in) & np.isfinite(a_out)
    if ok.sum() < 2 or ok_a.sum() < 2:
        nan = float("nan")
        return Ratios(nan, nan, nan, nan), nan, nan
    d_in, d_out = v_in[ok] - v_in[ok].mean(), v_out[ok] - v_out[ok].mean()
    rms_in, rms_out = float(np.sqrt(np.mean(d_in**2))), float(np.sqrt(np.mean(d_out**2)))
    a_in, a_out = a_in[ok_a], a_out[ok_a]
    ratios = Ratios(
        speed_rms=_ratio(rms_out, rms_in),
        speed_peak=_ratio(float(np.max(np.abs(d_out))), float(np.max(np.abs(d_in)))),
        accel_rms=_ratio(float(np.sqrt(np.mean(a_out**2))), float(np.sqrt(np.mean(a_in**2)))),
        accel_peak=_ratio(float(np.max(np.abs(a_out))), float(np.max(np.abs(a_in)))),
    )
    return ratios, rms_in, rms_out


def _check_platoon(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t, v = np.asarray(t, dtype=float), np.asarray(v, dtype=float)
    if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] != t.shape[0]:
        raise ValueError(f"speeds must be [n_cars >= 2, {t.shape[0]}] for {t.shape[0]} times, got {v.shape}")
    if t.ndim != 1 or t.shape[0] < 3 or not np.all(np.diff(t) > 0.0):
        raise ValueError("times must be a strictly increasing 1-D array of at least 3 samples")
    return t, v


def amplification(t: np.ndarray, v: np.ndarray, *, skip_fraction: float = SKIP_FRACTION) -> Amplification:
    """Amplification of speed deviation and acceleration, per pair and lead to last.

    Args:
        t: sample times [s], strictly increasing, shape [N].
        v: speeds [m/s], lead first, shape [n_cars, N]; NaN where not recorded.
        skip_fraction: the share of the run at its start left out.

    Raises:
        ValueError: bad shapes, times or ``skip_fraction``.
    """
    t, v = _check_platoon(t, v)
    w = _window(t.shape[0], skip_fraction)
    t, v = t[w], v[:, w]
    pairs = tuple(_ratios(t, v[i], v[i + 1])[0] for i in range(v.shape[0] - 1))
    last, rms_lead, rms_last = _ratios(t, v[0], v[-1])
    return Amplification(pairs, last, rms_lead, rms_last)


def _fill(x: np.ndarray) -> np.ndarray:
    """``x`` with NaNs filled by linear interpolation (held flat beyond the ends)."""
    ok = np.isfinite(x)
    if ok.all():
        return x
    if not ok.any():
        raise ValueError("a signal with no finite sample")
    idx = np.arange(x.shape[0])
    return np.interp(idx, idx[ok], x[ok])


def welch(
    x: np.ndarray, y: np.ndarray, fs: float, nperseg: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Welch's averaged periodograms: Hann window, 50 % overlap, each segment's mean removed.

    Args:
        x, y: evenly sampled signals of the same length.
        fs: sample rate [Hz].
        nperseg: samples per segment; default the largest power of two that leaves
            :data:`MIN_SEGMENTS` segments (at most the signal's length).

    Returns:
        (f [Hz], P_xx, P_yy, P_xy), one-sided, in the signals' units squared per Hz.

    Raises:
        ValueError: signals of different lengths or shorter than 8 samples.
    """
    n = x.shape[0]
    if y.shape[0] != n or n < 8:
        raise ValueError(f"welch needs two signals of the same length >= 8, got {n} and {y.shape[0]}")
    if nperseg is None:
        nperseg = 1 << int(np.floor(np.log2(max(8, 2 * n // (MIN_SEGMENTS + 1)))))
    nperseg = min(nperseg, n)
    step = max(nperseg // 2, 1)
    starts = np.arange(0, n - nperseg + 1, step)
    win = np.hanning(nperseg)
    scale = 1.0 / (fs * np.sum(win**2))
    segs_x = np.stack([x[s : s + nperseg] for s in starts])  # [S, nperseg]
    segs_y = np.stack([y[s : s + nperseg] for s in starts])
    fx = np.fft.rfft((segs_x - segs_x.mean(axis=1, keepdims=True)) * win, axis=1)  # [S, F]
    fy = np.fft.rfft((segs_y - segs_y.mean(axis=1, keepdims=True)) * win, axis=1)
    pxx = scale * np.mean(np.abs(fx) ** 2, axis=0)
    pyy = scale * np.mean(np.abs(fy) ** 2, axis=0)
    pxy = scale * np.mean(np.conj(fx) * fy, axis=0)
    # One-sided: double every bin but DC (and Nyquist for an even length); ratios don't care.
    pxx[1:], pyy[1:], pxy[1:] = 2 * pxx[1:], 2 * pyy[1:], 2 * pxy[1:]
    return np.fft.rfftfreq(nperseg, 1.0 / fs), pxx, pyy, pxy


def spectral_gain(
    t: np.ndarray,
    v_in: np.ndarray,
    v_out: np.ndarray,
    *,
    skip_fraction: float = SKIP_FRACTION,
    band_fraction: float = BAND_FRACTION,
    nperseg: int | None = None,
) -> SpectralGain:
    """A follower's speed-to-speed gain |P_xy / P_xx| over the band where the input has energy.

    The band is every frequency above 0 Hz where the input's power is at least
    ``band_fraction`` of its largest. Gaps (NaN) are filled by linear interpolation.

    Args:
        t: sample times [s], evenly spaced.
        v_in: the car ahead's speed [m/s] (or the lead's).
        v_out: the follower's speed [m/s].
        skip_fraction: share of the run at its start left out.
        band_fraction: the band's power threshold relative to the input's peak.
        nperseg: Welch segment length [samples]; see :func:`welch`.

    Raises:
        ValueError: uneven times, a signal with no finite sample, or no band (a constant input).
    """
    t = np.asarray(t, dtype=float)
    dt = np.diff(t)
    if dt.size == 0 or not np.allclose(dt, dt[0], rtol=1e-6, atol=1e-9):
        raise ValueError("spectral_gain needs evenly sampled times")
    w = _window(t.shape[0], skip_fraction)
    x, y = _fill(np.asarray(v_in, float)[w]), _fill(np.asarray(v_out, float)[w])
    f, pxx, pyy, pxy = welch(x, y, 1.0 / float(dt[0]), nperseg)
    top = float(np.max(pxx[1:])) if pxx.shape[0] > 1 else 0.0
    band = np.zeros_like(pxx, dtype=bool)
    band[1:] = pxx[1:] >= band_fraction * top
    if top <= 0.0 or not band.any():
        raise ValueError("the input speed has no power above 0 Hz: no band to estimate a gain over")
    gain = np.abs(pxy[band]) / pxx[band]
    coherence = np.abs(pxy[band]) ** 2 / (pxx[band] * pyy[band])
    return SpectralGain(
        freqs=f[band],
        gain=gain,
        coherence=coherence,
        peak=float(np.max(gain)),
        mean=float(np.sum(gain * pxx[band]) / np.sum(pxx[band])),
    )


def safety(t: np.ndarray, v: np.ndarray, gaps: np.ndarray) -> tuple[CarSafety, ...]:
    """Each follower's minimum gap [m] and minimum time-to-collision [s], over the whole run.

    TTC is the gap over the closing speed (follower minus car ahead) where that is positive.

    Raises:
        ValueError: ``gaps`` not of shape [n_cars - 1, N].
    """
    t, v = _check_platoon(t, v)
    gaps = np.asarray(gaps, dtype=float)
    if gaps.shape != (v.shape[0] - 1, v.shape[1]):
        raise ValueError(f"gaps must be [{v.shape[0] - 1}, {v.shape[1]}], got {gaps.shape}")
    out = []
    for i in range(gaps.shape[0]):
        closing = v[i + 1] - v[i]  # [m/s]
        g = gaps[i]
        ok = np.isfinite(g)
        near = ok & np.isfinite(closing) & (closing > 0.0)
        ttc = float(np.min(g[near] / closing[near])) if near.any() else float("inf")
        out.append(CarSafety(float(np.min(g[ok])) if ok.any() else float("nan"), ttc))
    return tuple(out)


def platoon_energy(t: np.ndarray, v: np.ndarray, vehicles: Sequence[str]) -> tuple[CarEnergy, ...]:
    """Each car's fuel (CMEM) or battery energy (eq. 6) over the run, by the energy models.

    Args:
        t: sample times [s].
        v: speeds [m/s], [n_cars, N], finite (fill gaps first).
        vehicles: one name per car: ``"corolla"``, ``"average"`` (ICE) or ``"leaf"`` (EV).

    Raises:
        ValueError: a vehicle count that does not match, or an unknown name.
        TraceError: a speed trace the energy models refuse (negative, or no distance).
    """
    t, v = _check_platoon(t, v)
    if len(vehicles) != v.shape[0]:
        raise ValueError(f"{len(vehicles)} vehicles for {v.shape[0]} cars")
    out = []
    for name, vi in zip(vehicles, v, strict=True):
        if name == "leaf":
            r = ev.eq6_per_mile(t, vi)
            out.append(CarEnergy(name, r.distance_mi * _M_PER_MI, 0.0, r.energy_kj_per_mi * r.distance_mi))
        elif name in cmem.VEHICLES:
            c = cmem.per_mile(t, vi, cmem.VEHICLES[name])
            out.append(CarEnergy(name, c.distance_mi * _M_PER_MI, c.fuel_g_per_mi * c.distance_mi, 0.0))
        else:
            raise ValueError(f"unknown vehicle {name!r}; known: leaf, {', '.join(cmem.VEHICLES)}")
    return tuple(out)


_M_PER_MI = 1609.344  # [m/mi]


def string_stability(
    t: np.ndarray,
    v: np.ndarray,
    gaps: np.ndarray,
    vehicles: Sequence[str] | None = None,
    *,
    skip_fraction: float = SKIP_FRACTION,
) -> dict[str, float]:
    """Every string-stability figure of a platoon as one flat dict.

    Keys: ``amp_<pair>_<signal>_<norm>`` with pair ``1_2`` (car 1 to car 2, the lead
    being car 0: ``0_1``) or ``lead_last``, signal ``speed`` or ``accel``, norm ``rms``
    or ``peak``; ``gain_<i>_peak``/``gain_<i>_mean`` (follower i on the car ahead);
    ``min_gap_<i>_m``, ``min_ttc_<i>_s``; with ``vehicles``, ``fuel_total_g`` and
    ``energy_total_kj``. A gain the data can't give (a constant lead) is NaN.

    Raises:
        ValueError: as :func:`amplification` and :func:`safety`.
    """
    t, v = _check_platoon(t, v)
    amp = amplification(t, v, skip_fraction=skip_fraction)
    out: dict[str, float] = {
        "lead_speed_dev_rms_mps": amp.lead_speed_dev_rms,
        "last_speed_dev_rms_mps": amp.last_speed_dev_rms,
    }
    named = [(f"{i}_{i + 1}", r) for i, r in enumerate(amp.pairs)] + [("lead_last", amp.lead_to_last)]
    for pair, r in named:
        for field, value in r._asdict().items():
            out[f"amp_{pair}_{field}"] = value
    even = np.allclose(np.diff(t), t[1] - t[0], rtol=1e-6, atol=1e-9)
    for i in range(1, v.shape[0]):
        try:
            g = spectral_gain(t, v[i - 1], v[i], skip_fraction=skip_fraction) if even else None
        except ValueError:
            g = None
        out[f"gain_{i}_peak"] = g.peak if g else float("nan")
        out[f"gain_{i}_mean"] = g.mean if g else float("nan")
    for i, s in enumerate(safety(t, v, gaps), start=1):
        out[f"min_gap_{i}_m"], out[f"min_ttc_{i}_s"] = s.min_gap_m, s.min_ttc_s
    if vehicles is not None:
        cars = platoon_energy(t, v, vehicles)
        out["fuel_total_g"] = sum(c.fuel_g for c in cars)
        out["energy_total_kj"] = sum(c.energy_kj for c in cars)
    return out
