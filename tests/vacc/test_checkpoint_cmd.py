"""`vacc checkpoint`: info, config, and the surgery (average, decide, narrow, export) on the
shipped models, each new file recording its parents' SHA-256."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from agent_client.rl.checkpoint import checkpoint_config, read_checkpoint, save_policy
from agent_client.rl.cli import make_config
from agent_client.rl.cli import train as train_command
from agent_client.rl.config import Config, config_dict
from agent_client.rl.network import QNetwork
from vacc.cli import main

CHECKOUT = Path(__file__).resolve().parents[2]
MODELS = CHECKOUT / "models"
SHIPPED = sorted(MODELS.glob("*.pt"))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _vacc(*args: str) -> subprocess.CompletedProcess[str]:
    """``python -m vacc ARGS`` from the checkout, as a user runs it."""
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=180, cwd=CHECKOUT)


def _invoke(*args: str):
    return CliRunner().invoke(main, ["checkpoint", *args])


def test_the_group_lists_its_commands():
    done = _invoke("--help")
    assert done.exit_code == 0
    for name in ("info", "config", "average", "decide", "narrow", "export", "upgrade"):
        assert f"  {name} " in done.output


def test_info_prints_the_digest_size_settings_and_an_unknown_lineage_of_a_shipped_model():
    path = MODELS / "ice-eco.pt"
    done = _invoke("info", str(path))
    assert done.exit_code == 0, done.output
    out = done.output
    assert _sha256(path) in out and f"{path.stat().st_size:,} bytes" in out
    assert "scenario ice, action ramp-fine, reward eco" in out and "conv 16/32/64, hidden 256" in out
    assert "decision mean, temperature 2, brake share 0.05 (confirmed in 3)" in out
    assert "unknown: written before checkpoints recorded their lineage" in out
    assert "recorded source (a path, informative only): tr2/latest.pt" in out
    assert 'scenario = "ice"' in out and "seed = 482" in out  # the whole config
    summary = json.loads(_invoke("info", "--json", str(path)).output)
    assert summary["sha256"] == _sha256(path) and summary["lineage"] is None and summary["step"] == 30000
    assert summary["config"] == json.loads(json.dumps(config_dict(checkpoint_config(read_checkpoint(path), path))))


def test_info_end_to_end_and_a_bad_file_in_one_line(tmp_path):
    done = _vacc("checkpoint", "info", "models/ev-force.pt")
    assert done.returncode == 0 and _sha256(MODELS / "ev-force.pt") in done.stdout and "action levels" in done.stdout, done.stderr
    (tmp_path / "junk.pt").write_bytes(b"junk")
    bad = _invoke("info", str(tmp_path / "junk.pt"))
    assert bad.exit_code == 2 and "junk.pt: not a checkpoint" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_export_decide_narrow_and_average_record_their_parents_digests(tmp_path):
    eco, gap, force = MODELS / "ice-eco.pt", MODELS / "ice-gap.pt", MODELS / "ice-force.pt"
    steps = [
        (["export", str(eco), str(tmp_path / "e.pt")], "export", [eco], "the policy at step 30000"),
        (["decide", str(tmp_path / "e.pt"), str(tmp_path / "d.pt"), "--decision", "mean", "--temperature", "3"], "decide",
         [tmp_path / "e.pt"], "decision mean, temperature 3"),
        (["narrow", str(eco), str(tmp_path / "n.pt"), "--conv-channels", "8,16,32", "--hidden", "64"], "narrow", [eco], "conv 8/16/32, hidden 64"),
        (["average", str(gap), str(force), "--weights", "3,1", "--out", str(tmp_path / "a.pt")], "average", [gap, force], "the weighted mean of 2 policies"),
    ]  # fmt: skip
    for args, stage, parents, said in steps:
        done = _invoke(*args)
        assert done.exit_code == 0 and said in done.output, done.output
        out = Path(args[-1] if stage == "average" else args[2])
        lineage = read_checkpoint(out)["lineage"]
        assert lineage == {"stage": stage, "parents": [{"sha256": _sha256(p), "path": str(p)} for p in parents], "recipe": None}
        shown = _invoke("info", str(out)).output
        assert f"stage    {stage}" in shown and all(f"parent   {_sha256(p)} (was {p})" in shown for p in parents)
    assert [r["share"] for r in read_checkpoint(tmp_path / "a.pt")["extra"]["average_of"]] == [0.75, 0.25]
    # a mean's step is its first source's: said so, with every source's step
    steps = [read_checkpoint(p)["extra"]["step"] for p in (gap, force)]
    assert f"step     {steps[0]} (its first source's: a mean of 2 policies, steps {min(steps)}-{max(steps)})" in _invoke("info", str(tmp_path / "a.pt")).output
    assert f"step     {read_checkpoint(eco)['extra']['step']}\n" in _invoke("info", str(eco)).output
    # exported (as a recipe's swa output is), a mean stays known as one
    assert _invoke("export", str(tmp_path / "a.pt"), str(tmp_path / "ae.pt")).exit_code == 0
    assert "a mean of 2 policies" in _invoke("info", str(tmp_path / "ae.pt")).output


@pytest.mark.slow  # four processes, each importing torch
def test_the_surgery_end_to_end(tmp_path):
    """One `python -m vacc checkpoint` run per surgery command, as the docs call them."""
    runs = {
        "average": (["average", "models/ev-gap.pt", "models/ev-force.pt", "--out", str(tmp_path / "a.pt")], "the mean of 2 policies"),
        "decide": (["decide", "models/ev-eco.pt", str(tmp_path / "d.pt"), "--decision", "mean", "--temperature", "2"], "decision mean, temperature 2"),
        "narrow": (["narrow", "models/ev-eco.pt", str(tmp_path / "n.pt"), "--conv-channels", "4,8,8", "--hidden", "32"], "conv 4/8/8, hidden 32"),
        "export": (["export", "models/ev-eco.pt", str(tmp_path / "x.pt")], "the policy at step 100449"),
    }
    for name, (args, said) in runs.items():
        done = _vacc("checkpoint", *args)
        assert done.returncode == 0 and said in done.stdout, (name, done.stderr)
    assert read_checkpoint(tmp_path / "n.pt")["lineage"]["parents"] == [{"sha256": _sha256(MODELS / "ev-eco.pt"), "path": "models/ev-eco.pt"}]
    again = _vacc("checkpoint", "export", "models/ev-eco.pt", str(tmp_path / "x.pt"))
    assert again.returncode == 2 and "exists" in again.stderr and len(again.stderr.strip().splitlines()) == 1


def test_average_weights_are_one_comma_separated_list(tmp_path):
    done = _invoke("average", str(MODELS / "ice-gap.pt"), str(MODELS / "ice-force.pt"), "--weights", "3,x", "--out", str(tmp_path / "a.pt"))
    assert done.exit_code == 2 and "want numbers such as 3,1,1, got '3,x'" in done.stderr
    assert not (tmp_path / "a.pt").exists()


def _train_config(config_json: Path, out: Path, *extra: str) -> Config:
    """The Config `vacc train --config CONFIG_JSON` would run with: click's own parsing and
    the command's own make_config, without training."""
    with train_command.make_context("train", ["--config", str(config_json), "--out", str(out), *extra]) as ctx:
        return make_config(ctx.params)


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_config_writes_what_vacc_train_config_reads_back(path, tmp_path, monkeypatch):
    monkeypatch.chdir(CHECKOUT)  # the shipped models' init_from paths are relative to it
    out = tmp_path / "config.json"
    done = _invoke("config", str(path), "--out", str(out))
    assert done.exit_code == 0 and f"vacc train --config {out}" in done.output, done.output
    saved = checkpoint_config(read_checkpoint(path), path)
    extra = [] if saved.init_from is None or Path(saved.init_from).is_file() else ["--init-from", str(path)]
    assert ("does not exist here" in done.stderr) == bool(extra)
    expected = saved if not extra else dataclasses.replace(saved, init_from=str(path))
    assert _train_config(out, tmp_path / "run", *extra) == expected
    assert json.loads(out.read_text()) == json.loads(json.dumps(dataclasses.asdict(saved)))


