"""String-stability figures on platoons whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from energy.string_stability import (
    amplification,
    platoon_energy,
    safety,
    spectral_gain,
    string_stability,
    welch,
)

DT = 0.1  # [s]
T = np.arange(0.0, 600.0, DT)  # [s]
F0 = 0.05  # [Hz]


def sine_platoon(gains: list[float], f: float = F0, v0: float = 10.0) -> np.ndarray:
    """Speeds [m/s]: a lead at v0 + sin(2 pi f t), each car ``gains[i]`` times the one ahead, lagged."""
    amp, phase, rows = 1.0, 0.0, []
    rows.append(v0 + amp * np.sin(2 * np.pi * f * T))
    for g in gains:
        amp, phase = amp * g, phase - 0.4
        rows.append(v0 + amp * np.sin(2 * np.pi * f * T + phase))
    return np.stack(rows)


def test_amplification_of_a_growing_sine_is_the_product_of_gains() -> None:
    v = sine_platoon([1.5, 2.0])
    amp = amplification(T, v)
    assert [p.speed_rms for p in amp.pairs] == pytest.approx([1.5, 2.0], rel=1e-3)
    assert amp.lead_to_last.speed_rms == pytest.approx(3.0, rel=1e-3)
    assert amp.lead_to_last.speed_peak == pytest.approx(3.0, rel=1e-3)
    # Same frequency: the acceleration grows as the speed does.
    assert amp.lead_to_last.accel_rms == pytest.approx(3.0, rel=1e-2)
    assert amp.lead_to_last.accel_peak == pytest.approx(3.0, rel=1e-2)
    assert amp.lead_speed_dev_rms == pytest.approx(1 / np.sqrt(2), rel=1e-3)


def test_amplification_skips_the_first_fifth() -> None:
    """A follower that oscillates only at the start is string-stable after it."""
    v = sine_platoon([1.0])
    v[1, : len(T) // 5] += 5.0 * np.sin(2 * np.pi * 0.2 * T[: len(T) // 5])
    assert amplification(T, v).lead_to_last.speed_rms == pytest.approx(1.0, rel=1e-3)
    assert amplification(T, v, skip_fraction=0.0).lead_to_last.speed_rms > 2.0


def test_amplification_ignores_gaps_in_the_recording() -> None:
    v = sine_platoon([2.0])
    v[1, 3000:3100] = np.nan
    assert amplification(T, v).lead_to_last.speed_rms == pytest.approx(2.0, rel=1e-2)


def test_a_constant_lead_makes_the_ratio_meaningless() -> None:
    """Behind a constant lead the ratio blows up; the last car's own deviation is the figure."""
    v = np.stack([np.full_like(T, 8.1), 8.1 + 0.3 * np.sin(T)])
    amp = amplification(T, v)
    assert amp.lead_speed_dev_rms == pytest.approx(0.0, abs=1e-12)
    assert amp.last_speed_dev_rms == pytest.approx(0.3 / np.sqrt(2), rel=1e-2)
    assert amp.lead_to_last.speed_rms > 1e6


def test_welch_power_of_a_sine_integrates_to_its_variance() -> None:
    x = 2.0 * np.sin(2 * np.pi * F0 * T)
    f, pxx, _, _ = welch(x, x, 1 / DT)
    assert np.sum(pxx) * (f[1] - f[0]) == pytest.approx(2.0, rel=0.05)  # variance of 2 sin: 2


@pytest.mark.parametrize("gain", [0.7, 1.0, 1.6])
def test_spectral_gain_recovers_a_sine_gain(gain: float) -> None:
    v = sine_platoon([gain])
    g = spectral_gain(T, v[0], v[1])
    assert g.freqs.min() <= F0 <= g.freqs.max()
    assert g.mean == pytest.approx(gain, rel=0.02)
    assert g.coherence.min() > 0.99


def test_spectral_gain_of_a_first_order_lag_follows_its_magnitude() -> None:
    """A follower that is a first-order lag (tau) of broadband input: |H| = 1/sqrt(1 + (w tau)^2)."""
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=T.size)) * 0.05
    tau, y = 2.0, np.empty_like(x)
    y[0] = x[0]
    for k in range(1, x.size):  # exact ZOH discretisation of dy/dt = (x - y) / tau
        y[k] = x[k - 1] + (y[k - 1] - x[k - 1]) * np.exp(-DT / tau)
    g = spectral_gain(T, x, y, band_fraction=0.01)
    theory = 1 / np.sqrt(1 + (2 * np.pi * g.freqs * tau) ** 2)
    assert g.gain == pytest.approx(theory, rel=0.1)


def test_spectral_gain_refuses_a_constant_lead() -> None:
    with pytest.raises(ValueError, match="no power"):
        spectral_gain(T, np.full_like(T, 8.0), np.full_like(T, 8.0))


def test_safety_min_gap_and_ttc() -> None:
    t = np.arange(0.0, 10.0, 1.0)
    v = np.stack([np.full_like(t, 10.0), np.where(t < 5, 12.0, 10.0)])
    gaps = np.array([20.0 - 2.0 * np.minimum(t, 5)])
    (s,) = safety(t, v, gaps)
    assert s.min_gap_m == pytest.approx(10.0)
    assert s.min_ttc_s == pytest.approx(12.0 / 2.0)  # at t = 4 s: 12 m closing at 2 m/s
    (never,) = safety(t, np.stack([v[0], v[0]]), gaps)
    assert never.min_ttc_s == float("inf")


def test_safety_refuses_gaps_of_the_wrong_shape() -> None:
    with pytest.raises(ValueError, match="gaps must be"):
        safety(T, sine_platoon([1.0]), np.zeros((2, T.size)))


def test_platoon_energy_uses_each_cars_model() -> None:
    v = sine_platoon([1.0, 1.0], v0=20.0)
    cars = platoon_energy(T, v, ["leaf", "corolla", "leaf"])
    assert [c.vehicle for c in cars] == ["leaf", "corolla", "leaf"]
    assert cars[0].distance_m == pytest.approx(20.0 * (T[-1] - T[0]), rel=1e-3)
    assert cars[0].energy_kj > 0 and cars[0].fuel_g == 0
    assert cars[1].fuel_g > 0 and cars[1].energy_kj == 0
    with pytest.raises(ValueError, match="unknown vehicle"):
        platoon_energy(T, v, ["leaf", "tesla", "leaf"])


def test_string_stability_flat_dict() -> None:
    v = sine_platoon([1.2, 1.2])
    gaps = np.full((2, T.size), 30.0)
    m = string_stability(T, v, gaps, ["leaf"] * 3)
    assert m["amp_lead_last_speed_rms"] == pytest.approx(1.44, rel=1e-3)
    assert m["amp_0_1_speed_rms"] == pytest.approx(1.2, rel=1e-3)
    assert m["gain_2_mean"] == pytest.approx(1.2, rel=0.02)
    assert m["min_gap_2_m"] == 30.0
    assert m["energy_total_kj"] > 0 and m["fuel_total_g"] == 0
