"""The platoon world: follower 0 drives as a single world's host, each follower's lead is
the car ahead step for step, and an ACC platoon drives as the kinematic platoon does."""

from __future__ import annotations

import numpy as np
import pytest

from agent_client.controllers.acc import AccController
from protocol.constants import MAX_FOLLOWERS
from sim_server.errors import InitialConditionError
from sim_server.platoon import PlatoonWorld, follower_seed
from sim_server.render import CameraConfig, Renderer
from sim_server.world import World, WorldConfig, WorldState
from vacc.platoon_sim import simulate_platoon

T = np.arange(0.0, 90.01, 1.0)
V = 20.0 + 3.0 * np.sin(2 * np.pi * T / 30.0)  # a lead that makes the platoon work


def _obs(st: WorldState) -> dict[str, float]:
    return {"t": st.t, "gap": st.gap, "v_host": st.v_host, "v_lead": st.v_lead, "accel": st.accel, "a_lead": st.a_lead, "set_speed": st.set_speed}


def _drive(platoon: PlatoonWorld, laws: list[AccController]) -> list[list[WorldState]]:
    frames = [platoon.states]
    while not platoon.over:
        frames.append(platoon.step([law(_obs(st)) for law, st in zip(laws, platoon.states, strict=True)]))
    return frames


def test_follower_0_drives_as_the_host_of_a_single_world() -> None:
    platoon, world = PlatoonWorld(3), World()
    states = platoon.reset(["ice", "ev", "ice"], 7, "test-2", duration=20.0)
    st = world.reset("ice", 7, "test-2", duration=20.0)
    assert states[0] == st
    forces = np.random.default_rng(0).uniform(-1, 1, 500)
    laws = [AccController(), AccController()]  # the followers behind keep the platoon going
    frames = 0
    for u in forces:
        if platoon.over:
            break
        behind = [law(_obs(s)) for law, s in zip(laws, platoon.states[1:], strict=True)]
        assert platoon.step([u, *behind])[0] == world.step(u)
        frames += 1
    assert frames == 200 and world.state is not None and world.state.truncated  # 20 s: the platoon ends with it


def test_each_followers_lead_is_the_car_ahead_and_the_run_repeats() -> None:
    def run() -> list[list[WorldState]]:
        platoon = PlatoonWorld(4, WorldConfig(traffic_per_lane=0))
        platoon.reset(["ice"] * 4, 3, "trace", trace=(T, V), gaps=[30.0, 35.0, 40.0, 45.0], host_speed=20.0)
        return _drive(platoon, [AccController() for _ in range(4)])

    frames = run()
    assert len(frames) == 901 and frames[-1][0].truncated
    for states in frames[1:]:
        for ahead, behind in zip(states, states[1:], strict=False):
            assert behind.v_lead == ahead.v_host and behind.a_lead == pytest.approx(ahead.accel, abs=1e-12)
    assert [s.gap for s in frames[0]] == [30.0, 35.0, 40.0, 45.0]
    assert run() == frames  # deterministic


def test_an_acc_platoon_drives_as_the_kinematic_platoon() -> None:
    platoon = PlatoonWorld(5, WorldConfig(traffic_per_lane=0))
    gaps = [40.0] * 5
    platoon.reset(["ice"] * 5, 1, "trace", trace=(T, V), gaps=gaps, host_speed=20.0)
    frames = _drive(platoon, [AccController() for _ in range(5)])
    run = simulate_platoon(platoon.worlds[0].v_lead_profile, [AccController() for _ in range(5)], gaps, v0=20.0)
    assert run.collided is None and run.v.shape[1] == len(frames)
    for i in range(5):
        assert np.array([f[i].gap for f in frames]) == pytest.approx(run.gaps[i], abs=1e-6)
        assert np.array([f[i].v_host for f in frames]) == pytest.approx(run.v[i + 1], abs=1e-9)


def test_each_follower_sees_the_car_ahead_in_its_own_camera() -> None:
    platoon = PlatoonWorld(2)
    platoon.reset(["ice", "ev"], 5, "trace", trace=(T, V), gaps=[20.0, 60.0], host_speed=20.0)
    renderer = Renderer(CameraConfig(width=200, height=200))
    near, far = (renderer.render(w.scene()) for w in platoon.worlds)
    assert near.shape == far.shape and not np.array_equal(near, far)  # the nearer car ahead looks bigger
    assert follower_seed(5, 0) == 5 and follower_seed(5, 1) != follower_seed(5, 2)


def test_bad_platoons_are_refused_with_one_line() -> None:
    with pytest.raises(InitialConditionError, match="1..16 followers"):
        PlatoonWorld(MAX_FOLLOWERS + 1)
    platoon = PlatoonWorld(2)
    with pytest.raises(InitialConditionError, match="needs 2 scenarios"):
        platoon.reset(["ice"], 0, "test-1")
    with pytest.raises(RuntimeError, match="not started"):
        platoon.step([0.0, 0.0])
    platoon.reset(["ice", "ice"], 0, "test-1")
    with pytest.raises(ValueError, match="needs 2 forces"):
        platoon.step([0.0])
