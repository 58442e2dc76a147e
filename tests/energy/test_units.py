from __future__ import annotations

import pytest

from energy import units


def test_speed_conversions() -> None:
    assert units.mph_to_mps(60.0) == pytest.approx(26.8224)
    assert units.mps_to_mph(26.8224) == pytest.approx(60.0)
    assert units.mps_to_kmh(10.0) == pytest.approx(36.0)


def test_mass_force_distance() -> None:
    assert units.lb_to_kg(3375.0) == pytest.approx(1530.87, abs=0.01)
    assert units.lbf_to_n(1.0) == pytest.approx(4.44822, rel=1e-6)
    assert units.m_to_mi(1609.344) == pytest.approx(1.0)


def test_road_load_to_si() -> None:
    a, b, c = units.road_load_to_si(27.071, 0.26485, 0.017466)
    assert a == pytest.approx(27.071 * 4.44822, rel=1e-5)
    assert b == pytest.approx(0.26485 * 4.44822 / 0.44704, rel=1e-5)
    assert c == pytest.approx(0.017466 * 4.44822 / 0.44704**2, rel=1e-5)
    # the SI polynomial gives the same force as the EPA one at 50 mph
    v = units.mph_to_mps(50.0)
    f_epa = (27.071 + 0.26485 * 50 + 0.017466 * 50**2) * 4.44822
    assert a + b * v + c * v**2 == pytest.approx(f_epa, rel=1e-5)


def test_specific_energy_and_mass() -> None:
    assert units.g_per_m_to_g_per_mi(0.1) == pytest.approx(160.9344)
    assert units.j_per_m_to_kj_per_mi(1000.0) == pytest.approx(1609.344)
    assert units.j_per_m_to_wh_per_mi(3600.0) == pytest.approx(1609.344)
    assert units.kj_to_wh(3.6) == pytest.approx(1.0)


def test_label_figures() -> None:
    # 2012 Leaf label: 34 kWh/100 mi is 99 MPGe combined
    assert units.wh_per_mi_to_mpge(340.0) == pytest.approx(99.1, abs=0.1)
    assert units.mpg_from_co2_g_per_mi(8887.0 / 50.0) == pytest.approx(50.0)


def test_mpg_of_a_run_that_burns_nothing_is_infinite():
    """A short run spent braking or coasting has zero CO2; its economy is inf, not a crash."""
    import math

    assert units.mpg_from_co2_g_per_mi(0.0) == math.inf
