"""Learning from a privileged teacher (DAgger): labels through the action types, the
cross-entropy update, and a teacher run end to end."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from driving import drive_briefly

from agent_client.actions import (
    ACTION_TYPES,
    EMERGENCY_LEVEL,
    RAMP_RATE,
    FineRamp,
    ForceRamp,
    is_continuous,
    make_action_type,
)
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.learner import Learner
from agent_client.rl.replay import ReplayMemory
from agent_client.rl.train import train
from agent_client.stacker import FrameStacker
from protocol.constants import FORCES
from vacc.cli import main


def _held(kind: str, held: float):
    t = make_action_type(kind)
    if kind != "levels":
        t.u = held
    return t


def _next_force(kind: str, held: float, action: int) -> float:
    return _held(kind, held).force(action)


@pytest.mark.parametrize("kind", [k for k in ACTION_TYPES if not is_continuous(k)])  # a teacher labels discrete actions
def test_the_label_is_the_action_whose_force_is_nearest_the_teachers(kind):
    rng = np.random.default_rng(0)
    for _ in range(300):
        held, u = round(float(rng.uniform(-1, 1)), 2), float(rng.uniform(-1, 1))
        t = _held(kind, held)
        label = t.imitate(u)
        assert kind == "levels" or t.u == held  # labelling changes nothing
        best = min(abs(_next_force(kind, held, a) - u) for a in range(t.n))
        assert abs(_next_force(kind, held, label) - u) == pytest.approx(best, abs=1e-9)


def test_the_ramp_label_brakes_at_once_only_where_the_teacher_brakes_hard():
    ramp = ForceRamp()
    assert ramp.imitate(-0.9) == EMERGENCY_LEVEL  # from 0, the ramp would reach -0.04
    assert FORCES[ramp.imitate(-0.3)] == pytest.approx(-0.3)  # a ramp toward the teacher's level
    assert FORCES[ramp.imitate(0.02)] in (0.0, 0.1) and abs(_next_force("ramp", 0.0, ramp.imitate(0.02)) - 0.02) <= RAMP_RATE / 2


def test_the_fine_ramp_holds_the_small_forces_of_steady_following():
    """The paper's levels can hold only multiples of 0.1, so a student of the ACC (steady
    forces of 0.01-0.06) pulses; the fine ramp reaches and holds 0.02 and -0.05."""
    fine, coarse = FineRamp(), ForceRamp()
    assert fine.levels[EMERGENCY_LEVEL] == -1.0 and fine.levels[-1] == 1.0 and len(fine.levels) == len(FORCES)
    assert list(fine.levels) == sorted(fine.levels)
    for u in (0.02, -0.05):
        for t in (fine, coarse):
            t.reset()
            for _ in range(5):
                t.force(t.imitate(u))
        assert fine.u == pytest.approx(u)  # held exactly, step after step
        assert coarse.u != pytest.approx(u)  # the paper's levels cannot hold it
    fine.reset()
    assert fine.force(EMERGENCY_LEVEL) == -1.0  # the full brake still acts at once


def test_config_checks_the_teacher():
    with pytest.raises(ConfigError, match="servers=1") as e:
        Config(teacher="acc", servers=2)
    assert e.value.field == "teacher"
    for bad in ({"teacher": "acc", "teacher_lag": -0.1}, {"teacher": "acc", "teacher_lag": float("nan")}, {"teacher_lag": 0.5}):
        with pytest.raises(ConfigError) as e:
            Config(**bad)
        assert e.value.field == "teacher_lag"
    result = CliRunner().invoke(main, ["train", "--reward", "eco", "--steps", "10", "--teacher", "hdm", "--out", "unused"])
    assert result.exit_code == 2 and "--teacher" in result.output


def test_the_teacher_update_learns_the_labels(tmp_path):
    """Cross-entropy to the stored labels: after a few steps the network answers them (a TD update would not)."""
    cfg = Config(reward="eco", action="ramp", teacher="acc", total_steps=10, batch_size=16, learning_rate=1e-3, torch_threads=1)
    learner = Learner(cfg, tmp_path, trainer="single")
    memory, stacker = ReplayMemory(64, 8, 1, n_controls=2), FrameStacker(8, 1)
    rng = np.random.default_rng(0)
    obs = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0, np.array([0.0, 30.0], np.float32))
    memory.start(obs)
    label = 17  # whatever the state, the teacher says +0.7 (rewards are all 0: nothing to bootstrap)
    for _ in range(40):
        obs = stacker.push(rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8), 20.0, np.array([0.0, 30.0], np.float32))
        memory.add(label, 0.0, False, False, obs)
    for _ in range(40):
        learner.update(memory.sample(16, rng, 1, 0.99))
    b = memory.sample(16, rng, 1, 0.99)
    with torch.no_grad():
        assert (learner.q(b.frames, b.speeds, b.controls).argmax(1) == label).all()
    learner.close()


def _brake_share(tmp_path, brake_weight: float) -> float:
    """The student's share of the full brake against throttle (ramp-fine level 17, +0.45) after
    learning one state labelled half each (a torn teacher)."""
    cfg = Config(reward="eco", action="ramp-fine", teacher="eco-margin", total_steps=10, batch_size=16, learning_rate=1e-3,
                 torch_threads=1, brake_weight=brake_weight)  # fmt: skip
    learner = Learner(cfg, tmp_path / str(brake_weight), trainer="single")
    memory, stacker = ReplayMemory(64, 8, 1, n_controls=2), FrameStacker(8, 1)
    frame = np.random.default_rng(0).integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8)
    obs = stacker.push(frame, 20.0, np.array([0.0, 30.0], np.float32))
    memory.start(obs)
    for i in range(40):
        memory.add(EMERGENCY_LEVEL if i % 2 else 17, 0.0, False, False, stacker.push(frame, 20.0, np.array([0.0, 30.0], np.float32)))
    rng = np.random.default_rng(1)
    for _ in range(150):
        learner.update(memory.sample(16, rng, 1, 0.99))
    b = memory.sample(1, rng, 1, 0.99)
    with torch.no_grad():
        p = torch.softmax(learner.q(b.frames, b.speeds, b.controls), 1)[0]
    learner.close()
    return float(p[EMERGENCY_LEVEL] / (p[EMERGENCY_LEVEL] + p[17]))


@pytest.mark.slow  # over ~5 s alone
def test_the_brake_weight_tilts_a_torn_label_toward_the_full_brake(tmp_path):
    """Weighted cross-entropy's optimum on a state labelled brake and throttle equally is
    w / (w + 1) on the brake: 1/2 unweighted, 4/5 at weight 4."""
    plain, weighted = _brake_share(tmp_path, 1.0), _brake_share(tmp_path, 4.0)
    assert plain == pytest.approx(0.5, abs=0.15)  # measured 0.55
    assert weighted == pytest.approx(0.8, abs=0.1) and weighted > plain + 0.2  # measured 0.87
    with pytest.raises(ConfigError, match="> 0") as e:
        Config(teacher="acc", brake_weight=0.0)
    assert e.value.field == "brake_weight"
    with pytest.raises(ConfigError, match="needs a teacher") as e:
        Config(brake_weight=4.0)  # no teacher: nothing to weight
    assert e.value.field == "brake_weight"


def test_a_lagged_teachers_view_starts_over_with_each_episode(tmp_path, monkeypatch):
    import agent_client.rl.learner as learner_module
    from agent_client.controllers.acc import LateClosing

    firsts: list[tuple[float, float]] = []  # (the closing speed as seen, as it is) at each episode's first label

    class Recorded(LateClosing):
        def __call__(self, obs):
            fresh = self._seen is None
            u = super().__call__(obs)
            if fresh:
                firsts.append((self._seen, obs["v_host"] - obs["v_lead"]))
            return u

    monkeypatch.setattr(learner_module, "LateClosing", Recorded)
    cfg = Config(
        reward="eco", action="ramp", teacher="acc-55-calm", teacher_lag=0.5, teacher_steps=60, train_trajectories=("random", "catch-up"),
        total_steps=90, learning_starts=30, train_every=4, batch_size=8, buffer_size=400, episode_seconds=3.0, checkpoint_every=10**6,
        eval_every=0, eval_trajectories=("stopped:1",), log_every=20,
    )  # fmt: skip
    summary = train(cfg, tmp_path / "run", progress=False)
    assert len(firsts) == summary["episodes"] == 3  # one fresh view per episode
    assert all(seen == closing for seen, closing in firsts)


def test_a_teacher_run_resumes_exactly_and_its_student_drives(tmp_path):
    cfg = Config(
        reward="eco", action="ramp", teacher="acc", teacher_steps=60, train_trajectories=("random", "stopped"), total_steps=120,
        learning_starts=30, train_every=4, batch_size=8, buffer_size=400, start_e=0.05, end_e=0.05, episode_seconds=3.0,
        checkpoint_every=30, eval_every=0, eval_trajectories=("stopped:1",), eval_seconds=1.0, log_every=20,
    )  # fmt: skip
    train(cfg, tmp_path / "whole", progress=False)
    train(Config(**{**cfg.__dict__, "total_steps": 60}), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = (torch.load(tmp_path / d / "latest.pt", weights_only=True) for d in ("whole", "split"))
    assert a["rng"]["numpy"] == b["rng"]["numpy"]
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    scalars = (tmp_path / "whole" / "scalars.csv").read_text()
    assert "losses/teacher_ce" in scalars and "losses/td_loss" not in scalars
    drive_briefly(tmp_path / "whole" / "best.pt", tmp_path / "drive.csv")


def test_the_teachers_are_the_acc_law_with_its_time_gap_or_the_papers_55_m():
    from agent_client.controllers.acc import AccController
    from agent_client.rl.config import TEACHERS
    from agent_client.rl.learner import make_teacher

    assert make_teacher("none") is None
    assert make_teacher("acc") == AccController()
    fixed = make_teacher("acc-55")
    assert [fixed.reference_gap(v) for v in (0.0, 10.0, 30.0)] == [55.0] * 3
    assert [AccController().reference_gap(v) for v in (0.0, 10.0, 30.0)] == [5.0, 18.0, 54.0]
    # at the 55 m target and the lead's speed, neither teacher asks for any force
    obs = {"gap": 55.0, "v_host": 30.0, "v_lead": 30.0, "a_lead": 0.0, "set_speed": 33.5}
    assert fixed(obs) == 0.0
    assert make_teacher("eco")(obs) == 0.0
    with pytest.raises(ValueError, match="PolicyTeacher"):
        make_teacher("policy")  # a network, not a law: it needs its checkpoint
    assert set(TEACHERS) == {"none", "policy", "acc", "acc-55", "acc-55-gentle", "acc-55-gentle-margin", "acc-55-eco", "acc-55-eco-margin",
                             "acc-55-calm", "acc-55-calm-margin", "acc-55-calmer", "acc-55-calmer-margin",
                             "eco", "eco-margin", "eco-mid", "eco-mid-margin", "eco-firm", "eco-firm-margin", "platoon", "platoon-calm"}  # fmt: skip


def test_the_gentle_55_m_teacher_caps_its_braking_but_not_its_collision_avoidance():
    from agent_client.actions import accel_of_force
    from agent_client.rl.learner import make_teacher

    gentle, acc55 = make_teacher("acc-55-gentle"), make_teacher("acc-55")
    assert gentle.reference_gap(10.0) == 55.0
    # 27.7 m behind a lead at the same speed: acc-55 brakes at 8 m/s^2, the gentle law at its 3
    opening = {"gap": 27.7, "v_host": 14.0, "v_lead": 14.0, "a_lead": 0.0, "set_speed": 33.5}
    assert accel_of_force(acc55(opening)) < -5.0
    assert accel_of_force(gentle(opening)) == pytest.approx(-3.0)
    # closing fast on a standing car: the collision-avoidance limit brakes beyond the cap
    closing = {"gap": 25.0, "v_host": 15.0, "v_lead": 0.0, "a_lead": 0.0, "set_speed": 33.5}
    assert accel_of_force(gentle(closing)) < -4.5


def test_the_eco_55_m_teacher_matches_the_leads_speed_harder_than_the_gentle_one():
    from agent_client.actions import accel_of_force
    from agent_client.rl.learner import make_teacher

    gentle, eco55 = make_teacher("acc-55-gentle"), make_teacher("acc-55-eco")
    assert eco55.reference_gap(20.0) == 55.0 and eco55.decel_cap == gentle.decel_cap
    at_gap = {"gap": 55.0, "v_host": 20.0, "v_lead": 20.5, "a_lead": 0.0, "set_speed": 33.5}
    assert accel_of_force(eco55(at_gap)) == pytest.approx(1.5 * accel_of_force(gentle(at_gap)))  # gamma 3.0 against 2.0
    opening = {"gap": 27.7, "v_host": 14.0, "v_lead": 14.0, "a_lead": 0.0, "set_speed": 33.5}
    assert accel_of_force(eco55(opening)) == pytest.approx(-3.0)  # the same cap


def test_the_calm_55_m_teachers_answer_the_gap_and_the_leads_speed_more_gently_with_the_same_cap():
    from agent_client.actions import accel_of_force
    from agent_client.rl.learner import make_teacher

    gentle, calm, calmer = make_teacher("acc-55-gentle"), make_teacher("acc-55-calm"), make_teacher("acc-55-calmer")
    assert calm.reference_gap(20.0) == calmer.reference_gap(20.0) == 55.0 and calm.decel_cap == calmer.decel_cap == gentle.decel_cap
    faster_lead = {"gap": 55.0, "v_host": 20.0, "v_lead": 20.5, "a_lead": 0.0, "set_speed": 33.5}
    assert accel_of_force(calm(faster_lead)) == pytest.approx(0.75 * accel_of_force(gentle(faster_lead)))  # gamma 1.5 against 2.0
    assert accel_of_force(calmer(faster_lead)) == pytest.approx(accel_of_force(calm(faster_lead)))
    far = {"gap": 57.0, "v_host": 20.0, "v_lead": 20.0, "a_lead": 0.0, "set_speed": 33.5}
    assert accel_of_force(calmer(far)) == pytest.approx(accel_of_force(calm(far)) * 0.25 / 0.3)  # beta 0.25 against 0.3
    assert accel_of_force(calm(far)) == pytest.approx(accel_of_force(gentle(far)) * 0.3 / 0.4)
    assert make_teacher("acc-55-calm-margin").d_safe == make_teacher("acc-55-gentle-margin").d_safe == 8.0  # stops as far back


def test_a_lagged_teacher_is_its_law_seeing_the_closing_speed_late():
    from agent_client.controllers.acc import LateClosing
    from agent_client.rl.learner import make_teacher

    late = make_teacher("acc-55-calm-margin", lag=0.5)
    assert isinstance(late, LateClosing) and late.law == make_teacher("acc-55-calm-margin") and late.lag == 0.5
    assert make_teacher("acc-55-calm", lag=0.0) == make_teacher("acc-55-calm")


def test_the_firm_eco_teacher_opens_a_short_gap_faster_on_the_same_desired_gap():
    from agent_client.rl.learner import make_teacher

    eco, mid, firm = make_teacher("eco"), make_teacher("eco-mid"), make_teacher("eco-firm")
    for v in (5.0, 20.0, 30.0):
        assert firm.reference_gap(v) == mid.reference_gap(v) == eco.reference_gap(v)
    close = {"gap": 27.7, "v_host": 28.2, "v_lead": 30.0, "a_lead": 0.0, "set_speed": 33.5}
    assert firm(close) < mid(close) < eco(close) < 0.0
    at_gap = {"gap": 55.0, "v_host": 30.0, "v_lead": 30.0, "a_lead": 0.0, "set_speed": 33.5}
    assert firm(at_gap) == mid(at_gap) == eco(at_gap) == 0.0
    assert make_teacher("eco-mid-margin").reference_gap(0.0) == make_teacher("eco-margin").reference_gap(0.0)


def test_the_margin_teacher_follows_as_the_eco_teacher_but_stops_further_back():
    from agent_client.rl.learner import make_teacher

    eco, margin = make_teacher("eco"), make_teacher("eco-margin")
    following = {"gap": 48.0, "v_host": 30.0, "v_lead": 29.0, "a_lead": 0.0, "set_speed": 33.5}
    assert margin(following) == eco(following)  # on the road, the same law
    # 6 m behind a standing car at 3 m/s: the eco teacher (aiming at 5 m) brakes gently, the margin one (8 m) hard
    standing = {"gap": 6.0, "v_host": 3.0, "v_lead": 0.0, "a_lead": 0.0, "set_speed": 33.5}
    assert margin(standing) < eco(standing) < 0.0
    assert margin.reference_gap(0.0) == 8.0 and eco.reference_gap(0.0) == 5.0
    gentle, gentle_margin = make_teacher("acc-55-gentle"), make_teacher("acc-55-gentle-margin")
    assert gentle_margin(following) == gentle(following)
    slower = {"gap": 10.0, "v_host": 16.0, "v_lead": 8.0, "a_lead": 0.0, "set_speed": 33.5}
    assert gentle_margin(slower) < gentle(slower) < 0.0  # aiming 6 m behind a slower car, not 3 m


def test_the_full_brake_is_a_label_only_where_the_teacher_brakes_beyond_iso_comfort():
    from agent_client.rl.config import config_dict, config_from

    ramp = ForceRamp()
    moderate = -3.2 / 5.5  # 3.2 m/s^2: the full brake is nearer, but its release would overshoot the teacher
    assert ramp.imitate(moderate) == EMERGENCY_LEVEL  # hard_brake 0: the nearest force
    assert FORCES[ramp.imitate(moderate, hard_brake=3.5)] == pytest.approx(-0.6)  # a ramp toward it
    assert ramp.imitate(-4.0 / 5.5, hard_brake=3.5) == EMERGENCY_LEVEL  # beyond 3.5 m/s^2: at once
    old = config_dict(Config(teacher="acc"))
    del old["teacher_brake"]  # a teacher run from before the setting: the nearest force, as it was
    assert config_from(old, "x").teacher_brake == 0.0
    assert Config().teacher_brake == 3.5
    with pytest.raises(ConfigError, match=">= 0"):
        Config(teacher_brake=-1.0)


def test_the_eco_teacher_aims_at_the_eco_rewards_desired_gap():
    from agent_client.rewards import eco_desired_gap
    from agent_client.rl.learner import make_teacher

    eco, acc = make_teacher("eco"), make_teacher("acc")
    for v in np.linspace(0.0, 40.0, 81):
        assert eco.reference_gap(float(v)) == pytest.approx(eco_desired_gap(float(v)))
    # gentler than the ACC where the gap is short of its target: a smaller brake, the same sign
    obs = {"gap": 30.0, "v_host": 30.0, "v_lead": 30.0, "a_lead": 0.0, "set_speed": 33.5}
    assert acc(obs) < eco(obs) < 0.0


def test_the_teacher_registry_is_the_one_source_of_the_names_and_the_laws():
    from agent_client.rl.config import TEACHERS
    from agent_client.rl.teachers import MARGIN_GAPS, REGISTRY, teacher_law

    assert TEACHERS == tuple(REGISTRY)
    for name, t in REGISTRY.items():
        assert t.name == name and t.about and "\n" not in t.about
        if t.gap is None:
            with pytest.raises(ValueError, match="not an ACC law"):
                teacher_law(name)
            continue
        law = teacher_law(name)
        assert (law.d_safe, law.d_min) == (MARGIN_GAPS if name.endswith("-margin") else (5.0, 3.0))
        if name.endswith("-margin"):  # the same law as its plain entry, further back
            plain = teacher_law(name.removesuffix("-margin"))
            assert dataclasses.replace(law, d_safe=plain.d_safe, d_min=plain.d_min) == plain
    with pytest.raises(ValueError, match="not one of"):
        teacher_law("acc-margin")


def test_every_teacher_has_its_row_in_the_docs_table():
    from pathlib import Path

    from agent_client.rl.teachers import REGISTRY

    docs = (Path(__file__).parents[3] / "docs" / "training.md").read_text()
    for name, t in REGISTRY.items():
        assert f"| `{name}` |" in docs and t.about in docs, name
