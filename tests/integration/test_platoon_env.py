"""The PettingZoo ParallelEnv over a real platoon server on 127.0.0.1."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test  # noqa: E402

from agent_client.platoon_env import PlatoonParallelEnv  # noqa: E402


def test_the_platoon_passes_pettingzoos_parallel_api_test():
    env = PlatoonParallelEnv(3, scenarios=("ice", "ev", "ice"), trajectory="test-1", episode_seconds=2.0)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # the test's made-up reset option, said in a warning
            parallel_api_test(env, num_cycles=30)
        obs, infos = env.reset(seed=1)
        assert sorted(obs) == ["seat_0", "seat_1", "seat_2"] and obs["seat_2"]["frames"].shape == (8, 105, 150)
        # one episode for all: seat i's lead is seat i - 1's car
        steps = 0
        while env.agents:
            actions = {"seat_0": 10, "seat_1": 8, "seat_2": 4}  # u = 0, -0.2, -0.6: seat_2 brakes hardest
            obs, rewards, terminations, truncations, infos = env.step(actions)
            steps += 1
            assert infos["seat_1"]["v_lead"] == pytest.approx(infos["seat_0"]["v_host"], abs=1e-12)
        assert steps == 20 and all(truncations.values()) and env.agents == []
        assert infos["seat_2"]["gap"] > infos["seat_1"]["gap"] + 1.0  # it fell back from the car ahead, which fell back too
        assert all(np.isfinite(r) for r in rewards.values())
    finally:
        env.close()


def test_wrong_agents_or_sizes_are_refused():
    with pytest.raises(ValueError, match="3 followers need 3 scenarios, got 2"):
        PlatoonParallelEnv(3, scenarios=("ice", "ev"))
    with pytest.raises(ValueError, match="1..16 followers, got 17"):
        PlatoonParallelEnv(17)
    env = PlatoonParallelEnv(2, trajectory="test-1", episode_seconds=1.0)
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match=r"actions for \['seat_0'\], but the live agents are \['seat_0', 'seat_1'\]"):
            env.step({"seat_0": 10})
    finally:
        env.close()
