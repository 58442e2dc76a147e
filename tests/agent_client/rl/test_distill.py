"""Distillation: the network's width as a setting, and a trained policy as the teacher of a
narrower student (``--teacher policy``), which sees what the student sees."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from driving import drive_briefly

from agent_client.actions import make_action_type
from agent_client.errors import InputFileError
from agent_client.preprocess import FRAME_H, FRAME_W
from agent_client.rl.checkpoint import load_policy
from agent_client.rl.config import Config, ConfigError
from agent_client.rl.learner import PolicyTeacher
from agent_client.rl.network import QNetwork
from agent_client.rl.train import train
from agent_client.stacker import FrameStacker
from vacc.cli import main

TEACHER = "models/ice-eco.pt"
NARROW = {"conv_channels": (8, 16, 32), "hidden": 128}


def _student(**changes) -> Config:
    """The shipped ice-eco's settings, taught by its own checkpoint, narrower."""
    _, tcfg = load_policy(TEACHER)
    return Config(**{**dataclasses.asdict(tcfg), "teacher": "policy", "teacher_policy": TEACHER, "init_from": None, **NARROW, **changes})


def test_the_width_is_a_setting_and_the_default_is_the_shipped_networks():
    wide, _ = load_policy(TEACHER)
    default = QNetwork.of(dataclasses.replace(Config(), action="ramp-fine"))
    assert {k: v.shape for k, v in default.state_dict().items()} == {k: v.shape for k, v in wide.state_dict().items()}
    narrow = QNetwork.of(Config(action="ramp-fine", **NARROW))
    assert narrow.conv[0].weight.shape == (8, 8, 5, 5) and narrow.fc[0].out_features == 128 and narrow.fc[-1].in_features == 128
    n = sum(p.numel() for p in narrow.parameters())
    assert 170_000 < n < sum(p.numel() for p in wide.parameters()) / 3.5  # about a quarter of the arithmetic and the weights
    frames = torch.zeros(2, 8, FRAME_H, FRAME_W, dtype=torch.uint8)
    assert narrow(frames, torch.full((2, 8), 20.0), torch.zeros(2, 8, 2)).shape == (2, 21)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"conv_channels": (8, 16)}, "conv_channels"),
        ({"conv_channels": (0, 16, 32)}, "conv_channels"),
        ({"hidden": 0}, "hidden"),
        ({"teacher": "policy"}, "teacher_policy"),
        ({"teacher_policy": TEACHER}, "teacher_policy"),
        ({"teacher": "policy", "teacher_policy": TEACHER, "teacher_lag": 0.5}, "teacher_lag"),
    ],
)
def test_config_refuses_a_bad_width_or_a_teacher_without_its_checkpoint(changes, field):
    with pytest.raises(ConfigError) as e:
        Config(**changes)
    assert e.value.field == field


def test_the_cli_names_the_option_of_a_bad_width():
    result = CliRunner().invoke(main, ["train", "--reward", "eco", "--steps", "10", "--conv-channels", "8,x,32", "--out", "unused"])
    assert result.exit_code == 2 and "--conv-channels" in result.output and "whole numbers" in result.output


def test_a_teacher_that_observes_otherwise_is_refused_in_one_line():
    cfg = _student(zoom=1)
    with pytest.raises(InputFileError, match=r"ice-eco\.pt: the teacher's zoom is 2, the student's 1"):
        PolicyTeacher(cfg)


def test_the_label_is_the_teachers_action_or_the_level_nearest_its_target():
    teacher = PolicyTeacher(_student())
    held, stacker = make_action_type("ramp-fine"), FrameStacker(8, 2)
    rng = np.random.default_rng(0)
    seen_target = seen_action = 0
    for _ in range(40):
        held.u = round(float(rng.uniform(-1, 1)), 2)
        frame = rng.integers(0, 256, (FRAME_H, FRAME_W), dtype=np.uint8)
        obs = stacker.push(frame, float(rng.uniform(0, 33)), held.controls(33.5))
        d, label = teacher.decide(obs, held, 4.0)
        if d.target is None:
            seen_action += 1
            assert label == d.action
        else:
            seen_target += 1
            assert label == held.imitate(d.target, 4.0)
    assert seen_target > 0  # the shipped rule is the mean decision


def test_a_distilled_student_trains_resumes_and_drives(tmp_path):
    cfg = _student(
        train_trajectories=("random", "stopped"), total_steps=120, learning_starts=30, train_every=4, batch_size=8, buffer_size=400,
        teacher_steps=60, episode_seconds=3.0, checkpoint_every=30, eval_every=0, eval_trajectories=("stopped:1",), eval_seconds=1.0,
        log_every=20, torch_threads=1,
    )  # fmt: skip
    train(cfg, tmp_path / "whole", progress=False)
    train(dataclasses.replace(cfg, total_steps=60), tmp_path / "split", progress=False)
    train(cfg, tmp_path / "split", resume=True, progress=False)
    a, b = (torch.load(tmp_path / d / "latest.pt", weights_only=True) for d in ("whole", "split"))
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    assert "losses/teacher_ce" in (tmp_path / "whole" / "scalars.csv").read_text()
    student, scfg = load_policy(tmp_path / "whole" / "best.pt")
    assert tuple(scfg.conv_channels) == (8, 16, 32) and student.fc[0].out_features == 128
    drive_briefly(tmp_path / "whole" / "best.pt", tmp_path / "drive.csv")


def test_init_from_a_network_of_another_width_is_refused_in_one_line(tmp_path):
    result = CliRunner().invoke(
        main, ["train", "--reward", "eco", "--action", "ramp-fine", "--zoom", "2", "--init-from", TEACHER, "--conv-channels", "8,16,32",
               "--hidden", "128", "--steps", "10", "--out", str(tmp_path / "run")],
    )  # fmt: skip
    assert result.exit_code == 1 and result.exception is not None and isinstance(result.exception, SystemExit)
    last = result.output.strip().splitlines()[-1]
    assert "16,32,64 channels and 256 hidden units, this run's 8,16,32 and 128" in last and "--teacher policy" in last
