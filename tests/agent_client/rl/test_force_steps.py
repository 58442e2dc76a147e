"""The held-force action types ("steps" and "ramp"): the force, the controls they observe, end to end."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from driving import drive_briefly

from agent_client.actions import (
    EMERGENCY_LEVEL,
    FORCE_STEPS,
    RAMP_RATE,
    ForceRamp,
    ForceSteps,
    make_action_type,
)
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.evaluation import score
from agent_client.rl.network import QNetwork, transfer_weights
from agent_client.rl.replay import ReplayMemory
from agent_client.rl.train import train
from agent_client.stacker import FrameStacker
from protocol.constants import A_MAX, A_MIN, FORCES
from vacc.cli import main


def test_force_steps_stay_on_their_grid_and_in_range():
    steps = ForceSteps()
    rng = np.random.default_rng(0)
    seen = []
    for k in range(5000):  # random, then only up, then only down
        action = int(rng.integers(len(FORCE_STEPS))) if k < 4000 else len(FORCE_STEPS) - 1 if k < 4500 else 0
        u = steps.force(action)
        seen.append(u)
        assert -1.0 <= u <= 1.0
        assert abs(u * 50 - round(u * 50)) < 1e-9  # on the 0.02 grid: no float drift
    assert min(seen) == -1.0 and max(seen) == 1.0
    assert max(abs(np.diff(seen))) <= max(abs(s) for s in FORCE_STEPS) + 1e-12
    steps.reset()
    assert steps.u == 0.0 and steps.controls(20.0).tolist() == [0.0, 20.0]
    with pytest.raises(ValueError, match="action type"):
        make_action_type("torque")


def test_ramp_moves_toward_the_chosen_level_at_a_bounded_rate():
    ramp = ForceRamp()
    rng = np.random.default_rng(0)
    seen, prev = [], 0.0
    for _ in range(3000):
        action = int(rng.integers(1, len(FORCES)))  # any level but the emergency brake
        u = ramp.force(action)
        assert abs(u - prev) <= RAMP_RATE + 1e-12  # the actuator's rate, whatever the policy asks
        assert min(prev, FORCES[action]) - 1e-12 <= u <= max(prev, FORCES[action]) + 1e-12  # toward the target, never past it
        assert abs(u * 100 - round(u * 100)) < 1e-9  # no float drift
        seen.append(u)
        prev = u
    # The rate is comfortable in both directions: under ISO 15622's 2.5 m/s^3 over 0.1 s.
    assert RAMP_RATE * A_MAX / 0.1 < 2.5 and RAMP_RATE * -A_MIN / 0.1 < 2.5
    for _ in range(60):
        u = ramp.force(len(FORCES) - 1)
    assert u == 1.0  # a held level is reached and kept
    assert ramp.force(EMERGENCY_LEVEL) == -1.0  # the full brake acts at once
    assert ramp.force(10) == pytest.approx(-1.0 + RAMP_RATE)  # and is released at the rate
    ramp.reset()
    assert ramp.u == 0.0 and ramp.controls(20.0).tolist() == [0.0, 20.0]
    ramp.force(20)
    ramp.observe(0.0)  # the vehicle achieved nothing (the limiter): anti-windup, as for steps
    assert ramp.u == 0.0
    assert make_action_type("ramp").n == len(FORCES)


def test_env_observes_the_held_force_and_the_set_speed():
    from agent_client.env import VisionACCEnv
    from agent_client.launcher import local_server

    with local_server() as addr:
        env = VisionACCEnv(addr, episode_seconds=2.0, action="steps", set_speed=25.0, stack_stride=2)
        try:
            assert env.action_space.n == len(FORCE_STEPS)
            obs, info = env.reset(options={"seed": 4, "host_speed": 15.0})  # well below the set speed: no limiter
            assert set(obs) == {"frames", "speeds", "controls"} and env.observation_space.contains(obs)
            assert obs["controls"].tolist() == [[0.0, 25.0]] * 8
            up = FORCE_STEPS.index(0.1)
            for _ in range(3):
                obs, *_, info = env.step(up)
            assert info["force"] == pytest.approx(0.3)  # the simulator got the held force
            assert obs["controls"][-1].tolist() == pytest.approx([0.3, 25.0])
            assert obs["controls"][-2].tolist() == pytest.approx([0.1, 25.0])  # two steps back (stride 2)
            env.reset(seed=4)
            assert env.actions.u == 0.0  # released at every episode start
        finally:
            env.close()


def test_env_ramps_the_force_it_sends_to_the_simulator():
    from agent_client.env import VisionACCEnv
    from agent_client.launcher import local_server

    with local_server() as addr:
        env = VisionACCEnv(addr, episode_seconds=2.0, action="ramp", set_speed=25.0)
        try:
            assert env.action_space.n == len(FORCES) and "controls" in env.observation_space.spaces
            env.reset(options={"seed": 4, "host_speed": 15.0})
            forces = [env.step(len(FORCES) - 1)[-1]["force"] for _ in range(3)]  # ask for full throttle
            assert forces == pytest.approx([RAMP_RATE, 2 * RAMP_RATE, 3 * RAMP_RATE])
            obs, *_, info = env.step(EMERGENCY_LEVEL)
            assert info["force"] == -1.0 and obs["controls"][-1].tolist() == pytest.approx([-1.0, 25.0])
        finally:
            env.close()


def test_replay_keeps_the_controls_of_each_stack(tmp_path):
    rng = np.random.default_rng(1)
    memory = ReplayMemory(50, 4, 2, n_controls=2)
    stacker, steps = FrameStacker(4, 2), ForceSteps()
    expected = {}
    for _episode in range(3):
        stacker.reset()
        steps.reset()
        obs = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0, steps.controls(30.0))
        memory.start(obs)
        expected[memory.total - 1] = obs["controls"]
        for _ in range(12):
            action = int(rng.integers(len(FORCE_STEPS)))
            steps.force(action)
            obs = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0, steps.controls(30.0))
            memory.add(action, 0.0, False, False, obs)
            expected[memory.total - 1] = obs["controls"]
    for i, controls in expected.items():
        np.testing.assert_array_equal(memory.stack_controls(np.array([i]))[0], controls)
    b = memory.sample(8, np.random.default_rng(0))
    assert b.controls.shape == b.next_controls.shape == (8, 4, 2)
    memory.save(tmp_path / "r.npz", 7)
    again = ReplayMemory(50, 4, 2, n_controls=2)
    assert again.load(tmp_path / "r.npz") == 7
    np.testing.assert_array_equal(again.controls, memory.controls)


def test_transfer_keeps_the_perception_of_a_levels_policy():
    torch.manual_seed(0)
    levels, steps = QNetwork(), QNetwork.of(Config(action="steps"))
    kept = transfer_weights(levels, steps)
    assert kept == ["fc.2.weight", "fc.2.bias"]  # a new output layer: other actions
    frames = torch.randint(0, 256, (3, 8, FRAME_H, FRAME_W), dtype=torch.uint8)
    speeds = torch.rand(3, 8) * 30
    controls = torch.rand(3, 8, 2)
    hidden = lambda q, *x: q.fc[1](q.fc[0](torch.cat([q.conv(frames.float() / 255), *x], 1)))  # noqa: E731
    torch.testing.assert_close(hidden(steps, speeds / 30, controls.flatten(1)), hidden(levels, speeds / 30), rtol=0, atol=1e-6)


def test_config_checks_the_action_and_the_training_mix():
    with pytest.raises(ConfigError, match="servers=1") as e:
        Config(action="steps", servers=2)
    assert e.value.field == "action"
    with pytest.raises(ConfigError, match="lead scenario") as e:
        Config(train_trajectories=("random", "test-1"))
    assert e.value.field == "train_trajectories"
    result = CliRunner().invoke(main, ["train", "--reward", "eco", "--steps", "10", "--train-trajectories", "stoped", "--out", "unused"])
    assert result.exit_code == 2 and "--train-trajectories" in result.output and "stoped" in result.output


@pytest.mark.parametrize(
    ("weights", "message"),
    [("1,0.5", "needs 4 weights"), ("1,x,0,0", "not a comma-separated list of numbers"), ("0,1,1,1", "the gap's > 0"), ("1,-1,0,0", ">= 0")],
)
def test_eco_weights_are_checked_against_their_option(weights, message):
    result = CliRunner().invoke(main, ["train", "--reward", "eco", "--steps", "10", "--eco-weights", weights, "--out", "unused"])
    assert result.exit_code == 2 and "--eco-weights" in result.output and message in result.output


def test_eco_weights_round_trip_and_old_configs_load_without_the_closing_term():
    from agent_client.rl.config import config_dict, config_from

    cfg = Config(reward="eco", eco_weights=(1.0, 0.2, 0.3, 0.4))
    assert config_from(config_dict(cfg), "x").eco_weights == (1.0, 0.2, 0.3, 0.4)
    old = config_dict(Config())
    del old["eco_weights"]  # a run from before the closing term
    assert config_from(old, "x").eco_weights == (1.0, 0.5, 0.25, 0.0)


def test_best_pt_score_counts_the_55m_target_on_following_trajectories_only():
    class Log:
        def add(self, *a):
            pass

    follow = {"trajectory": "random:1", "gap_rmse_m": 3.0, "collision": False, "min_gap_m": 40.0, "reason": "end"}
    stop = {"trajectory": "stopped:1", "gap_rmse_m": 45.0, "collision": False, "min_gap_m": 4.5, "reason": "end"}
    assert score(Log(), [follow, stop], 0) == 3.0  # behind a stopped car 55 m is no target
    assert score(Log(), [stop], 0) == 45.0  # but with nothing else it is all there is
    close = {**stop, "min_gap_m": 1.5}
    assert score(Log(), [follow, close], 0) == 1e6 + 3.0  # under the 2 m safety floor: a failure


def test_steps_policy_on_a_scenario_mix_resumes_exactly(tmp_path):
    cfg = Config(
        reward="eco", action="steps", train_trajectories=("random", "stopped", "brake-stop"), total_steps=120,
        learning_starts=30, train_every=4, batch_size=8, buffer_size=400, exploration_steps=100, target_sync_every=40,
        episode_seconds=3.0, checkpoint_every=30, eval_every=0, eval_trajectories=("random:2", "stopped:1"),
        eval_seconds=1.0, log_every=20,
    )  # fmt: skip
    whole = train(cfg, tmp_path / "whole", progress=False)
    train(Config(**{**cfg.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    assert {r["trajectory"] for r in whole["last_eval"]} == {"random:2", "stopped:1"}
    a, b = (torch.load(tmp_path / d / "latest.pt", weights_only=True) for d in ("whole", "split"))
    assert a["rng"]["numpy"] == b["rng"]["numpy"]
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    # and it drives: vacc drive takes the policy, holding its force between steps
    log = drive_briefly(tmp_path / "whole" / "best.pt", tmp_path / "drive.csv")
    forces = np.loadtxt(log, delimiter=",", skiprows=1, usecols=6)
    assert np.all(np.abs(np.diff(forces)) <= 0.5 + 1e-9)


def test_anti_windup_holds_the_force_the_vehicle_achieved():
    steps = ForceSteps()
    for _ in range(5):
        steps.force(FORCE_STEPS.index(0.1))
    steps.observe(0.5 * 3.5)  # the vehicle followed: nothing changes
    assert steps.u == 0.5
    steps.observe(0.0)  # the limiter held the speed
    assert steps.u == 0.0
    steps.force(0)  # -0.5: braking at 2.75 m/s^2
    steps.observe(-1.3)  # it stopped part-way through the step
    assert steps.u == -0.22  # 1.3 / 5.5 = 0.236, toward zero on the 0.02 grid


def test_env_force_never_winds_up_on_the_speed_limiter():
    from agent_client.env import VisionACCEnv
    from agent_client.launcher import local_server

    with local_server() as addr:
        env = VisionACCEnv(addr, episode_seconds=2.0, action="steps", trajectory="constant")
        try:
            env.reset(options={"seed": 1, "host_speed": 20.0, "set_speed": 20.0, "gap": 150.0})
            for _ in range(6):  # full throttle asked for, at the set speed
                obs, *_, info = env.step(FORCE_STEPS.index(0.1))
            assert info["v_host"] == pytest.approx(20.0)
            assert obs["controls"][-1, 0] == 0.0  # the held force is the achieved one
        finally:
            env.close()
