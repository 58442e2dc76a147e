"""Lead scenarios, custom traces, initial conditions and the set-speed limiter, in the world."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.scenarios import (
    DEFAULT_SET_SPEED,
    LEAD_SCENARIOS,
    STOP_MARGIN,
    TRACE_ACCEL_LIMIT,
    TRACE_MAX_SAMPLES,
    stopping_gap,
)
from sim_server import scenarios as S
from sim_server import trajectory as T
from sim_server.errors import InitialConditionError, TrajectoryError
from sim_server.vehicle import A_MIN
from sim_server.world import World

DT = 0.02  # [s]
NAMES = list(LEAD_SCENARIOS)


def drive(world: World, actions, **reset):
    states = [world.reset(**reset)]
    for u in actions:
        if states[-1].terminated or states[-1].truncated:
            break
        states.append(world.step(u))
    return states


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("scenario", ["ice", "ev"])
def test_same_seed_same_episode_bit_for_bit(name, scenario):
    actions = np.random.default_rng(1).uniform(-1, 1, 150)
    a = drive(World(), actions, scenario=scenario, seed=3, trajectory=name)
    b = drive(World(), actions, scenario=scenario, seed=3, trajectory=name)
    assert a == b
    c = drive(World(), actions, scenario=scenario, seed=4, trajectory=name)
    assert a != c


@pytest.mark.parametrize("name", NAMES)
def test_seed_draws_every_parameter_within_its_range(name):
    spec = LEAD_SCENARIOS[name]
    seen = {p.name: set() for p in spec.params}
    for seed in range(30):
        ep = S.build(name, np.random.default_rng(seed), DT)
        again = S.build(name, np.random.default_rng(seed), DT)
        np.testing.assert_array_equal(ep.v_lead, again.v_lead)
        assert (ep.v_host, ep.gap, ep.params) == (again.v_host, again.gap, again.params)
        assert len(ep.v_lead) == round(spec.duration / DT) + 1
        assert ep.v_lead.min() >= 0.0 and ep.v_host >= 0.0 and ep.gap > 0.0
        # The lead never brakes harder than Euro NCAP's 6 m/s^2 nor pulls away faster than 2 m/s^2.
        a = np.diff(ep.v_lead) / DT
        assert a.min() >= -6.0 - 1e-6 and a.max() <= 2.0 + 1e-6
        for key, value in ep.params.items():
            p = spec.param(key)
            assert p.low <= value <= p.high, (key, value)
            seen[key].add(value)
    assert all(len(values) > 1 for values in seen.values())  # the seed really draws them


def test_both_vehicles_get_the_same_lead():
    # Lead scenarios sit outside Table 2's bands: the ICE car gets no 27-33 m/s clipping.
    ice, ev = World(), World()
    ice.reset("ice", 5, "stop-and-go")
    ev.reset("ev", 5, "stop-and-go")
    np.testing.assert_array_equal(ice.v_lead_profile, ev.v_lead_profile)
    assert ice.v_lead_profile.min() == 0.0 < T.LIMITS["ice"].v_min


@pytest.mark.parametrize("seed", range(10))
def test_stopped_car_can_be_stopped_for_at_full_brake(seed):
    world = World()
    s0 = world.reset("ev", seed, "stopped")
    assert s0.v_lead == 0.0 and s0.gap >= stopping_gap(s0.v_host)
    # One control period of reaction, then full brake: the host stops STOP_MARGIN short.
    states = drive(world, [0.0] + [-1.0] * 100, scenario="ev", seed=seed, trajectory="stopped")
    assert not any(s.collision for s in states)
    assert states[-1].v_host == 0.0 and states[-1].gap >= STOP_MARGIN - 0.2


def test_stopping_is_possible_over_the_whole_documented_ranges():
    stopped = LEAD_SCENARIOS["stopped"]
    assert stopping_gap(stopped.param("v_host").high) <= stopped.param("gap").high
    slow = LEAD_SCENARIOS["slow-lead"]
    assert stopping_gap(slow.param("v_host").high - slow.param("v_lead").low) <= slow.param("gap").high
    cut = LEAD_SCENARIOS["cut-in"]
    assert stopping_gap(cut.param("speed_deficit").high) <= cut.param("gap").high
    closing = LEAD_SCENARIOS["closing"]
    assert closing.param("margin").low > 1.0
    assert closing.param("v_lead").high + closing.param("closing_speed").high <= DEFAULT_SET_SPEED
    for seed in range(50):
        for name in ("slow-lead", "cut-in"):
            ep = S.build(name, np.random.default_rng(seed), DT)
            assert ep.gap >= stopping_gap(ep.v_host - ep.v_lead[0]), (name, seed)
    assert stopping_gap(16.0) == pytest.approx(1.6 + 16.0**2 / (2 * -A_MIN) + 2.0)


@pytest.mark.parametrize("seed", range(10))
def test_a_car_cutting_in_can_be_fallen_back_from_at_full_brake(seed):
    world = World()
    s0 = world.reset("ice", seed, "cut-in")
    # It starts inside the camera's near field (the mask keeps a lead whole down to about 9 m).
    assert s0.v_lead < s0.v_host and stopping_gap(s0.v_host - s0.v_lead) <= s0.gap <= LEAD_SCENARIOS["cut-in"].param("gap").high
    states = drive(world, [0.0] + [-1.0] * 60, scenario="ice", seed=seed, trajectory="cut-in")
    assert not any(s.collision for s in states)
    assert min(s.gap for s in states) >= STOP_MARGIN - 0.2


@pytest.mark.parametrize("seed", range(10))
def test_a_slower_car_met_late_can_be_stopped_for_only_by_braking_at_once(seed):
    spec = LEAD_SCENARIOS["closing"]
    s0 = World().reset("ev", seed, "closing")
    closing = s0.v_host - s0.v_lead
    assert 0.0 < s0.v_lead < s0.v_host
    assert spec.param("margin").low * stopping_gap(closing) <= s0.gap + 1e-9 <= spec.param("margin").high * stopping_gap(closing) + 1e-9
    # Full brake after one control period: no collision, at least the margin left.
    states = drive(World(), [0.0] + [-1.0] * 60, scenario="ev", seed=seed, trajectory="closing")
    assert not any(s.collision for s in states) and min(s.gap for s in states) >= STOP_MARGIN - 0.2
    # Coasting into it for 1.2 s first collides or ends inside the margin: no room to wait.
    states = drive(World(), [0.0] * 12 + [-1.0] * 60, scenario="ev", seed=seed, trajectory="closing")
    assert any(s.collision for s in states) or min(s.gap for s in states) < STOP_MARGIN


@pytest.mark.parametrize("seed", range(10))
def test_braking_lead_can_be_stopped_for_by_braking_when_it_does(seed):
    world = World()
    obs = world.reset("ice", seed, "brake-stop")
    while not (obs.terminated or obs.truncated):
        obs = world.step(-1.0 if obs.a_lead < 0 or obs.v_lead < obs.v_host else 0.0)
    assert not obs.collision and obs.v_lead == 0.0 and obs.gap >= STOP_MARGIN


def test_scenario_shapes():
    rng = np.random.default_rng
    ep = S.build("brake-stop", rng(0), DT)
    p = ep.params
    t_stop = p["t_brake"] + p["v_cruise"] / p["decel"]
    i = int(round(p["t_brake"] / DT))
    assert ep.v_lead[i] == p["v_cruise"] and ep.v_lead[-1] == 0.0 and ep.v_host == p["v_cruise"]
    assert np.flatnonzero(ep.v_lead == 0.0)[0] * DT == pytest.approx(t_stop, abs=DT)
    ep = S.build("brake-hard", rng(0), DT)
    assert ep.v_lead[-1] == pytest.approx(ep.params["v_cruise"] - ep.params["speed_drop"])
    ep = S.build("cut-in", rng(0), DT)
    assert np.ptp(ep.v_lead) == 0.0 and ep.v_host - ep.v_lead[0] == pytest.approx(ep.params["speed_deficit"])
    ep = S.build("closing", rng(0), DT)
    p = ep.params
    assert np.ptp(ep.v_lead) == 0.0 and ep.v_host - ep.v_lead[0] == pytest.approx(p["closing_speed"])
    assert ep.gap == pytest.approx(p["margin"] * stopping_gap(p["closing_speed"]))
    ep = S.build("catch-up", rng(0), DT)
    assert ep.v_lead[0] - ep.v_host == pytest.approx(ep.params["speed_deficit"]) and np.ptp(ep.v_lead) == 0.0
    ep = S.build("constant", rng(0), DT)
    assert np.ptp(ep.v_lead) == 0.0 and ep.v_host == pytest.approx(ep.v_lead[0] + ep.params["speed_offset"])
    ep = S.build("stop-and-go", rng(0), DT)
    standing = ep.v_lead == 0.0
    stops = np.count_nonzero(standing[1:] & ~standing[:-1])
    starts = np.count_nonzero(~standing[1:] & standing[:-1])
    assert stops >= 3 and starts >= 2 and ep.v_host == ep.v_lead[0] > 0.0


def test_ramp_profile_lands_on_its_targets():
    v = S.ramp_profile(10.0, [(0.0, 2.0, 1.0), (4.0, 1.0, 0.0)], 0.02, 12.0)
    assert len(v) == 601 and v[0] == 10.0
    assert v[250] == 0.0 and v[300] == 0.0 and v[-1] == 4.0  # 5 s down, 1 s standing, 4 s up
    assert np.diff(v).min() == pytest.approx(-0.04) and np.diff(v).max() == pytest.approx(0.02)


def test_unknown_lead_scenario():
    with pytest.raises(TrajectoryError, match="unknown trajectory 'parked'"):
        World().reset("ice", 0, "parked")
    with pytest.raises(TrajectoryError, match="unknown lead scenario"):
        S.build("parked", np.random.default_rng(0), DT)


# -- custom traces -------------------------------------------------------------


def test_trace_is_driven_as_given_not_clipped_to_the_band():
    # A 0-27 m/s cycle used to become a constant 27 m/s lead in the ICE scenario.
    t = np.array([0.0, 10.0, 20.0, 30.0])
    v = np.array([0.0, 15.0, 27.0, 0.0])
    profile = T.build("ice", "trace", np.random.default_rng(0), DT, trace=(t, v))
    np.testing.assert_allclose(profile, np.interp(np.arange(1501) * DT, t, v), atol=1e-12)
    world = World()
    s0 = world.reset("ice", 0, "trace", trace=(t, v))
    assert s0.v_lead == 0.0 and s0.v_host == 0.0  # the host starts at the lead's first speed
    s1 = World().reset("ice", 0, "trace", trace=(t, v), host_speed=12.0, gap=40.0)
    assert s1.v_host == 12.0 and s1.gap == pytest.approx(40.0)


@pytest.mark.parametrize(
    ("t", "v", "words"),
    [
        ([0.0, 1.0], [30.0, 15.0], f"trace samples 0-1 accelerate at -15 m/s^2, beyond the physical limit of +-{TRACE_ACCEL_LIMIT:g} m/s^2"),
        ([0.0, 1.0, 2.0], [0.0, 5.0, 20.0], "trace samples 1-2 accelerate at 15 m/s^2"),
        ([0.0, 100.0], [10.0, 80.0], "trace sample 1 has speed 80 m/s, above the 70 m/s limit"),
        ([0.0, 1.0], [1.0, -1.0], "negative speed"),
    ],
)
def test_trace_a_car_cannot_drive_is_refused_in_one_line(t, v, words):
    with pytest.raises(TrajectoryError, match=words.replace("+", r"\+").replace("^", r"\^")) as err:
        World().reset("ev", 0, "trace", trace=(np.array(t), np.array(v)))
    assert "\n" not in str(err.value)


def test_a_trace_too_long_or_too_many_samples_is_refused_before_resampling():
    import resource
    import time

    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with pytest.raises(TrajectoryError, match="a trace spans at most 14400 s"):
        World().reset("ice", 0, "trace", trace=(np.array([0.0, 1e12]), np.array([10.0, 10.0])))
    n = TRACE_MAX_SAMPLES + 1
    with pytest.raises(TrajectoryError, match=f"at most {TRACE_MAX_SAMPLES} samples; this one has {n}"):
        World().reset("ice", 0, "trace", trace=(np.arange(n, dtype=float), np.full(n, 10.0)))
    assert time.perf_counter() - t0 < 1.0  # the 1e12 s span was never resampled
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss < 10_000  # [KiB]: < 10 MB


# -- initial conditions and set speed ----------------------------------------


@pytest.mark.parametrize("trajectory", ["test-1", "random", "brake-stop"])
def test_host_speed_and_gap_override_only_the_start(trajectory):
    world = World()
    drawn = world.reset("ice", 2, trajectory)
    profile, traffic = world.v_lead_profile.copy(), [b.velocity.x for b, _, _ in world.traffic]
    given = world.reset("ice", 2, trajectory, host_speed=5.0, gap=80.0)
    assert given.v_host == 5.0 and given.gap == pytest.approx(80.0)
    assert given.v_lead == drawn.v_lead
    np.testing.assert_array_equal(world.v_lead_profile, profile)  # same lead, same traffic
    assert [b.velocity.x for b, _, _ in world.traffic] == traffic


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"host_speed": 40.0}, "host speed 40.0 m/s is outside 0..33.5 m/s (the set speed)"),
        ({"host_speed": 20.0, "set_speed": 15.0}, "host speed 20.0 m/s is outside 0..15 m/s"),
        ({"host_speed": -1.0}, "host speed -1.0 m/s"),
        ({"host_speed": float("nan")}, "host speed nan m/s"),
        ({"gap": 0.0}, "gap 0.0 m is outside (0, 300) m"),
        ({"gap": 300.0}, "gap 300.0 m is outside"),
        ({"set_speed": 0.0}, "set speed 0.0 m/s is outside 1..80 m/s"),
        ({"set_speed": 90.0}, "set speed 90.0 m/s"),
        ({"set_speed": float("inf")}, "set speed inf m/s"),
    ],
)
def test_bad_initial_conditions_are_refused_in_one_line(kwargs, words):
    with pytest.raises(InitialConditionError) as err:
        World().reset("ice", 0, "test-1", **kwargs)
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(("trajectory", "set_speed"), [("catch-up", None), ("catch-up", 20.0), ("test-2", 31.0), ("constant", 12.0)])
def test_full_throttle_never_exceeds_the_set_speed(trajectory, set_speed):
    v_set = DEFAULT_SET_SPEED if set_speed is None else set_speed
    world = World()
    states = drive(world, [1.0] * 600, scenario="ice", seed=1, trajectory=trajectory, gap=250.0, set_speed=set_speed)
    assert all(s.set_speed == v_set for s in states)
    assert max(s.v_host for s in states) == v_set  # reached and held, never passed
    assert all(s.v_host <= v_set for s in states)
    reached = next(i for i, s in enumerate(states) if s.v_host == v_set)
    assert all(s.accel == 0.0 for s in states[reached + 1 :])  # the limiter cuts the throttle


def test_drawn_host_speed_above_the_set_speed_starts_at_it():
    s = World().reset("ice", 0, "test-1", set_speed=20.0)  # Table 2 draws 25-30 m/s
    assert s.v_host == 20.0 and s.set_speed == 20.0


def test_the_limiter_never_touches_braking():
    world = World()
    world.reset("ice", 0, "test-1", set_speed=20.0)
    s = world.step(-1.0)
    assert s.accel == pytest.approx(A_MIN)


def test_distant_stop_shape():
    ep = S.build("distant-stop", np.random.default_rng(0), DT)
    p = ep.params
    assert ep.v_host == DEFAULT_SET_SPEED and ep.v_lead[0] == p["v_cruise"] < ep.v_host
    assert 100.0 <= ep.gap <= 200.0 and ep.v_lead[-1] == 0.0
    t_stop = p["t_brake"] + p["v_cruise"] / p["decel"]
    assert np.flatnonzero(ep.v_lead == 0.0)[0] * DT == pytest.approx(t_stop, abs=DT)


@pytest.mark.parametrize("seed", range(10))
def test_distant_stop_can_be_stopped_for_by_slowing_on_the_approach(seed):
    # A host that holds the lead's speed once within 60 m, and brakes fully when the lead
    # brakes, stops short: the scenario asks for an approach, not a miracle.
    world = World()
    obs = world.reset("ice", seed, "distant-stop")
    while not (obs.terminated or obs.truncated):
        u = -1.0 if obs.a_lead < 0 or (obs.gap < 60.0 and obs.v_lead < obs.v_host) else 0.3
        obs = world.step(u)
    assert not obs.collision and obs.v_lead == 0.0 and obs.gap >= STOP_MARGIN
