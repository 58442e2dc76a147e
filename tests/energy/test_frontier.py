"""The preview frontier: the least-energy trace behind a known lead, on hand-made leads."""

from __future__ import annotations

import numpy as np
import pytest

from energy import TraceError
from energy.ev import eq6_per_mile
from energy.frontier import preview_bound

DT = 0.1


def _lead(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(len(v)) * DT
    x = 55.0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * DT)])
    return t, x


def test_behind_a_steady_lead_it_holds_the_leads_speed_or_saves_by_dropping_back():
    v = np.full(601, 25.0)
    t, x = _lead(v)
    holding = eq6_per_mile(t, v).energy_kj_per_mi
    tight = preview_bound(t, x, 25.0, 55.0, 25.0, lam=10.0)
    np.testing.assert_allclose(tight.v, 25.0, atol=0.02)
    assert tight.gap_rmse_m < 0.1 and tight.energy_kj_per_mi == pytest.approx(holding, rel=1e-4)
    # eq. 6 spends less per mile at a lower speed, so a loose weight drops back a little
    loose = preview_bound(t, x, 25.0, 55.0, 25.0, lam=0.01)
    assert loose.energy_kj_per_mi < holding and loose.v.min() < 25.0 and loose.gap_rmse_m > tight.gap_rmse_m


@pytest.mark.slow  # over ~5 s alone
def test_a_heavier_gap_weight_trades_energy_for_a_smaller_gap_error():
    rng = np.random.default_rng(0)
    a = np.repeat(rng.normal(0.0, 0.8, 60), 20)[:1200]  # a lead that speeds up and slows down every 2 s
    v = np.clip(22.0 + np.concatenate([[0.0], np.cumsum(a) * DT]), 5.0, 35.0)
    t, x = _lead(v)
    points = [preview_bound(t, x, v[0], 55.0, v[-1], lam) for lam in (0.001, 0.01, 0.1, 1.0)]
    rmse = [p.gap_rmse_m for p in points]
    energy = [p.energy_kj_per_mi for p in points]
    assert rmse == sorted(rmse, reverse=True) and energy == sorted(energy)
    assert energy[0] < eq6_per_mile(t, v).energy_kj_per_mi  # smoothing the lead's swings saves energy
    assert rmse[-1] < 0.5  # and a heavy weight follows it closely
    for p in points:
        assert p.v[0] == v[0] and p.v[-1] == v[-1]


@pytest.mark.slow  # over ~5 s alone
def test_behind_a_lead_that_stops_the_trace_stops_and_never_reverses():
    v = np.concatenate([np.linspace(20.0, 0.0, 101), np.zeros(300), np.linspace(0.0, 10.0, 101)])
    t, x = _lead(v)
    p = preview_bound(t, x, 20.0, 55.0, 10.0, lam=0.001)
    assert p.v.min() >= 0.0
    assert (p.v == 0.0).any()


@pytest.mark.parametrize(
    ("t", "lam", "match"),
    [(np.array([0.0, 0.1]), 0.01, "3 samples"), (np.array([0.0, 0.1, 0.3]), 0.01, "evenly"), (np.array([0.0, 0.1, 0.2]), 0.0, "> 0")],
)
def test_bad_input_is_refused_with_what_was_wrong(t, lam, match):
    with pytest.raises(TraceError, match=match):
        preview_bound(t, np.linspace(55.0, 60.0, len(t)), 20.0, 55.0, 20.0, lam)
