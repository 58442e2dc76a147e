"""`vacc train --out DIR --resume`: the run's config.json gives the settings, a change that
would break the bit-exact resume is refused, and a resume that fails changes nothing."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from vacc.cli import main

# A tiny run: 4 episodes of 10 steps, a checkpoint at 20 and 40, one evaluation at the end (best.pt).
TINY_ARGS = [
    "--reward", "gap", "--steps", "40", "--learning-starts", "10", "--train-every", "4", "--batch-size", "8",
    "--buffer-size", "200", "--exploration-steps", "30", "--target-sync-every", "20", "--episode-seconds", "1",
    "--checkpoint-every", "20", "--eval-every", "0", "--eval-trajectories", "test-1", "--eval-seconds", "1",
    "--log-every", "10", "--quiet",
]  # fmt: skip


def _invoke(*args: str):
    return CliRunner().invoke(main, ["train", *args])


def _one_line_refusal(result) -> str:
    """The refusal's line; fails on a traceback, rc 0 or a message of several lines."""
    assert result.exit_code not in (0, None), result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)  # not an uncaught error
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    return lines[0]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("resume") / "run"
    result = _invoke(*TINY_ARGS, "--out", str(run))
    assert result.exit_code == 0, result.output
    return run


def test_resume_reads_the_runs_config_and_given_options_override(tmp_path, tiny_run):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    # Before: `Missing option '--reward'`. A resumable change (the step budget) is allowed.
    result = _invoke("--out", str(run), "--resume", "--steps", "50", "--quiet")
    assert result.exit_code == 0, result.output
    assert "trained 50 steps" in result.output
    saved = json.loads((run / "config.json").read_text())
    assert saved["total_steps"] == 50 and saved["reward"] == "gap" and saved["buffer_size"] == 200
    assert torch.load(run / "latest.pt", weights_only=True)["state"]["global_step"] == 50


@pytest.mark.parametrize(("option", "value"), [("--gamma", "0.9"), ("--reward", "force"), ("--episode-seconds", "2")])
def test_resume_refuses_a_change_that_breaks_the_bit_exact_resume_naming_it(tmp_path, tiny_run, option, value):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    before = _snapshot(run)
    line = _one_line_refusal(_invoke("--out", str(run), "--resume", option, value))
    assert option in line and "--steps" in line  # the setting, and what may change
    assert _snapshot(run) == before
    # the same value as the run's is no change
    same = {"--gamma": "0.99", "--reward": "gap", "--episode-seconds": "1"}[option]
    assert "differs" not in _invoke("--out", str(run), "--resume", option, same, "--steps", "40").output


def test_resume_of_a_folder_without_a_run_is_one_line(tmp_path):
    line = _one_line_refusal(_invoke("--out", str(tmp_path / "none"), "--resume"))
    assert "none" in line and "latest.pt" in line
    assert not (tmp_path / "none").exists()


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _empty(p: Path) -> None:
    p.write_bytes(b"")


def _zero(p: Path) -> None:
    p.write_bytes(bytes(p.stat().st_size))


def _flip(p: Path) -> None:
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF
    p.write_bytes(bytes(data))


def _delete(p: Path) -> None:
    p.unlink()


DAMAGES = {"truncated": _truncate, "emptied": _empty, "zeroed": _zero, "flipped": _flip, "deleted": _delete}
# What a resume reads. summary.json and TensorBoard's events are outputs a resume never reads.
RESUME_READS = ("config.json", "latest.pt", "replay-*.npz", "scalars.csv", "best.pt")


def test_the_tiny_run_holds_every_file_a_resume_reads(tiny_run):
    for pattern in RESUME_READS:
        assert len(list(tiny_run.glob(pattern))) == 1, pattern


@pytest.mark.parametrize("damage", DAMAGES)
@pytest.mark.parametrize("pattern", RESUME_READS)
def test_a_damaged_run_folder_is_refused_in_one_line_and_left_byte_identical(tmp_path, tiny_run, pattern, damage):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    [victim] = run.glob(pattern)
    DAMAGES[damage](victim)
    before = _snapshot(run)
    line = _one_line_refusal(_invoke("--out", str(run), "--resume", "--steps", "60"))
    assert victim.name in line, line  # it names the damaged file
    assert _snapshot(run) == before  # every file's bytes, and the set of files


def test_a_junk_config_json_is_refused_not_overwritten(tmp_path, tiny_run):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    (run / "config.json").write_text('{"reward": "gap", "gamma": "lots"')
    before = _snapshot(run)
    line = _one_line_refusal(_invoke("--out", str(run), "--resume"))
    assert "config.json" in line
    assert _snapshot(run) == before
    # a config.json that parses but disagrees with latest.pt is refused too, naming the setting
    (run / "config.json").write_text(json.dumps({**json.loads((tiny_run / "config.json").read_text()), "gamma": 0.9}))
    before = _snapshot(run)
    line = _one_line_refusal(_invoke("--out", str(run), "--resume"))
    assert "gamma" in line and "latest.pt" in line
    assert _snapshot(run) == before


def test_a_full_disk_during_training_says_so_and_names_the_file(tmp_path, monkeypatch):
    def short_write(obj, f, *args, **kwargs):  # torch.save's words for a full disk
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 2048 vs 1024")

    monkeypatch.setattr(torch, "save", short_write)
    run = tmp_path / "run"
    line = _one_line_refusal(_invoke(*TINY_ARGS, "--out", str(run)))
    assert line == f"Error: {run / 'latest.pt'}: could not be written: no space left on device; the previous file is kept"
