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


@pytest.mark.parametrize("weights", [None, (0.7, 0.3, 0.11, 0.9), (1.0, 0.0, 0.0, 0.0)])
@pytest.mark.parametrize("scenario", ["ice", "ev"])
def test_reward_terms_sum_to_the_reward(scenario, weights):
    import math

    from agent_client.rewards import ECO_WEIGHT_NAMES, REWARDS, make_reward, make_reward_terms

    extra = {} if weights is None else {"eco_weights": weights}
    names = {"gap": {"gap"}, "force": {"gap", "force"}, "eco": set(ECO_WEIGHT_NAMES), "eco-draw": set(ECO_WEIGHT_NAMES)}
    rng = np.random.default_rng(1)
    for name in REWARDS:
        fn, terms_fn = make_reward(name, scenario, **extra), make_reward_terms(name, scenario, **extra)
        for _ in range(300):
            gap, u = float(rng.uniform(-5, 350)), float(rng.uniform(-1, 1))
            kw = {"v": float(rng.uniform(0, 35)), "a": float(rng.uniform(-5.5, 3.5)), "a_prev": float(rng.uniform(-5.5, 3.5))}
            if rng.random() < 0.8:
                kw["v_lead"] = float(rng.uniform(0, 35))
            terms = terms_fn(gap, u, **kw)
            assert set(terms) == names[name]
            assert math.fsum(terms.values()) == pytest.approx(fn(gap, u, **kw), rel=1e-12, abs=1e-15)
    with pytest.raises(ValueError, match="reward 'speed'"):
        make_reward_terms("speed", scenario)
    with pytest.raises(ValueError, match="needs 4 weights"):
        make_reward_terms("eco", scenario, (1.0, 0.5))


def test_eco_terms_are_the_single_terms_signed_by_the_eco_reward():
    from agent_client.rewards import (
        closing_term,
        comfort_term,
        eco_desired_gap,
        eco_reward_terms,
        eco_terms,
        energy_term,
    )

    t = eco_terms(40.0, v=20.0, a=1.0, a_prev=-0.5, v_lead=22.0, scenario="ev")
    assert t.gap == gap_term(40.0, eco_desired_gap(20.0))
    assert t.energy == energy_term(20.0, 1.0, "ev") and t.comfort == comfort_term(1.0, -0.5) and t.closing == closing_term(20.0, 22.0)
    assert eco_terms(40.0, v=20.0, a=1.0, a_prev=-0.5).closing == 0.0  # no lead speed: no closing term
    w = eco_reward_terms(40.0, 0.0, v=20.0, a=1.0, a_prev=-0.5, v_lead=22.0, scenario="ev", weights=(1.0, 1.0, 1.0, 1.0))
    assert w == pytest.approx({"gap": t.gap / 40, "energy": -t.energy / 4, "comfort": -t.comfort / 4, "closing": -t.closing / 4})


def test_reward_ablation_scores_a_log_as_the_eco_reward_pays_it(tmp_path):
    # scripts/reward_ablation.py reads run logs (no env runs there): its mean terms under a
    # weighting are the mean eco reward those rows would have been paid.
    import importlib.util
    from pathlib import Path

    from agent_client.rewards import ECO_WEIGHTS, make_reward

    spec = importlib.util.spec_from_file_location("reward_ablation", Path(__file__).resolve().parents[2] / "scripts" / "reward_ablation.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    rows = [(30.0, 29.0, 40.0, 0.0), (30.2, 28.5, 39.0, 2.0), (30.1, 28.0, 37.5, -1.0), (29.5, 28.0, 36.0, -3.0)]
    log = tmp_path / "acc-1.csv"
    log.write_text("v_host,v_lead,gap,accel\n" + "".join(f"{v},{vl},{g},{a}\n" for v, vl, g, a in rows))
    for scenario in ("ice", "ev"):
        for w in (ECO_WEIGHTS, (1.0, 1.0, 0.0, 0.5)):
            fn, paid, a_prev = make_reward("eco", scenario, w), [], 0.0
            for v, vl, g, a in rows[1:]:  # the first row is the reset's: no reward
                paid.append(fn(g, 0.0, v=v, a=a, a_prev=a_prev, v_lead=vl))
                a_prev = a
            assert float(np.dot(script.mean_terms(log, scenario), w) / sum(w)) == pytest.approx(np.mean(paid), rel=1e-12)


def test_eco_draw_pays_the_ev_nothing_for_regenerating_and_is_eco_elsewhere():
    """eco-draw: a regenerating brake earns the EV nothing (the energy term is 0, not
    negative); drawing power costs as in eco, and the ICE's reward is eco's to the bit."""
    from agent_client.rewards import make_reward, make_reward_terms

    kw = {"v": 30.0, "a_prev": 0.0, "v_lead": 29.0}
    eco, draw = make_reward("eco", "ev"), make_reward("eco-draw", "ev")
    braking, cruising = {**kw, "a": -2.0}, {**kw, "a": 0.5}
    assert draw(50.0, -0.5, **braking) < eco(50.0, -0.5, **braking)  # eco pays the regeneration
    assert make_reward_terms("eco-draw", "ev")(50.0, -0.5, **braking)["energy"] == 0.0
    assert draw(50.0, 0.2, **cruising) == eco(50.0, 0.2, **cruising)
    terms = make_reward_terms("eco-draw", "ev")(50.0, -0.5, **braking)
    assert sum(terms.values()) == pytest.approx(draw(50.0, -0.5, **braking))
    for a in (-3.0, -1.0, 0.0, 1.0, 3.0):
        step = {**kw, "a": a}
        assert make_reward("eco-draw", "ice")(48.0, 0.1, **step) == make_reward("eco", "ice")(48.0, 0.1, **step)
    with pytest.raises(ValueError, match="eco weights"):
        make_reward("eco-draw", "ev", (0.0, 1.0, 1.0, 1.0))
