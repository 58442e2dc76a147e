"""The decision rule (Config.decision): the argmax, or the ramp toward the softmax-weighted
mean of a student's target levels; checkpoints record it, and every path decides alike."""

from __future__ import annotations

import csv
import subprocess
import sys

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from driving import drive_briefly

from agent_client.actions import EMERGENCY_LEVEL, FINE_LEVELS, RAMP_RATE, FineRamp
from agent_client.errors import InputFileError
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.checkpoint import load_policy, save_policy, with_decision
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.network import FIRM_BRAKE, Decision, Policy, QNetwork, greedy_action
from agent_client.rl.train import train
from vacc.cli import main

STUDENT = {"reward": "eco", "action": "ramp-fine", "teacher": "acc"}


def _fixed_outputs(logits: list[float]) -> QNetwork:
    """A network whose outputs are ``logits`` whatever it sees."""
    q = QNetwork(n_actions=len(logits), n_controls=2)
    with torch.no_grad():
        q.fc[-1].weight.zero_()
        q.fc[-1].bias.copy_(torch.tensor(logits))
    return q.eval()


def _obs(rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {
        "frames": rng.integers(0, 256, (8, FRAME_H, FRAME_W), dtype=np.uint8),
        "speeds": np.full(8, 25.0, np.float32),
        "controls": np.tile(np.array([0.0, 33.5], np.float32), (8, 1)),
    }


def test_the_ramp_moves_toward_a_target_between_levels_at_its_rate_and_never_jumps():
    ramp = FineRamp()
    assert ramp.force_toward(0.5) == pytest.approx(RAMP_RATE)
    assert ramp.force_toward(0.05) == pytest.approx(0.05)  # within a step: reached
    assert ramp.force_toward(0.013) == pytest.approx(0.01)  # reached, on the 0.01 grid
    ramp.reset()
    assert ramp.force_toward(-1.0) == pytest.approx(-RAMP_RATE)  # only the full brake's level acts at once
    ramp.u = 0.99
    assert ramp.force_toward(7.0) == 1.0  # clipped to the force range


def test_the_mean_decision_is_the_softmax_weighted_level_without_the_full_brake():
    rng = np.random.default_rng(0)
    logits = [float(np.float32(x)) for x in rng.normal(0.0, 2.0, len(FINE_LEVELS))]  # the network's float32
    logits[12] = 9.0  # the argmax, not the full brake
    q = _fixed_outputs(logits)
    for temperature in (0.5, 1.0, 2.0, 5.0):
        d = Policy(q, "mean", FINE_LEVELS, temperature)(_obs(rng))
        z = np.array(logits[1:]) / temperature
        p = np.exp(z - z.max()) / np.exp(z - z.max()).sum()
        assert d.action == 12
        assert d.target == pytest.approx(float(p @ np.array(FINE_LEVELS[1:])), abs=1e-12)
    cold, hot = (Policy(q, "mean", FINE_LEVELS, t)(_obs(rng)).target for t in (0.01, 1e6))
    assert cold == pytest.approx(FINE_LEVELS[12])  # a cold softmax is the argmax's level
    assert hot == pytest.approx(float(np.mean(FINE_LEVELS[1:])))  # a hot one averages them all


def test_the_mean_decision_matches_torchs_softmax_and_argmax_on_many_outputs():
    # decide() computes in Python floats (cheaper per decision than tensor ops); it must pick
    # torch.argmax's action (the first of equal maxima) and torch.softmax's target.
    rng = np.random.default_rng(3)
    policy = Policy(QNetwork(n_actions=len(FINE_LEVELS), n_controls=2), "mean", FINE_LEVELS, 2.0)
    levels = torch.tensor(FINE_LEVELS[1:], dtype=torch.float64)
    outs = torch.from_numpy(rng.normal(0.0, 3.0, (2000, len(FINE_LEVELS))).astype(np.float32))
    outs[::5, 7] = outs[::5, 3] = 50.0  # equal maxima: the first is the action
    for out in outs:
        d = policy.decide(out)
        assert d.action == int(torch.argmax(out))
        if d.target is not None:
            expected = float(torch.softmax(out.double()[1:] / 2.0, dim=0) @ levels)
            if FINE_LEVELS[d.action] <= -FIRM_BRAKE:  # a firm argmax brake: the target no softer
                expected = min(expected, FINE_LEVELS[d.action])
            assert d.target == pytest.approx(expected, abs=1e-12)


def test_the_full_brake_acts_at_once_where_it_is_the_argmax():
    logits = [0.0] * len(FINE_LEVELS)
    logits[EMERGENCY_LEVEL] = 3.0
    assert Policy(_fixed_outputs(logits), "mean", FINE_LEVELS, 2.0)(_obs(np.random.default_rng(1))) == Decision(EMERGENCY_LEVEL)


def test_the_full_brake_acts_at_once_where_its_softmax_share_reaches_the_brake_share():
    rng = np.random.default_rng(4)
    logits = [0.0] * len(FINE_LEVELS)
    logits[4], logits[EMERGENCY_LEVEL] = 2.0, 1.0  # the argmax brakes at -0.3; the full brake is second
    z = np.array(logits) / 2.0
    share = float(np.exp(z[EMERGENCY_LEVEL]) / np.exp(z).sum())  # the full brake's share at temperature 2
    q = _fixed_outputs(logits)
    below = Policy(q, "mean", FINE_LEVELS, 2.0, brake_share=share + 1e-3)(_obs(rng))
    assert below.action == 4 and below.target is not None  # a ramp, as without the rule
    assert below == Policy(q, "mean", FINE_LEVELS, 2.0)(_obs(rng))
    assert Policy(q, "mean", FINE_LEVELS, 2.0, brake_share=share - 1e-3)(_obs(rng)) == Decision(EMERGENCY_LEVEL)
    with pytest.raises(ConfigError, match=r"\(0, 1\]") as e:
        Config(**STUDENT, decision="mean", decision_brake_share=0.0)
    assert e.value.field == "decision_brake_share"
    with pytest.raises(ConfigError, match="mean"):
        Config(**STUDENT, decision_brake_share=0.2)  # the argmax has no softmax to read


def test_where_the_argmax_brakes_firmly_the_mean_brakes_no_softer():
    rng = np.random.default_rng(3)
    firm = next(a for a, u in enumerate(FINE_LEVELS) if a != EMERGENCY_LEVEL and u <= -FIRM_BRAKE)
    soft = FINE_LEVELS.index(-0.14)
    for argmax in (firm, soft):
        logits = [0.0] * len(FINE_LEVELS)
        logits[argmax] = 2.0  # the rest pulls the mean toward the middle levels
        d = Policy(_fixed_outputs(logits), "mean", FINE_LEVELS, 2.0)(_obs(rng))
        z = np.array(logits[1:]) / 2.0
        mean = float(np.exp(z) @ np.array(FINE_LEVELS[1:]) / np.exp(z).sum())
        assert mean > FINE_LEVELS[argmax]  # the average alone would brake softer
        expected = FINE_LEVELS[argmax] if argmax == firm else mean
        assert d == Decision(argmax, pytest.approx(expected, abs=1e-12))


def test_the_deadband_keeps_the_held_force_near_the_target_but_never_holds_back_a_firm_brake():
    rng = np.random.default_rng(5)
    logits = [0.0] * len(FINE_LEVELS)
    logits[FINE_LEVELS.index(0.09)] = 6.0  # the mean sits a little below 0.09
    q = _fixed_outputs(logits)
    free = Policy(q, "mean", FINE_LEVELS, 1.0)(_obs(rng)).target
    assert free is not None
    for held, deadband, kept in ((free + 0.015, 0.02, True), (free - 0.025, 0.02, False), (free + 0.015, 0.01, False)):
        obs = _obs(rng)
        obs["controls"][-1, 0] = held  # the force held now: the last of the observed controls
        d = Policy(q, "mean", FINE_LEVELS, 1.0, deadband=deadband)(obs)
        assert d.target == pytest.approx(float(np.float32(held)) if kept else free, abs=1e-12)
    logits = [0.0] * len(FINE_LEVELS)
    logits[FINE_LEVELS.index(-0.3)] = 6.0  # a firm brake
    q = _fixed_outputs(logits)
    obs = _obs(rng)
    obs["controls"][-1, 0] = -0.29
    assert Policy(q, "mean", FINE_LEVELS, 1.0, deadband=0.05)(obs).target == pytest.approx(-0.3)  # not held at -0.29
    with pytest.raises(ValueError, match="controls"):
        Policy(q, "mean", FINE_LEVELS, 1.0, deadband=0.05).decide(torch.tensor(logits))
    with pytest.raises(ConfigError, match="mean") as e:
        Config(**STUDENT, decision_deadband=0.02)  # the argmax has no target to hold near
    assert e.value.field == "decision_deadband"
    with pytest.raises(ConfigError, match=r"\[0, 0.5\)"):
        Config(**STUDENT, decision="mean", decision_deadband=-0.01)


def test_the_smoothing_asks_a_share_of_the_way_to_the_target_but_never_lags_a_firm_brake():
    rng = np.random.default_rng(6)
    logits = [0.0] * len(FINE_LEVELS)
    logits[FINE_LEVELS.index(0.2)] = 6.0
    q = _fixed_outputs(logits)
    free = Policy(q, "mean", FINE_LEVELS, 1.0)(_obs(rng)).target
    assert free is not None
    obs = _obs(rng)
    obs["controls"][-1, 0] = held = -0.05
    for share in (1.0, 0.5, 0.2):
        d = Policy(q, "mean", FINE_LEVELS, 1.0, smoothing=share)(obs)
        assert d.target == pytest.approx(float(np.float32(held)) + share * (free - float(np.float32(held))), abs=1e-12)
    logits = [0.0] * len(FINE_LEVELS)
    logits[FINE_LEVELS.index(-0.45)] = 6.0  # a firm brake: the argmax's level at once, as without smoothing
    obs["controls"][-1, 0] = 0.1
    assert Policy(_fixed_outputs(logits), "mean", FINE_LEVELS, 1.0, smoothing=0.2)(obs).target == pytest.approx(-0.45)
    for bad in (0.0, 1.5):
        with pytest.raises(ConfigError, match=r"\(0, 1\]") as e:
            Config(**STUDENT, decision="mean", decision_smoothing=bad)
        assert e.value.field == "decision_smoothing"
    with pytest.raises(ConfigError, match="mean"):
        Config(**STUDENT, decision_smoothing=0.5)


def test_the_argmax_decision_is_the_greedy_action():
    torch.manual_seed(0)
    q, rng = QNetwork(n_actions=len(FINE_LEVELS), n_controls=2).eval(), np.random.default_rng(2)
    for _ in range(5):
        obs = _obs(rng)
        assert Policy(q)(obs) == Decision(greedy_action(q, obs["frames"], obs["speeds"], obs["controls"]))


def test_config_refuses_a_mean_decision_without_a_teachers_ramp_targets():
    for bad in ({"teacher": "none"}, {"action": "levels"}, {"action": "steps"}):
        with pytest.raises(ConfigError, match="mean") as e:
            Config(**{**STUDENT, **bad, "decision": "mean"})
        assert e.value.field == "decision"
    with pytest.raises(ConfigError, match="> 0") as e:
        Config(**STUDENT, decision="mean", decision_temperature=0.0)
    assert e.value.field == "decision_temperature"
    result = CliRunner().invoke(main, ["train", "--reward", "eco", "--steps", "10", "--decision", "mean", "--out", "unused"])
    assert result.exit_code == 2 and "--decision" in result.output


def test_a_policy_copied_with_another_decision_keeps_its_weights_and_the_original(tmp_path):
    torch.manual_seed(0)
    cfg = Config(**STUDENT)
    q = QNetwork.of(cfg)
    src, dst = tmp_path / "student.pt", tmp_path / "mean.pt"
    save_policy(q, cfg, src)
    before = src.read_bytes()
    assert with_decision(src, dst, "mean", 3.0, brake_share=0.2).decision_temperature == 3.0
    assert src.read_bytes() == before
    copy, copy_cfg = load_policy(dst)
    assert (copy_cfg.decision, copy_cfg.decision_temperature, copy_cfg.decision_brake_share) == ("mean", 3.0, 0.2)
    for key, value in q.state_dict().items():
        torch.testing.assert_close(copy.state_dict()[key], value, rtol=0, atol=0)
    with pytest.raises(InputFileError, match="exists"):
        with_decision(src, dst, "argmax")
    assert load_policy(dst)[1].decision == "mean"  # not overwritten
    dqn = tmp_path / "dqn.pt"
    save_policy(QNetwork(), Config(), dqn)
    cli = [sys.executable, "-m", "vacc", "checkpoint", "decide", str(dqn), str(tmp_path / "x.pt"), "--decision", "mean"]
    done = subprocess.run(cli, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "needs a teacher" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.pt").exists()


def test_a_mean_decision_run_trains_evaluates_and_drives_smoothly(tmp_path):
    cfg = Config(
        **STUDENT, decision="mean", teacher_steps=40, train_trajectories=("random",), total_steps=80, learning_starts=20,
        train_every=4, batch_size=8, buffer_size=300, start_e=0.0, end_e=0.0, episode_seconds=3.0, checkpoint_every=40,
        eval_every=40, eval_trajectories=("random:1",), eval_seconds=2.0, log_every=20,
    )  # fmt: skip
    summary = train(cfg, tmp_path / "run", progress=False)
    assert summary["last_eval"][0]["steps"] > 0
    assert load_policy(tmp_path / "run" / "best.pt")[1].decision == "mean"
    log = drive_briefly(tmp_path / "run" / "best.pt", tmp_path / "drive.csv", "random", 4.0)
    forces = np.array([float(r["force"]) for r in csv.DictReader(log.open())])
    steps = np.abs(np.diff(forces))
    # a ramp (or the full brake at once); off the levels' grid where the mean lies between them
    assert ((steps <= RAMP_RATE + 1e-9) | (forces[1:] == -1.0)).all()


def test_a_confirmed_brake_share_brakes_fully_only_in_decisions_in_a_row():
    rng = np.random.default_rng(5)
    logits = [0.0] * len(FINE_LEVELS)
    logits[4], logits[EMERGENCY_LEVEL] = 2.0, 1.0  # the full brake second, at a share of about 0.06 at temperature 2
    calm = [0.0] * len(FINE_LEVELS)
    calm[4] = 2.0  # the full brake at a share of about 0.04
    sure = [0.0] * len(FINE_LEVELS)
    sure[EMERGENCY_LEVEL] = 3.0
    unsure, calm, sure = _fixed_outputs(logits), _fixed_outputs(calm), _fixed_outputs(sure)
    obs = _obs(rng)
    policy = Policy(unsure, "mean", FINE_LEVELS, 2.0, brake_share=0.05, brake_confirm=2)
    first = policy(obs)
    assert first.action == 4 and first.target is not None  # one decision at the share: not yet
    assert policy(obs) == Decision(EMERGENCY_LEVEL)  # the second in a row: the full brake
    assert policy(obs) == Decision(EMERGENCY_LEVEL)
    policy.reset()
    assert policy(obs).target is not None  # a new episode starts the count over
    policy.q = calm
    assert policy(obs).target is not None  # a decision below the share breaks the run
    policy.q = unsure
    assert policy(obs).target is not None
    fresh = policy.fresh()
    assert policy(obs) == Decision(EMERGENCY_LEVEL) and fresh(obs).target is not None  # a copy has its own count
    policy.reset()
    policy.q = sure
    assert policy(obs) == Decision(EMERGENCY_LEVEL)  # the argmax's full brake acts at once ...
    policy.q = unsure
    assert policy(obs) == Decision(EMERGENCY_LEVEL)  # ... and a share after it goes on braking
    at_once = Policy(unsure, "mean", FINE_LEVELS, 2.0, brake_share=0.05)
    assert at_once(obs) == Decision(EMERGENCY_LEVEL)
    with pytest.raises(ConfigError) as e:
        Config(**STUDENT, decision="mean", decision_brake_share=0.1, decision_brake_confirm=0)
    assert e.value.field == "decision_brake_confirm"
    with pytest.raises(ConfigError, match="brake_share below 1"):
        Config(**STUDENT, decision="mean", decision_brake_confirm=2)


def test_decide_records_the_brake_confirmation(tmp_path):
    cfg = Config(**STUDENT)
    src, dst = tmp_path / "student.pt", tmp_path / "confirmed.pt"
    save_policy(QNetwork.of(cfg), cfg, src)
    cli = [sys.executable, "-m", "vacc", "checkpoint", "decide", str(src), str(dst), "--decision", "mean",
           "--brake-share", "0.1", "--brake-confirm", "2", "--full-brake-confirm", "3"]  # fmt: skip
    done = subprocess.run(cli, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "(confirmed in 2)" in done.stdout and "full brake confirmed in 3" in done.stdout, done.stderr
    assert load_policy(dst)[1].decision_brake_confirm == 2 and load_policy(dst)[1].decision_full_brake_confirm == 3
    bad = subprocess.run([*cli[:6], str(tmp_path / "bad.pt"), "--decision", "mean", "--brake-confirm", "2"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "decision_brake_confirm" in bad.stderr and not (tmp_path / "bad.pt").exists()


def test_a_confirmed_full_brake_ramps_toward_it_until_the_argmax_repeats_it(tmp_path):
    # A phantom full brake is often the argmax for one decision: with full_brake_confirm 2,
    # that decision ramps toward the full brake, and only a second in a row brakes at once.
    rng = np.random.default_rng(6)
    sure = [0.0] * len(FINE_LEVELS)
    sure[EMERGENCY_LEVEL] = 3.0
    calm = [0.0] * len(FINE_LEVELS)
    calm[4] = 2.0
    sure, calm = _fixed_outputs(sure), _fixed_outputs(calm)
    obs = _obs(rng)
    policy = Policy(sure, "mean", FINE_LEVELS, 2.0, full_brake_confirm=2)
    assert policy(obs) == Decision(EMERGENCY_LEVEL, -1.0)  # not yet: the ramp heads for it
    assert policy(obs) == Decision(EMERGENCY_LEVEL)  # the second in a row: at once
    assert policy(obs) == Decision(EMERGENCY_LEVEL)
    policy.reset()
    assert policy(obs).target == -1.0  # a new episode starts the count over
    policy.q = calm
    assert policy(obs).target is not None and policy(obs).action == 4  # another argmax breaks the run
    policy.q = sure
    assert policy(obs).target == -1.0
    held = FineRamp()
    assert held.force_toward(-1.0) == -RAMP_RATE  # through the ramp, not at once
    assert Policy(sure, "mean", FINE_LEVELS, 2.0)(obs) == Decision(EMERGENCY_LEVEL)  # the default: at once
    with pytest.raises(ConfigError) as e:
        Config(**STUDENT, decision="mean", decision_full_brake_confirm=0)
    assert e.value.field == "decision_full_brake_confirm"
    with pytest.raises(ConfigError, match="needs decision 'mean'"):
        Config(**STUDENT, decision_full_brake_confirm=2)
    cfg = Config(**STUDENT, decision="mean")
    save_policy(QNetwork.of(cfg), cfg, tmp_path / "student.pt")
    assert with_decision(tmp_path / "student.pt", tmp_path / "confirmed.pt", "mean", full_brake_confirm=2).decision_full_brake_confirm == 2
    assert load_policy(tmp_path / "confirmed.pt")[1].decision_full_brake_confirm == 2
    assert load_policy(tmp_path / "student.pt")[1].decision_full_brake_confirm == 1
