from __future__ import annotations

import numpy as np
import pytest

from protocol.constants import SUN_ELEVATION, TRAFFIC_PER_LANE, TRAFFIC_PER_LANE_RANGE
from protocol.scenarios import MAX_PREROLL, PREROLL_MIN_GAP
from sim_server import trajectory as T
from sim_server.errors import InitialConditionError, ScenarioError, TrajectoryError
from sim_server.vehicle import accel_of_force, advance_speed
from sim_server.world import GAP_LIMIT, World, WorldConfig


def run(world: World, actions, **reset):
    states = [world.reset(**reset)]
    for u in actions:
        if states[-1].terminated or states[-1].truncated:
            break
        states.append(world.step(u))
    return states


def test_force_map():
    assert accel_of_force(1.0) == pytest.approx(3.5)
    assert accel_of_force(-1.0) == pytest.approx(-5.5)
    assert accel_of_force(0.0) == 0.0
    assert accel_of_force(0.5) == pytest.approx(1.75)
    for bad in (1.01, -1.5, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            accel_of_force(bad)


def test_speed_never_negative():
    assert advance_speed(0.05, -5.5, 0.02) == 0.0
    states = run(World(), [-1.0] * 200, scenario="ev", seed=1, trajectory="test-2")
    assert min(s.v_host for s in states) == 0.0
    assert all(s.v_host >= 0.0 for s in states)


def test_full_throttle_accelerates_at_3_5():
    w = World()
    s0 = w.reset("ice", 0, "test-1")
    s1 = w.step(1.0)
    assert s1.accel == pytest.approx(3.5)
    assert s1.v_host - s0.v_host == pytest.approx(3.5 * w.config.control_period)
    assert s1.t == pytest.approx(0.1)


def test_same_seed_same_actions_bit_identical():
    actions = np.random.default_rng(3).uniform(-1, 1, 300)
    a = run(World(), actions, scenario="ice", seed=7, trajectory="random")
    b = run(World(), actions, scenario="ice", seed=7, trajectory="random")
    assert a == b
    c = run(World(), actions, scenario="ice", seed=8, trajectory="random")
    assert a != c


def test_salt_changes_the_world():
    a = World(salt=0).reset("ice", 1, "test-1")
    b = World(salt=1).reset("ice", 1, "test-1")
    assert a != b


@pytest.mark.parametrize("scenario", ["ice", "ev"])
def test_initial_conditions_within_table_2(scenario):
    lim = T.LIMITS[scenario]
    for seed in range(20):
        s = World().reset(scenario, seed, "random")
        assert lim.v0_host[0] <= s.v_host <= lim.v0_host[1]
        assert lim.gap0[0] <= s.gap <= lim.gap0[1] + 1e-9
        assert lim.v0_lead[0] <= s.v_lead <= lim.v0_lead[1]


def test_collision_is_detected_by_pymunk_and_terminates():
    w = World()
    states = run(w, [1.0] * 500, scenario="ice", seed=0, trajectory="test-1")
    last = states[-1]
    assert last.collision and last.terminated and last.reason == "collision"
    assert w._collided  # the pymunk handler fired, not only the gap check
    assert not states[-2].collision


def test_gap_over_limit_terminates():
    states = run(World(), [-1.0] * 2000, scenario="ice", seed=0, trajectory="test-1")
    last = states[-1]
    assert last.terminated and last.reason == "gap" and last.gap > GAP_LIMIT
    assert not last.collision


def test_truncated_at_end_of_trajectory_and_duration():
    states = run(World(), [0.0] * 100, scenario="ice", seed=0, trajectory="test-1", duration=5.0)
    assert len(states) == 51
    assert states[-1].truncated and not states[-1].terminated and states[-1].reason == "end"
    assert states[-1].t == pytest.approx(5.0)
    w = World()
    w.reset("ice", 0, "test-1", duration=0.3)
    for _ in range(3):
        w.step(0.0)
    with pytest.raises(RuntimeError):
        w.step(0.0)


def test_substeps_setting_changes_control_period():
    w = World(WorldConfig(substeps=1))
    w.reset("ice", 0, "test-1")
    assert w.step(0.0).t == pytest.approx(0.02)


def test_traffic_faster_left_slower_right():
    w = World()
    w.reset("ice", 4, "test-1")
    for body, lane, _ in w.traffic:
        if lane < 0:
            assert body.velocity.x > 30.0
        else:
            assert body.velocity.x < 30.0
    scene = w.scene()
    assert scene.lead is not None and scene.lead.dx == pytest.approx(w.state.gap)
    assert {c.lane for c in scene.cars} >= {-1, 0, 1}


@pytest.mark.parametrize("n", [0, 1, TRAFFIC_PER_LANE, 8, TRAFFIC_PER_LANE_RANGE[1]])
def test_traffic_per_lane_sets_the_neighbours_and_nothing_else(n):
    # --traffic is a clean A/B for a camera policy: the same seed and actions drive the
    # same lead and host whatever the number of neighbours; only the picture changes.
    actions = np.random.default_rng(5).uniform(-1, 1, 200)
    w = World(WorldConfig(traffic_per_lane=n))
    states = run(w, actions, scenario="ev", seed=3, trajectory="cut-in")
    lanes = [lane for _, lane, _ in w.traffic]
    assert lanes.count(-1) == n and lanes.count(1) == n and len(w.oncoming) == 2 * n
    default = World()
    assert states == run(default, actions, scenario="ev", seed=3, trajectory="cut-in")
    assert w.light == default.light and w.scene().scenery_seed == default.scene().scenery_seed
    assert len([c for c in w.scene().cars if c.lane != 0]) <= 4 * n


@pytest.mark.parametrize("n", [-1, TRAFFIC_PER_LANE_RANGE[1] + 1])
def test_traffic_per_lane_out_of_range_is_refused(n):
    with pytest.raises(ValueError, match=r"traffic_per_lane must be in \[0, 10\], got"):
        WorldConfig(traffic_per_lane=n)


def test_sun_elevation_narrows_the_suns_height_and_changes_nothing_else():
    # The same seeds and actions drive the same lead and host under a lower sun, and the
    # default range draws the very suns it always drew.
    actions = np.random.default_rng(2).uniform(-1, 1, 100)
    low, default = World(WorldConfig(sun_elevation=(0.35, 0.5))), World()
    assert World(WorldConfig(sun_elevation=SUN_ELEVATION)).reset("ice", 227, "catch-up") == default.reset("ice", 227, "catch-up")
    assert default.light == pytest.approx((1.1, 0.35), abs=0.01)  # seed 227: a low sun from the right, as drawn since the start
    heights = []
    for seed in range(40):
        assert run(low, actions, scenario="ice", seed=seed, trajectory="constant") == run(default, actions, scenario="ice", seed=seed, trajectory="constant")
        assert low.light[0] == default.light[0]  # the azimuth is the same draw
        heights.append(low.light[1])
    assert 0.35 <= min(heights) and max(heights) <= 0.5 and max(heights) - min(heights) > 0.1
    low.reset("ice", 0, "test-1")
    assert low.light == (0.6, 0.8)  # the test trajectories keep their fixed sun


@pytest.mark.parametrize("bounds", [(0.5, 0.4), (0.0, 0.5), (0.4, 1.6), (0.4,), (0.3, float("nan"))])
def test_a_bad_sun_elevation_is_refused(bounds):
    with pytest.raises(ValueError, match="sun_elevation must"):
        WorldConfig(sun_elevation=bounds)


@pytest.mark.parametrize("scenario", ["ice", "ev"])
@pytest.mark.parametrize("name", ["test-1", "test-2", "test-3", "test-4", "random"])
def test_trajectories_respect_table_2(scenario, name):
    lim = T.LIMITS[scenario]
    v = T.build(scenario, name, np.random.default_rng(0), 0.02)
    a = np.diff(v) / 0.02
    assert len(v) == 12001  # 4 minutes at 50 Hz
    assert v.min() >= lim.v_min - 1e-9 and v.max() <= lim.v_max + 1e-9
    assert a.min() >= lim.a_min - 1e-6 and a.max() <= lim.a_max + 1e-6


def test_test_trajectories_are_fixed():
    v1 = T.build("ice", "test-3", np.random.default_rng(0), 0.02)
    v2 = T.build("ice", "test-3", np.random.default_rng(99), 0.02)
    np.testing.assert_array_equal(v1, v2)
    r1 = T.build("ice", "random", np.random.default_rng(0), 0.02)
    r2 = T.build("ice", "random", np.random.default_rng(1), 0.02)
    assert not np.array_equal(r1, r2)


def test_eq7_matches_the_formula():
    a, w = T.ICE_TEST_PARAMS["test-1"]
    t = np.array([0.0, 1.3])
    expected = 30 + 0.3 * sum(ai * np.sin(2 * wi * t) for ai, wi in zip(a, w, strict=True))
    np.testing.assert_allclose(T.eq7_speed(np.array(a, float), np.array(w, float), t), expected)


def test_trace_trajectory_and_errors():
    v = T.build("ev", "trace", np.random.default_rng(0), 0.02, trace=(np.array([0.0, 10.0]), np.array([10.0, 20.0])))
    assert len(v) == 501 and v[0] == 10.0 and v[-1] == pytest.approx(20.0)
    with pytest.raises(TrajectoryError, match="not increasing"):
        T.from_trace(np.array([0.0, 0.0]), np.array([1.0, 1.0]), 0.02, T.LIMITS["ev"])
    with pytest.raises(TrajectoryError, match="negative"):
        T.from_trace(np.array([0.0, 1.0]), np.array([1.0, -1.0]), 0.02, T.LIMITS["ev"])
    with pytest.raises(TrajectoryError, match="unknown trajectory"):
        T.build("ice", "test-9", np.random.default_rng(0), 0.02)
    with pytest.raises(ScenarioError):
        T.build("diesel", "test-1", np.random.default_rng(0), 0.02)


def test_random_ev_training_windows_never_overlap_the_test_windows():
    from sim_server.trajectory import _load_trace, random_ev_window

    rng = np.random.default_rng(0)
    for _ in range(400):
        name, i, j = random_ev_window(rng, T.RANDOM_DURATION)
        t_s, _ = _load_trace(name)
        for f, start in T.EV_TEST_WINDOWS.values():
            assert f != name or t_s[j] <= start or t_s[i] >= start + T.TEST_DURATION, (name, t_s[i], start)


def test_trace_semantics_as_the_spec_states():
    # Time 0 is trace_t[0]; linear between samples; a speed band beyond Table 2's ICE
    # 27..33 m/s is driven as given; truncated at the last full control period.
    t = np.array([100.0, 102.0, 103.37])
    v = np.array([5.0, 15.0, 15.0])
    world = World()
    states = run(world, [0.0] * 100, scenario="ice", seed=0, trajectory="trace", trace=(t, v))
    assert states[0].v_lead == 5.0 and states[0].v_host == 5.0  # host starts at the trace's first speed
    assert states[10].v_lead == pytest.approx(10.0)  # 1 s in: halfway between 5 and 15
    assert states[-1].frame == int(np.floor((t[-1] - t[0]) / 0.02 + 1e-9)) // 5 == 33 and states[-1].reason == "end"
    short = World().reset("ice", 0, "trace", trace=(np.array([0.0, 0.05]), np.array([10.0, 10.0])))
    assert short.frame == 0 and short.truncated  # shorter than one control period


def test_obs_t_is_physics_steps_times_dt():
    states = run(World(), [0.0] * 3, scenario="ice", seed=0, trajectory="test-1")
    assert states[3].t == 15 * 0.02 and states[3].t != 3 * 0.1
    # A collision ends its frame at the physics step where it happened.
    world = World()
    state = world.reset("ice", 0, "stopped", host_speed=16.0, gap=0.5)
    state = world.step(1.0)
    assert state.collision and state.t < 5 * 0.02 and round(state.t / 0.02) == world.step_index


@pytest.mark.parametrize("trajectory", ["stopped", "catch-up", "brake-stop", "test-1", "random"])
def test_a_preroll_ends_in_the_cold_start_bit_for_bit(trajectory):
    # The camera runs before the start, but from frame 0 the episode is the cold one:
    # same state, same scene, same states under the same actions (the pre-roll's
    # actions are ignored and nothing is drawn from the episode's generator).
    actions = np.random.default_rng(5).uniform(-0.3, 0.3, 150)
    cold, warm = World(), World()
    a = run(cold, actions, scenario="ice", seed=4, trajectory=trajectory)
    first = warm.reset("ice", 4, trajectory, preroll=14)
    assert (first.frame, first.t) == (-14, pytest.approx(-1.4))
    pre = [first] + [warm.step(1.0) for _ in range(14)]
    assert [s.frame for s in pre] == list(range(-14, 1))
    assert all(s.force == 0.0 and s.accel == 0.0 and s.v_host == a[0].v_host for s in pre)
    assert pre[-1] == a[0]
    b = [pre[-1]]
    for u in actions[: len(a) - 1]:
        b.append(warm.step(u))
    assert b == a
    assert warm.scene() == cold.scene()


def test_the_preroll_shows_the_approach_and_never_ends_the_episode():
    w = World()
    first = w.reset("ice", 2, "stopped", preroll=30)
    host_speed = first.v_host
    gaps = [first.gap] + [w.step(0.0).gap for _ in range(30)]
    # the host closes on the standing car at its own speed: 3 s of it
    assert gaps[0] - gaps[-1] == pytest.approx(host_speed * 3.0)
    assert np.all(np.diff(gaps) < 0)
    # a lead much faster than the host is drawn no closer than PREROLL_MIN_GAP
    w.reset("ice", 3, "catch-up", preroll=100)
    gaps = [w.state.gap] + [w.step(0.0).gap for _ in range(100)]
    assert min(gaps) >= PREROLL_MIN_GAP - 1e-9
    assert w.state.frame == 0 and not w.state.terminated


def test_a_bad_preroll_is_refused_with_its_range():
    with pytest.raises(InitialConditionError, match=r"preroll 101 is outside 0\.\.100"):
        World().reset("ice", 0, "test-1", preroll=MAX_PREROLL + 1)
    with pytest.raises(InitialConditionError, match="preroll -1"):
        World().reset("ice", 0, "test-1", preroll=-1)
