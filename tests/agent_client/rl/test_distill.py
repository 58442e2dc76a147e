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


@pytest.mark.slow  # over ~5 s alone
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


def _inputs(n: int = 4) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(5)
    frames = torch.from_numpy(rng.integers(0, 256, (n, 8, FRAME_H, FRAME_W), dtype=np.uint8))
    return frames, torch.full((n, 8), 25.0), torch.tensor([0.1, 33.5]).expand(n, 8, 2)


def test_narrowing_to_the_same_widths_is_the_same_network(tmp_path):
    from agent_client.rl.checkpoint import narrow_policy

    q, _ = load_policy(TEACHER)
    narrow_policy(TEACHER, tmp_path / "same.pt", (16, 32, 64), 256)
    same, _ = load_policy(tmp_path / "same.pt")
    with torch.inference_mode():
        assert torch.equal(q(*_inputs()), same(*_inputs()))


@pytest.mark.slow  # over ~5 s alone
def test_narrowing_drops_the_weakest_units_and_the_columns_that_read_them(tmp_path):
    # Units whose weights in and out are zero contribute nothing: cut exactly those, and the
    # narrow network computes what the wide one did (to rounding: fewer terms in each sum).
    from agent_client.rl.checkpoint import narrow_policy, save_policy

    wide, cfg = load_policy(TEACHER)
    dead = {"conv.0": [1, 4, 6, 9, 10, 12, 13, 15], "conv.2": list(range(0, 32, 4)), "conv.4": list(range(1, 64, 2))}
    reads = {"conv.0": "conv.2", "conv.2": "conv.4"}
    with torch.no_grad():
        sd = wide.state_dict()
        for name, units in dead.items():
            sd[f"{name}.weight"][units] = 0.0
            sd[f"{name}.bias"][units] = 0.0
            if name in reads:
                sd[f"{reads[name]}.weight"][:, units] = 0.0
        spatial = (sd["fc.0.weight"].shape[1] - 8 * 3) // 64
        for c in dead["conv.4"]:
            sd["fc.0.weight"][:, c * spatial : (c + 1) * spatial] = 0.0
        hidden_dead = list(range(0, 256, 2))
        sd["fc.0.weight"][hidden_dead] = 0.0
        sd["fc.0.bias"][hidden_dead] = 0.0
        sd["fc.2.weight"][:, hidden_dead] = 0.0
    save_policy(wide, cfg, tmp_path / "wide.pt")
    out = narrow_policy(tmp_path / "wide.pt", tmp_path / "narrow.pt", (8, 24, 32), 128)
    assert (out.conv_channels, out.hidden) == ((8, 24, 32), 128)
    narrow, ncfg = load_policy(tmp_path / "narrow.pt")
    assert ncfg.conv_channels == (8, 24, 32) and narrow.fc[0].weight.shape == (128, 32 * spatial + 24)
    with torch.inference_mode():
        torch.testing.assert_close(narrow(*_inputs()), wide(*_inputs()), rtol=0, atol=1e-5)


def test_narrowing_refuses_a_wider_network_and_an_existing_file(tmp_path):
    (tmp_path / "there.pt").write_bytes(b"")
    for args, words in ((["--conv-channels", "16,64,64", "--hidden", "128"], "narrowing needs each new width from 1"),
                        (["--conv-channels", "8,16,32", "--hidden", "0"], "narrowing needs each new width from 1"),
                        (["--conv-channels", "8,16", "--hidden", "128"], "want three whole numbers such as 8,16,32, got '8,16'"),
                        (["--conv-channels", "8,a,32", "--hidden", "128"], "want three whole numbers such as 8,16,32, got '8,a,32'")):  # fmt: skip
        done = CliRunner().invoke(main, ["checkpoint", "narrow", TEACHER, str(tmp_path / "n.pt"), *args])
        assert done.exit_code == 2 and words in done.stderr
    with pytest.raises(InputFileError, match="exists"):
        from agent_client.rl.checkpoint import narrow_policy

        narrow_policy(TEACHER, tmp_path / "there.pt", (8, 16, 32), 128)
    assert not (tmp_path / "n.pt").exists()
