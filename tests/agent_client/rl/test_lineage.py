"""Lineage by digest: a checkpoint records the SHA-256 of the files it was made from, so a
later step that overwrites one of their paths cannot pass for its parent."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch

from agent_client.errors import InputFileError
from agent_client.rl.checkpoint import (
    file_sha256,
    load_policy,
    make_lineage,
    read_checkpoint,
    save_policy,
)
from agent_client.rl.config import Config
from agent_client.rl.network import QNetwork
from agent_client.rl.train import train

SHIPPED = Path(__file__).resolve().parents[3] / "models"
TINY = Config(
    total_steps=60, learning_starts=20, train_every=4, batch_size=8, buffer_size=200, exploration_steps=40,
    target_sync_every=20, episode_seconds=3.0, checkpoint_every=30, eval_every=30, eval_trajectories=("stopped:1",),
    eval_seconds=1.0, log_every=10,
)  # fmt: skip


def test_the_digest_is_the_files_sha256_and_a_missing_parent_is_one_line(tmp_path):
    path = SHIPPED / "ice-gap.pt"
    assert file_sha256(path) == hashlib.sha256(path.read_bytes()).hexdigest()
    assert make_lineage("average", [path, SHIPPED / "ice-force.pt"]) == {
        "stage": "average", "recipe": None,
        "parents": [{"sha256": file_sha256(path), "path": str(path)}, {"sha256": file_sha256(SHIPPED / "ice-force.pt"), "path": str(SHIPPED / "ice-force.pt")}],
    }  # fmt: skip
    assert make_lineage("train", [path], ["init_from"])["parents"][0]["role"] == "init_from"
    with pytest.raises(InputFileError, match="gone.pt: cannot be read"):
        make_lineage("export", [tmp_path / "gone.pt"])


def test_a_checkpoint_without_a_lineage_still_loads_and_one_with_it_round_trips(tmp_path):
    for path in SHIPPED.glob("*.pt"):  # written before lineage (unknown, not an error), or by its own recipe's last stage
        lineage = read_checkpoint(path).get("lineage")
        assert lineage is None or (lineage["recipe"]["name"], lineage["recipe"]["smoke"]) == (path.stem, False)
        assert load_policy(path)[1].scenario in ("ice", "ev")
    save_policy(QNetwork(), Config(), tmp_path / "plain.pt")
    assert "lineage" not in torch.load(tmp_path / "plain.pt", weights_only=True)
    assert "lineage" not in read_checkpoint(tmp_path / "plain.pt") and load_policy(tmp_path / "plain.pt")[1] == Config()
    lineage = make_lineage("narrow", [SHIPPED / "ice-eco.pt"])
    save_policy(QNetwork(), Config(), tmp_path / "p.pt", lineage=lineage)
    assert read_checkpoint(tmp_path / "p.pt")["lineage"] == lineage  # under the digest: read_checkpoint checked it


@pytest.mark.slow  # three tiny trainings
def test_a_run_records_what_it_started_from_and_keeps_it_when_resumed_after_the_file_changed(tmp_path):
    start = tmp_path / "start.pt"
    torch.manual_seed(0)
    save_policy(QNetwork(), Config(), start)
    digest = file_sha256(start)
    train(Config(**{**TINY.__dict__, "init_from": str(start)}), tmp_path / "run", progress=False)
    expected = {"stage": "train", "parents": [{"sha256": digest, "path": str(start), "role": "init_from"}], "recipe": None}
    for name in ("latest.pt", "best.pt"):
        assert read_checkpoint(tmp_path / "run" / name)["lineage"] == expected, name
    start.unlink()
    save_policy(QNetwork(), Config(), start)  # a later step overwrites the path
    assert file_sha256(start) != digest
    train(Config(**{**TINY.__dict__, "init_from": str(start), "total_steps": 90}), tmp_path / "run", resume=True, progress=False)
    assert read_checkpoint(tmp_path / "run" / "latest.pt")["state"]["global_step"] == 90
    assert read_checkpoint(tmp_path / "run" / "latest.pt")["lineage"] == expected  # what it read, not what the path holds now
    train(Config(**{**TINY.__dict__, "eval_every": 0, "eval_trajectories": ()}), tmp_path / "scratch", progress=False)
    assert read_checkpoint(tmp_path / "scratch" / "latest.pt")["lineage"] == {"stage": "train", "parents": [], "recipe": None}