def test_config_notes_a_file_setting_that_is_not_here_and_refuses_an_existing_file(tmp_path):
    cfg = Config(init_from=str(tmp_path / "gone.pt"))
    save_policy(QNetwork.of(cfg), cfg, tmp_path / "p.pt")
    done = _invoke("config", str(tmp_path / "p.pt"), "--out", "-")
    assert done.exit_code == 0 and json.loads(done.stdout)["init_from"] == str(tmp_path / "gone.pt")
    assert f"note: init_from {tmp_path / 'gone.pt'} does not exist here; give --init-from FILE to vacc train" in done.stderr
    (tmp_path / "there.json").write_text("{}")
    again = _invoke("config", str(tmp_path / "p.pt"), "--out", str(tmp_path / "there.json"))
    assert again.exit_code == 2 and "exists" in again.stderr and (tmp_path / "there.json").read_text() == "{}"


def test_config_end_to_end_and_train_refuses_a_checkpoint_as_config_in_one_line(tmp_path):
    done = _vacc("checkpoint", "config", "models/ice-force.pt", "--out", str(tmp_path / "c.json"))
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "c.json").read_text())["reward"] == "force"
    bad = CliRunner().invoke(main, ["train", "--config", str(MODELS / "ice-eco.pt"), "--out", str(tmp_path / "run")])
    assert bad.exit_code == 2
    error = [line for line in bad.stderr.splitlines() if line.startswith("Error")]
    assert len(error) == 1 and f"vacc checkpoint config {MODELS / 'ice-eco.pt'} --out config.json" in error[0]
    assert not (tmp_path / "run").exists()
