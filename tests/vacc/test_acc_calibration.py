"""The array ACC is the controller, the replay is the platoon, and the fit finds known gains."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agent_client.controllers.acc import AccController
from energy.openacc import read_openacc
from protocol.force import accel_of_force
from vacc.acc_calibration import acc_accel, fit_follower, replay_spacing
from vacc.platoon_sim import lead_profile, simulate_platoon


def test_array_law_is_the_controller() -> None:
    rng = np.random.default_rng(0)
    n = 2000
    gap, v = rng.uniform(0.5, 80.0, n), rng.uniform(0.0, 35.0, n)
    v_lead, a_lead = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.0, 35.0, n)), rng.uniform(-5.0, 3.0, n)
    beta, gamma, t_gap = rng.uniform(0.01, 1.0, n), rng.uniform(0.0, 1.5, n), rng.uniform(0.3, 3.0, n)
    got = acc_accel(gap, v, v_lead, a_lead, beta, gamma, t_gap)
    want = [
        accel_of_force(AccController(beta=b, gamma=g, t_gap=tg)({"gap": s, "v_host": vh, "v_lead": vl, "a_lead": al, "set_speed": 33.5}))
        for s, vh, vl, al, b, g, tg in zip(gap, v, v_lead, a_lead, beta, gamma, t_gap, strict=True)
    ]
    assert got == pytest.approx(np.array(want), abs=1e-9)


def test_replay_is_the_platoon_simulation() -> None:
    t = np.arange(0.0, 120.0, 0.1)
    v_lead = 9.0 + 2.0 * np.sin(2 * np.pi * t / 30.0)
    law = AccController(beta=0.3, gamma=0.2, t_gap=1.2)
    run = simulate_platoon(lead_profile(t, v_lead, t[-1] - t[0]), [law], 12.0, v0=9.0)
    gaps = replay_spacing(v_lead, 12.0, 9.0, np.array([0.3]), np.array([0.2]), np.array([1.2]))
    assert gaps[0] == pytest.approx(run.gaps[0], abs=1e-9)


@pytest.mark.parametrize("truth", [(0.2, 0.3, 1.4), (0.05, 0.8, 1.0)])
def test_fit_recovers_known_gains(truth: tuple[float, float, float]) -> None:
    """A follower made by the ACC itself behind a real leader: the fit finds its gains."""
    real = read_openacc("short_setting_dynamic_part10.csv")
    n = 1000
    v_lead = real.speed[0, :n]
    ivs = replay_spacing(v_lead, real.ivs[0, 0], real.speed[1, 0], *(np.array([x]) for x in truth))[0]
    speed = real.speed[:2, :n].copy()
    made = dataclasses.replace(real, t=real.t[:n], speed=speed, ivs=ivs[None, :])
    fit = fit_follower(made, 1)
    assert fit.rmse_m < 0.01
    assert (fit.beta, fit.gamma, fit.t_gap) == pytest.approx(truth, rel=0.01)


def test_calibrated_acc_reproduces_a_real_follower() -> None:
    fit = fit_follower(read_openacc("long_setting_dynamic_part19.csv"), 4)
    assert fit.vehicle == "BMW_I3"
    assert fit.rmse_m < 2.0  # measured 0.99 m over 145 s (beta 0.076, gamma 0.100, t_gap 2.34 s)


def test_fit_refuses_a_follower_that_is_not_there() -> None:
    with pytest.raises(ValueError, match="followers 1..3"):
        fit_follower(read_openacc("short_setting_dynamic_part10.csv"), 4)
