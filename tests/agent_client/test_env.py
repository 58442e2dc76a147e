from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import agent_client.env  # noqa: F401 - registers the id
from agent_client.env import FORCES, VisionACCEnv
from agent_client.launcher import local_server


@pytest.fixture(scope="module")
def server():
    with local_server() as addr:
        yield addr


def test_forces_are_the_21_paper_levels():
    assert len(FORCES) == 21 and FORCES[0] == -1.0 and FORCES[10] == 0.0 and FORCES[-1] == 1.0
    np.testing.assert_allclose(np.diff(FORCES), 0.1)


def test_check_env_passes(server):
    env = VisionACCEnv(server, episode_seconds=3.0)
    try:
        check_env(env, skip_render_check=True)
    finally:
        env.close()


def test_registered_id_spawns_and_reaps_its_server():
    env = gym.make("vacc/VisionACC-v0", episode_seconds=1.0)
    try:
        obs, info = env.reset(seed=0)
        assert obs["frames"].shape == (8, 105, 150) and obs["frames"].dtype == np.uint8
        assert "gap" in info and "gap" not in obs
        steps = 0
        terminated = truncated = False
        while not (terminated or truncated):
            obs, reward, terminated, truncated, info = env.step(10)
            steps += 1
        assert truncated and steps == 10
        assert -1.0 <= reward <= 1.0
    finally:
        env.close()


def test_same_seed_same_observations(server):
    env = VisionACCEnv(server, episode_seconds=2.0)
    try:
        runs = []
        for _ in range(2):
            obs, _ = env.reset(seed=5)
            frames = [obs["frames"][-1].copy()]
            for a in (20, 0, 15, 5):
                obs, *_ = env.step(a)
                frames.append(obs["frames"][-1].copy())
            runs.append(np.stack(frames))
        np.testing.assert_array_equal(runs[0], runs[1])
        assert not np.array_equal(runs[0][0], runs[0][-1])  # the image changes as the car moves
    finally:
        env.close()


def test_stack_stride_picks_older_frames(server):
    env = VisionACCEnv(server, frame_stack=3, stack_stride=2, episode_seconds=2.0)
    try:
        obs, _ = env.reset(seed=1)
        seen = [obs["speeds"][-1]]
        for _ in range(6):
            obs, *_ = env.step(20)
            seen.append(obs["speeds"][-1])
        np.testing.assert_allclose(obs["speeds"], [seen[2], seen[4], seen[6]])
    finally:
        env.close()


@pytest.mark.parametrize(
    ("reward", "scenario", "names"),
    [
        ("gap", "ice", {"gap"}),
        ("force", "ice", {"gap", "force"}),
        ("eco", "ice", {"gap", "energy", "comfort", "closing"}),
        ("eco", "ev", {"gap", "energy", "comfort", "closing"}),
    ],
)
def test_info_reward_terms_sum_to_the_reward(server, reward, scenario, names):
    # A short real episode: each step's named terms add up to the reward the step paid,
    # and the reward is the reward function's own value (not the terms' sum).
    from agent_client.rewards import make_reward

    fn = make_reward(reward, scenario)
    env = VisionACCEnv(server, scenario=scenario, reward=reward, episode_seconds=2.0)
    try:
        _, info = env.reset(seed=4)
        assert "reward_terms" not in info  # reset pays no reward
        a_prev, nonzero = info["accel"], set()
        for i in range(20):
            _, r, terminated, truncated, info = env.step((20, 0, 13, 7, 10)[i % 5])
            terms = info["reward_terms"]
            assert set(terms) == names | {"crash"} and terms["crash"] == 0.0
            assert math.fsum(terms.values()) == pytest.approx(r, rel=1e-12, abs=1e-15)
            assert r == fn(info["gap"], info["force"], v=info["v_host"], a=info["accel"], a_prev=a_prev, v_lead=info["v_lead"])
            a_prev = info["accel"]
            nonzero |= {k for k, v in terms.items() if v != 0.0}
            if terminated or truncated:
                break
        assert nonzero >= names - {"force"}  # every term of the reward was exercised
    finally:
        env.close()


def test_bad_arguments():
    with pytest.raises(ValueError, match="reward"):
        VisionACCEnv(("127.0.0.1", 9), reward="speed")


def test_server_traffic_changes_the_picture_not_the_drive():
    # Two real servers, 0 and 8 cars a lane: the same seed and actions give the same
    # speeds and gaps (the A/B of docs/training.md), and a busier picture.
    runs = []
    for n in (0, 8):
        env = VisionACCEnv(scenario="ev", trajectory="constant", episode_seconds=3.0, server_args=("--traffic", str(n)), zoom=2)
        try:
            obs, info = env.reset(seed=2)
            gaps, frames = [info["gap"]], [obs["frames"][-1].copy()]
            for a in (12, 12, 8, 10, 10):
                obs, _, _, _, info = env.step(a)
                gaps.append(info["gap"])
                frames.append(obs["frames"][-1].copy())
            runs.append((gaps, np.stack(frames)))
        finally:
            env.close()
    assert runs[0][0] == runs[1][0]
    assert not np.array_equal(runs[0][1], runs[1][1])
