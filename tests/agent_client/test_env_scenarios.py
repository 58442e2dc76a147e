"""The gym env with lead scenarios and the set-speed / initial-condition reset options."""

from __future__ import annotations

import pytest

from agent_client.env import VisionACCEnv
from agent_client.launcher import local_server


@pytest.fixture(scope="module")
def server():
    with local_server() as addr:
        yield addr


def test_lead_scenario_and_reset_options(server):
    env = VisionACCEnv(server, trajectory="stopped", episode_seconds=2.0, set_speed=20.0)
    try:
        _, info = env.reset(seed=1)
        assert info["v_lead"] == 0.0 and info["set_speed"] == 20.0
        _, info = env.reset(options={"seed": 1, "trajectory": "catch-up", "host_speed": 4.0, "gap": 70.0, "set_speed": 25.0})
        assert info["v_host"] == 4.0 and info["gap"] == pytest.approx(70.0) and info["set_speed"] == 25.0
        for _ in range(5):
            *_, info = env.step(20)  # full throttle
        assert info["v_host"] == pytest.approx(4.0 + 3.5 * 0.5)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({"trajectory": "parked"}, "unknown trajectory 'parked'"),
        ({"host_speed": 40.0}, "host speed 40.0 m/s is outside 0..33.5 m/s"),
        ({"gap": 0.0}, "gap 0.0 m is outside"),
        ({"set_speed": 99.0}, "set speed 99.0 m/s is outside 1..80 m/s"),
        ({"sett_speed": 20.0}, "unknown reset options ['sett_speed']"),
    ],
)
def test_bad_reset_options_are_clear_errors(server, options, words):
    env = VisionACCEnv(server, episode_seconds=1.0)
    try:
        with pytest.raises(ValueError) as err:
            env.reset(seed=0, options=options)
        assert words in str(err.value)
    finally:
        env.close()


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="unknown trajectory 'test-9'"):
        VisionACCEnv(("127.0.0.1", 9), trajectory="test-9")
    with pytest.raises(ValueError, match="set speed 0.5 m/s"):
        VisionACCEnv(("127.0.0.1", 9), set_speed=0.5)


def test_a_preroll_env_starts_with_real_frames_and_the_same_frame_0(server):
    import numpy as np

    firsts = {}
    for preroll in (False, True):
        env = VisionACCEnv(server, trajectory="stopped", episode_seconds=2.0, frame_stack=8, stack_stride=2, action="ramp-fine", preroll=preroll)
        try:
            obs, info = env.reset(options={"seed": 3})
            firsts[preroll] = obs, info
        finally:
            env.close()
    (cold, cold_info), (warm, warm_info) = firsts[False], firsts[True]
    assert "preroll" not in cold_info and len(warm_info["preroll"]) == 14
    assert all(np.array_equal(f, cold["frames"][0]) for f in cold["frames"])
    assert len({f.tobytes() for f in warm["frames"]}) == 8  # the standing car growing
    assert np.array_equal(warm["frames"][-1], cold["frames"][-1]) and warm_info["gap"] == cold_info["gap"]
    # the stack's older frames are the pre-roll's, every stride-th one
    for k, frame in enumerate(warm["frames"][:-1]):
        assert np.array_equal(frame, warm_info["preroll"][2 * k]["frames"][-1])
    assert all(f["controls"][-1][0] == 0.0 for f in warm_info["preroll"])  # coasting: no force held


def _crash_into_a_stopped_car(server, **kwargs):
    """Coast (u = 0, the force term's peak) into a standing car; the last step's returns."""
    env = VisionACCEnv(server, trajectory="stopped", reward="force", episode_seconds=60.0, **kwargs)
    try:
        env.reset(options={"seed": 0, "host_speed": 15.0, "gap": 6.0})
        for _ in range(100):
            _, reward, terminated, truncated, info = env.step(10)  # action 10: u = 0
            if terminated or truncated:
                return reward, terminated, info
        raise AssertionError("no collision in 10 s at 15 m/s from 6 m")
    finally:
        env.close()


def test_crash_reward_replaces_the_rewards_value_at_contact(server):
    from agent_client.rewards import force_reward

    reward, terminated, info = _crash_into_a_stopped_car(server)
    assert terminated and info["collision"]
    assert reward == force_reward(info["gap"], 0.0) == pytest.approx(0.0)  # Table 1 at contact: (-10 + 10) / 20
    assert info["reward_terms"] == {"gap": -0.5, "force": 0.5, "crash": 0.0}  # no crash_reward: the reward's own terms
    reward, terminated, info = _crash_into_a_stopped_car(server, crash_reward=-1.0)
    assert terminated and info["collision"] and reward == -1.0
    assert info["reward_terms"] == {"gap": 0.0, "force": 0.0, "crash": -1.0}  # the crash value replaced them
    with pytest.raises(ValueError, match="crash_reward must be finite"):
        VisionACCEnv(("127.0.0.1", 9), crash_reward=float("nan"))
