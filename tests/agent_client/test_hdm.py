"""The Human Driver Model (Treiber et al. 2006): gap keeping, reaction delay, seeding."""

from __future__ import annotations

import numpy as np
import pytest

from agent_client.controllers.hdm import NAME, HdmParams, HumanDriverModel, idm_accel
from agent_client.drive import DESIRED_GAP, drive_episode
from agent_client.launcher import local_server
from agent_client.session import Session


def _obs(t: float, gap: float, v: float, v_lead: float, accel: float = 0.0) -> dict[str, float]:
    return {"t": t, "gap": gap, "v_host": v, "v_lead": v_lead, "accel": accel}


@pytest.fixture(scope="module")
def server():
    with local_server() as addr:
        yield addr


def _drive(addr, controller, trajectory="test-1", tmp_path=None):
    log = None if tmp_path is None else tmp_path / f"{trajectory}.csv"
    with Session(addr) as session:
        forces: list[float] = []
        a_lead: list[float] = []

        def record(obs):
            u = controller(obs)
            forces.append(u)
            a_lead.append(obs["a_lead"])
            return u

        record.reset = controller.reset  # type: ignore[attr-defined]
        summary = drive_episode(session, record, scenario="ice", seed=0, trajectory=trajectory, log=log)
    return summary, np.array(a_lead), np.array(forces)


def test_name_is_a_model_not_data():
    assert NAME == "Human Driver Model (Treiber et al. 2006)"
    assert "data" not in NAME.lower()


def test_idm_equilibrium_gap_near_desired_at_30_mps():
    # Defaults are chosen so the IDM's equilibrium gap at the ICE lead's mean speed
    # is the paper's 55 m: the acceleration there is ~0.
    p = HdmParams()
    assert idm_accel(p, 55.8, 30.0, 0.0) == pytest.approx(0.0, abs=0.02)
    assert idm_accel(p, 40.0, 30.0, 0.0) < 0.0 < idm_accel(p, 70.0, 30.0, 0.0)


@pytest.mark.parametrize("trajectory", ["test-1", "test-2", "test-3", "test-4"])
def test_hdm_keeps_a_plausible_gap_without_collision(server, trajectory):
    summary, _, forces = _drive(server, HumanDriverModel(seed=0), trajectory)
    assert summary.reason == "end" and not summary.collision
    assert summary.steps == 2400  # the whole 4 min test trajectory
    assert summary.gap_min > 20.0  # [m] never closer than the (27.7 m) start
    assert summary.gap_rmse < 15.0  # [m] vs 55 m; the paper's humans: 6.59 m
    assert np.all(np.abs(forces) <= 1.0)


def test_reaction_time_shows_as_force_lag_on_a_real_run(server):
    """The force follows the lead's acceleration about one reaction time later than with none."""

    def lag(reaction_time: float) -> float:
        _, a_lead, u = _drive(server, HumanDriverModel(HdmParams(reaction_time=reaction_time), seed=0))
        a, u = a_lead[300:] - a_lead[300:].mean(), u[300:] - u[300:].mean()  # skip the start transient
        lags = np.arange(40)  # [steps] of 0.1 s
        cc = [float(np.dot(a[: len(a) - k], u[k:])) for k in lags]
        return 0.1 * float(lags[int(np.argmax(cc))])

    assert lag(1.0) - lag(0.0) == pytest.approx(1.0, abs=0.35)


def test_reaction_delay_on_a_lead_speed_step():
    """A step in the lead's speed at t = 10 s moves the force exactly T' = 1 s later."""
    hdm = HumanDriverModel(HdmParams(errors=False), seed=0)
    forces = []
    for k in range(200):
        t = 0.1 * k
        v_lead = 30.0 if t < 10.0 - 1e-9 else 25.0
        forces.append(hdm(_obs(t, 55.8, 30.0, v_lead)))
    forces = np.array(forces)
    assert np.all(forces[:110] == forces[0])  # t < 11 s: still acting on what it saw before 10 s
    assert forces[110] < forces[0] - 0.05  # t = 11 s: brakes for the slower lead


def test_no_delay_reacts_at_once():
    hdm = HumanDriverModel(HdmParams(errors=False, reaction_time=0.0), seed=0)
    f = [hdm(_obs(0.1 * k, 55.8, 30.0, 30.0 if k < 100 else 25.0)) for k in range(102)]
    assert f[100] < f[99] - 0.05


def test_seeded_and_reset_repeats():
    obs = [_obs(0.1 * k, 50.0 + np.sin(k / 7), 30.0, 30.0 + np.cos(k / 9)) for k in range(300)]
    a, b, c = HumanDriverModel(seed=3), HumanDriverModel(seed=3), HumanDriverModel(seed=4)
    fa, fb, fc = [a(o) for o in obs], [b(o) for o in obs], [c(o) for o in obs]
    assert fa == fb and fa != fc
    a.reset()
    assert [a(o) for o in obs] == fa


def test_estimation_errors_are_correlated_unit_variance():
    """The Wiener (OU) processes: unit stationary variance, correlation time tau~ = 20 s."""
    hdm = HumanDriverModel(seed=1)
    w = []
    for _ in range(100_000):
        hdm._advance_errors(0.1)
        w.append(hdm._w_s)
    w = np.array(w)
    assert w.var() == pytest.approx(1.0, abs=0.25)
    lag = 200  # steps = 20 s = tau~: autocorrelation exp(-1)
    r = np.corrcoef(w[:-lag], w[lag:])[0, 1]
    assert r == pytest.approx(np.exp(-1.0), abs=0.15)
    assert DESIRED_GAP == 55.0
