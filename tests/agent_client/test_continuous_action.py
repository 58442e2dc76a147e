"""The "continuous" action type: a target force in [-1, 1], ramped as the ramp's, the full brake at once."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

from agent_client.actions import (
    ACTION_TYPES,
    FULL_BRAKE_TARGET,
    RAMP_RATE,
    ContinuousRamp,
    ForceRamp,
    is_continuous,
    make_action_type,
)
from agent_client.env import VisionACCEnv


def test_the_held_force_moves_toward_the_target_at_the_ramps_rate():
    act = make_action_type("continuous")
    assert isinstance(act, ContinuousRamp) and act.n == 1 and act.n_controls == 2
    forces = []
    for _ in range(20):
        forces.append(act.force(0.5))
    assert max(abs(b - a) for a, b in zip([0.0, *forces], forces, strict=False)) <= RAMP_RATE + 1e-12
    assert forces[-1] == pytest.approx(0.5)  # reached, and held there
    u = act.force(0.515)  # between the ramp's levels: held exactly, not flipped on a 0.01 grid
    assert u == pytest.approx(0.515) and act.force(0.515) == pytest.approx(0.515)
    assert act.force(5.0) == pytest.approx(0.515 + RAMP_RATE)  # clipped to [-1, 1], then ramped


def test_the_full_brake_acts_at_once_and_is_released_at_the_rate():
    act = make_action_type("continuous")
    act.force(0.3)
    assert act.force(FULL_BRAKE_TARGET) == -1.0
    assert act.force(0.0) == pytest.approx(-1.0 + RAMP_RATE)
    assert act.force(FULL_BRAKE_TARGET + 0.01) == pytest.approx(FULL_BRAKE_TARGET + 0.01)  # above it: the ramp
    act.reset()
    assert act.u == 0.0 and act.controls(20.0).tolist() == [0.0, 20.0]


def test_the_same_rate_limit_as_the_discrete_ramp():
    # comfort by construction: one step never moves the force more than ForceRamp's
    ramp, cont = ForceRamp(), ContinuousRamp()
    for target_level, target in ((20, 1.0), (12, 0.2), (5, -0.5)):
        for _ in range(5):
            assert ramp.force(target_level) == pytest.approx(cont.force(target), abs=1e-9)


def test_imitate_gives_the_teachers_force_and_the_full_brake_only_when_hard():
    act = ContinuousRamp()
    assert act.imitate(0.37) == pytest.approx(0.37)
    assert act.imitate(-1.0, hard_brake=0.0) == -1.0
    assert act.imitate(-0.96, hard_brake=6.0) > FULL_BRAKE_TARGET  # not hard enough: the ramp's hardest


def test_continuous_is_an_action_type_and_the_discrete_ones_are_not_continuous():
    assert "continuous" in ACTION_TYPES and is_continuous("continuous")
    assert not any(is_continuous(n) for n in ACTION_TYPES if n != "continuous")


def test_env_has_a_box_action_space_that_passes_check_env():
    env = VisionACCEnv(episode_seconds=1.0, action="continuous", set_speed=25.0)
    try:
        assert env.action_space == spaces.Box(-1.0, 1.0, (1,), np.float32)
        assert env.observation_space["controls"].shape == (8, 2)
        check_env(env, skip_render_check=True)
        env.reset(seed=3, options={"host_speed": 15.0})
        forces = [env.step(np.array([1.0], np.float32))[4]["force"] for _ in range(3)]
        assert forces == pytest.approx([RAMP_RATE, 2 * RAMP_RATE, 3 * RAMP_RATE], abs=1e-6)
        assert env.step(np.array([-1.0], np.float32))[4]["force"] == pytest.approx(-1.0)
        with pytest.raises(ValueError, match="not in Box"):
            env.step(np.array([1.5], np.float32))
        with pytest.raises(ValueError, match="not in Box"):
            env.step(np.array([0.1, 0.2], np.float32))
    finally:
        env.close()
