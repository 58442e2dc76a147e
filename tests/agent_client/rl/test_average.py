"""Averaging policies (a model soup): the mean of the weights of fine-tunes from one start,
refused for policies that see or act differently; nothing saved is overwritten."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from agent_client.errors import InputFileError
from agent_client.rl.checkpoint import average_policies, load_policy, read_checkpoint, save_policy
from agent_client.rl.config import Config
from agent_client.rl.network import QNetwork


def _policies(tmp_path, n: int, cfg: Config | None = None) -> list:
    cfg = cfg or Config(zoom=2)
    paths = []
    for i in range(n):
        torch.manual_seed(i)
        path = tmp_path / f"p{i}.pt"
        save_policy(QNetwork.of(cfg), cfg, path, {"step": 1000 * (i + 1)})
        paths.append(path)
    return paths


@pytest.mark.slow  # over ~5 s alone
def test_the_average_is_the_elementwise_mean_of_the_weights_and_keeps_the_sources(tmp_path):
    srcs = _policies(tmp_path, 3)
    before = [p.read_bytes() for p in srcs]
    cfg = average_policies(srcs, tmp_path / "soup.pt")
    assert cfg.zoom == 2
    soup, soup_cfg = load_policy(tmp_path / "soup.pt")
    assert soup_cfg == load_policy(srcs[0])[1]
    nets = [load_policy(p)[0].state_dict() for p in srcs]
    for key, value in soup.state_dict().items():
        by_hand = (nets[0][key].double() + nets[1][key].double() + nets[2][key].double()) / 3
        torch.testing.assert_close(value, by_hand.float(), rtol=0, atol=1e-7)
    assert [p.read_bytes() for p in srcs] == before
    recorded = read_checkpoint(tmp_path / "soup.pt")["extra"]["average_of"]
    assert [(r["path"], r["step"]) for r in recorded] == [(str(p), 1000 * (i + 1)) for i, p in enumerate(srcs)]
    assert [r["sha256"] for r in recorded] == [read_checkpoint(p)["sha256"] for p in srcs]
    assert [r["share"] for r in recorded] == pytest.approx([1 / 3] * 3)


def test_weights_give_a_weighted_mean_normalised_to_one(tmp_path):
    srcs = _policies(tmp_path, 3)
    average_policies(srcs, tmp_path / "weighted.pt", [1.0, 2.0, 1.0])
    soup = load_policy(tmp_path / "weighted.pt")[0].state_dict()
    nets = [load_policy(p)[0].state_dict() for p in srcs]
    for key, value in soup.items():
        by_hand = 0.25 * nets[0][key].double() + 0.5 * nets[1][key].double() + 0.25 * nets[2][key].double()
        torch.testing.assert_close(value, by_hand.float(), rtol=0, atol=1e-7)
    recorded = read_checkpoint(tmp_path / "weighted.pt")["extra"]["average_of"]
    assert [r["share"] for r in recorded] == pytest.approx([0.25, 0.5, 0.25])
    for bad, says in (([1.0], "1 weights for 3 policies"), ([1.0, 0.0, 1.0], "finite and positive"),
                      ([1.0, -1.0, 1.0], "finite and positive"), ([1.0, float("nan"), 1.0], "finite and positive")):
        with pytest.raises(InputFileError, match=says):
            average_policies(srcs, tmp_path / "bad.pt", bad)
    assert not (tmp_path / "bad.pt").exists()


def test_policies_that_see_or_act_differently_or_a_lone_one_or_an_existing_file_are_refused(tmp_path):
    a, b = _policies(tmp_path, 2)
    other = tmp_path / "zoom1.pt"
    save_policy(QNetwork.of(Config(zoom=1)), Config(zoom=1), other)
    with pytest.raises(InputFileError, match=r"zoom1\.pt: zoom is 1, .*p0\.pt's is 2"):
        average_policies([a, other], tmp_path / "x.pt")
    steps = tmp_path / "steps.pt"
    save_policy(QNetwork.of(Config(zoom=2, action="steps")), Config(zoom=2, action="steps"), steps)
    with pytest.raises(InputFileError, match="action is 'steps'"):
        average_policies([a, steps], tmp_path / "x.pt")
    gap_head = tmp_path / "aux.pt"
    save_policy(QNetwork.of(Config(zoom=2, aux_gap=0.1)), Config(zoom=2, aux_gap=0.1), gap_head)
    with pytest.raises(InputFileError, match=r"aux\.pt: its layers differ from .*p0\.pt"):
        average_policies([a, gap_head], tmp_path / "x.pt")
    with pytest.raises(InputFileError, match=r"p0\.pt: the same policy is given twice"):
        average_policies([a, b, a], tmp_path / "x.pt")
    with pytest.raises(InputFileError, match="at least two"):
        average_policies([a], tmp_path / "x.pt")
    assert not (tmp_path / "x.pt").exists()
    kept = b.read_bytes()
    with pytest.raises(InputFileError, match="exists"):
        average_policies([a, tmp_path / "p0.pt"], b)
    assert b.read_bytes() == kept


def test_the_command_line_averages_and_says_what_was_wrong_in_one_line(tmp_path):
    a, b = _policies(tmp_path, 2)
    cli = [sys.executable, "-m", "vacc", "checkpoint", "average"]
    done = subprocess.run([*cli, str(a), str(b), "--out", str(tmp_path / "soup.pt")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "the mean of 2 policies" in done.stdout
    assert load_policy(tmp_path / "soup.pt")[1].zoom == 2
    done = subprocess.run([*cli, str(a), str(b), "--weights", "3,1", "--out", str(tmp_path / "w.pt")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "the weighted mean of 2 policies" in done.stdout
    assert [r["share"] for r in read_checkpoint(tmp_path / "w.pt")["extra"]["average_of"]] == [0.75, 0.25]
    done = subprocess.run([*cli, str(a), str(b), "--weights", "1", "--out", str(tmp_path / "z.pt")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "1 weights for 2 policies" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    done = subprocess.run([*cli, str(a), str(tmp_path / "junk.pt"), "--out", str(tmp_path / "y.pt")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "junk.pt: not a checkpoint" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "y.pt").exists()
