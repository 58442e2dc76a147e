from __future__ import annotations

import numpy as np
import pytest

from agent_client.rewards import force_reward, force_term, gap_reward, gap_term


def test_gap_term_breakpoints():
    assert gap_term(0.0) == -10.0
    assert gap_term(-3.0) == -10.0  # overlap after a collision
    assert gap_term(30.0) == pytest.approx(0.0)
    assert gap_term(55.0) == pytest.approx(10.0)
    assert gap_term(80.0) == pytest.approx(0.0)
    assert gap_term(300.0) == pytest.approx(-5.0)
    assert gap_term(1000.0) == pytest.approx(-5.0)


def test_gap_term_shape():
    g = np.linspace(0, 300, 3001)
    r = np.array([gap_term(x) for x in g])
    assert g[np.argmax(r)] == pytest.approx(55.0)
    assert np.all(np.diff(r[g <= 55]) > 0) and np.all(np.diff(r[g >= 55]) < 0)
    positive = g[r > 0]
    assert positive.min() == pytest.approx(30.0, abs=0.2) and positive.max() == pytest.approx(80.0, abs=0.2)


def test_force_triangle():
    assert force_term(0.0) == 10.0
    assert force_term(0.15) == pytest.approx(5.0) == force_term(-0.15)
    assert force_term(0.3) == 0.0 and force_term(-1.0) == 0.0


@pytest.mark.parametrize("fn", [gap_reward, force_reward])
def test_normalised_to_unit_interval(fn):
    for g in np.linspace(-5, 400, 200):
        for u in np.linspace(-1, 1, 21):
            assert -1.0 <= fn(g, u) <= 1.0
    assert fn(55.0, 0.0) == pytest.approx(1.0)


def test_gap_reward_ignores_force_and_force_reward_does_not():
    assert gap_reward(50.0, 0.0) == gap_reward(50.0, 1.0)
    assert force_reward(50.0, 0.0) > force_reward(50.0, 0.5)
    assert force_reward(55.0, 1.0) == pytest.approx(0.5)


def test_eco_energy_term_is_the_energy_models_rate_over_full_throttle():
    from agent_client.rewards import FUEL_FULL, POWER_FULL, energy_term
    from energy.cmem import COROLLA_2022, cmem_rates
    from energy.ev import eq6_power_kw

    v, a = np.array([30.0]), np.array([0.0])
    assert energy_term(30.0, 0.0, "ice") == pytest.approx(cmem_rates(v, a, COROLLA_2022).fuel_g_s[0] / FUEL_FULL)
    assert energy_term(30.0, 0.0, "ev") == pytest.approx(eq6_power_kw(v, a)[0] / POWER_FULL)
    assert energy_term(30.0, 3.5, "ice") == pytest.approx(1.0, abs=0.01)  # full throttle at 30 m/s
    assert energy_term(30.0, -3.0, "ice") == 0.0  # fuel cut while braking
    assert energy_term(30.0, -3.0, "ev") < 0.0  # regeneration
    assert 0.0 < energy_term(30.0, 0.0, "ice") < energy_term(30.0, 1.0, "ice") < energy_term(30.0, 3.5, "ice")


def test_eco_comfort_term_is_the_jerk_over_one_period():
    from agent_client.rewards import JERK_FULL, comfort_term

    assert comfort_term(1.0, 1.0) == 0.0
    assert comfort_term(1.0, 0.0) == pytest.approx(1.0 / 0.1 / JERK_FULL)  # 10 m/s^3
    assert comfort_term(-5.5, 3.5) == 1.0  # bang-bang: capped


def test_eco_reward_prefers_the_smooth_economical_step_at_the_same_gap():
    from agent_client.rewards import ECO_WEIGHTS, eco_reward, gap_term, make_reward

    smooth = eco_reward(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0)
    assert eco_reward(55.0, 1.0, v=30.0, a=3.5, a_prev=0.0) < smooth  # burns fuel and jerks
    assert eco_reward(55.0, 0.0, v=30.0, a=0.0, a_prev=-3.0) < smooth  # jerks
    assert eco_reward(20.0, 0.0, v=30.0, a=0.0, a_prev=0.0) < smooth  # too close
    for gap, a, a_prev in ((0.0, 3.5, -5.5), (55.0, -3.0, -3.0), (300.0, 3.5, 3.5)):
        for scenario in ("ice", "ev"):
            assert -1.0 <= eco_reward(gap, 0.0, v=30.0, a=a, a_prev=a_prev, scenario=scenario) <= 1.0
    assert smooth == pytest.approx((gap_term(55.0) / 10 - ECO_WEIGHTS[1] * 1.1778 / 19.1) / sum(ECO_WEIGHTS), rel=1e-3)
    ev = make_reward("eco", "ev")
    assert ev(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0) != smooth  # the EV's own energy model
    with pytest.raises(ValueError, match="reward 'speed'"):
        make_reward("speed", "ice")


def test_eco_closing_term_penalises_a_speed_difference_to_the_lead_either_way():
    from agent_client.rewards import (
        CLOSING_FULL,
        ECO_WEIGHTS,
        closing_term,
        eco_reward,
        make_reward,
    )

    assert closing_term(30.0, 30.0) == 0.0
    assert closing_term(30.0, 30.0 + CLOSING_FULL / 2) == closing_term(30.0, 30.0 - CLOSING_FULL / 2) == 0.5
    assert closing_term(30.0, 0.0) == 1.0  # saturates
    matched = eco_reward(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0, v_lead=30.0)
    closing = eco_reward(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0, v_lead=25.0)
    assert closing == pytest.approx(matched - ECO_WEIGHTS[3] / sum(ECO_WEIGHTS))
    assert eco_reward(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0) == matched  # no lead speed given: no closing term
    # the weights reach the reward; a zero closing weight turns the term off
    off = make_reward("eco", "ice", (1.0, 0.5, 0.25, 0.0))
    assert off(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0, v_lead=25.0) == off(55.0, 0.0, v=30.0, a=0.0, a_prev=0.0, v_lead=30.0)
    with pytest.raises(ValueError, match="needs 4 weights"):
        make_reward("eco", "ice", (1.0, 0.5))
