from __future__ import annotations

import pytest

from agent_client.controllers.acc import AccController, LateClosing, force_of_accel
from agent_client.drive import drive_episode
from agent_client.launcher import local_server
from agent_client.session import Session

SET = 20.0  # [m/s] a set speed below the catch-up leads (24-30 m/s)


@pytest.fixture(scope="module")
def server():
    with local_server() as addr:
        yield addr


def test_force_of_accel_inverts_the_force_map():
    assert force_of_accel(3.5) == 1.0 and force_of_accel(-5.5) == -1.0
    assert force_of_accel(1.75) == pytest.approx(0.5) and force_of_accel(-2.75) == pytest.approx(-0.5)
    assert force_of_accel(99.0) == 1.0 and force_of_accel(-99.0) == -1.0


def test_eq_1_to_3_while_following():
    acc = AccController()
    obs = {"gap": 60.0, "v_host": 30.0, "v_lead": 31.0, "a_lead": -1.0, "set_speed": 40.0}
    a_ref = 0.23 * (60.0 - 1.8 * 30.0) + 0.07 * 1.0  # eq. 1 with d_ref = v t_gap (eq. 2)
    assert acc(obs) == pytest.approx(a_ref / 3.5)
    assert acc.reference_gap(1.0) == 5.0  # d_safe at low speed (eq. 3)


def test_late_closing_follows_the_closing_speed_through_a_first_order_lag():
    law = AccController(fixed_gap=55.0, beta=0.3, gamma=1.5, decel_cap=3.0)
    late = LateClosing(law, lag=0.5, dt=0.1)
    obs = {"gap": 56.0, "v_host": 30.0, "v_lead": 30.0, "a_lead": 0.0, "set_speed": 40.0}
    assert late(obs) == law(obs)  # the first call of an episode sees the closing speed as it is
    faster = {**obs, "v_lead": 31.0}  # the lead speeds up by 1 m/s: closing 0 -> -1
    seen = 0.0 + 0.2 * (-1.0 - 0.0)  # dt / lag of the step
    assert late(faster) == pytest.approx((0.3 * 1.0 + 1.5 * -seen) / 3.5)
    seen += 0.2 * (-1.0 - seen)
    assert late(faster) == pytest.approx((0.3 * 1.0 + 1.5 * -seen) / 3.5)
    assert late(faster) < law(faster)  # still answering less than the whole change
    late.reset()
    assert late(faster) == law(faster)  # a new episode sees it as it is again
    with pytest.raises(ValueError, match="lag"):
        LateClosing(law, lag=0.0, dt=0.1)


def test_late_closing_brakes_for_a_standing_car_on_the_true_speeds():
    law = AccController(fixed_gap=55.0, beta=0.3, gamma=1.5, decel_cap=3.0)
    late = LateClosing(law, lag=0.5, dt=0.1)
    late({"gap": 60.0, "v_host": 20.0, "v_lead": 20.0, "a_lead": 0.0})  # following, closing 0
    stopped = {"gap": 40.0, "v_host": 20.0, "v_lead": 0.0, "a_lead": 0.0}  # then a standing car 40 m ahead
    assert late(stopped) == law(stopped) == force_of_accel(-(20.0**2) / (2 * (40.0 - law.d_safe)))
    assert law(stopped, seen_closing=1.0) == law(stopped)  # the limit binds, whatever the following term sees


def test_collision_avoidance_limit_engages_only_when_closing_fast():
    acc = AccController()
    calm = {"gap": 50.0, "v_host": 31.0, "v_lead": 30.0, "a_lead": -2.0, "set_speed": 33.5}  # 48 s to reach d_min
    assert acc(calm) == pytest.approx(force_of_accel(0.23 * (50 - 1.8 * 31) + 0.07 * -1.0))
    urgent = {"gap": 12.0, "v_host": 9.0, "v_lead": 6.0, "a_lead": -1.5, "set_speed": 33.5}  # 3 s to reach d_min
    a_safe = -1.5 - 3.0**2 / (2 * (12.0 - 3.0))  # aims at d_min = 3 m
    assert acc(urgent) == pytest.approx(force_of_accel(a_safe))


@pytest.mark.parametrize("scenario", ["ice", "ev"])
def test_no_collision_on_the_test_trajectories(scenario):
    with local_server() as addr, Session(addr) as s:
        for traj in ("test-1", "test-2", "test-3", "test-4"):
            summary = drive_episode(s, AccController(), scenario=scenario, seed=0, trajectory=traj)
            assert not summary.collision, traj
            assert summary.reason == "end" and summary.sim_time == pytest.approx(240.0)


def test_set_speed_caps_the_command_in_speed_control_mode():
    acc = AccController()
    far = {"gap": 250.0, "v_host": 25.0, "v_lead": 30.0, "a_lead": 0.0, "set_speed": 30.0}
    assert acc(far) == pytest.approx(force_of_accel(0.4 * (30.0 - 25.0)))  # SUMO's speed-control gain
    at_set = {**far, "v_host": 30.0}
    assert acc(at_set) == 0.0
    assert acc({**far, "set_speed": 40.0}) == 1.0  # the gap law wants more than full throttle


def test_cruises_at_the_set_speed_when_the_lead_is_far(server):
    speeds: list[float] = []
    with Session(server) as s:
        summary = drive_episode(
            s, AccController(), scenario="ev", seed=0, trajectory="catch-up", set_speed=SET,
            on_step=lambda obs: speeds.append(obs["v_host"]),
        )  # fmt: skip
    assert not summary.collision
    assert max(speeds) <= SET
    # 10 s after the start it cruises at the set speed while the lead pulls away.
    assert speeds[100:] == pytest.approx([SET] * len(speeds[100:]), abs=0.05)


@pytest.mark.parametrize("seed", range(3))
def test_stops_d_safe_behind_a_stopped_car(server, seed):
    last: list[dict] = []
    with Session(server) as s:
        summary = drive_episode(s, AccController(), scenario="ev", seed=seed, trajectory="stopped", on_step=last.append)
    assert not summary.collision and last[-1]["v_host"] == 0.0
    # It comes to rest at its standstill distance d_safe = 5 m (it stopped 1.9 m short before).
    assert last[-1]["gap"] == pytest.approx(AccController().d_safe, abs=0.5)


@pytest.mark.parametrize("seed", range(3))
def test_keeps_clear_of_a_much_slower_lead(server, seed):
    with Session(server) as s:
        summary = drive_episode(s, AccController(), scenario="ice", seed=seed, trajectory="slow-lead")
    assert not summary.collision and summary.gap_min >= 2.0  # the safety suite's minimum gap
