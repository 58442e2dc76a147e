"""The card `vacc drive` writes beside its run log: the episode, the road and who drove."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from agent_client.cli import drive
from agent_client.errors import InputFileError
from agent_client.launcher import local_server
from agent_client.runlog import CARD_VERSION, card_path, file_sha256, read_card, write_card
from vacc.metrics_cmd import metrics


def _drive(*args: str):
    return CliRunner().invoke(drive, [*args, "--quiet"], catch_exceptions=False)


@pytest.mark.parametrize(("log", "card"), [("run.csv", "run.card.json"), ("a.b.csv", "a.b.card.json"), ("run", "run.card.json")])
def test_the_card_goes_beside_the_log(tmp_path, log, card):
    assert card_path(tmp_path / log) == tmp_path / card


def test_a_spawned_servers_road_and_a_traces_digest_are_on_the_card(tmp_path):
    trace = tmp_path / "cycle.csv"
    trace.write_text("t_s,speed_mps\n0,10\n10,15\n")
    log = tmp_path / "logs" / "run.csv"  # a folder that does not exist yet
    result = _drive("--controller", "acc", "--trajectory", str(trace), "--seed", "3", "--gap", "30", "--traffic", "5", "--duration", "2", "--log", str(log))
    assert result.exit_code == 0, result.output
    card = read_card(log)
    assert card is not None and card["card"] == CARD_VERSION
    assert card["road"]["traffic"] == 5 and card["road"]["seed_salt"] == 0 and card["road"]["spawned"] is True
    assert card["episode"]["trajectory"] == str(trace) and card["episode"]["trace_sha256"] == file_sha256(trace)
    assert card["episode"]["seed"] == 3 and card["episode"]["gap"] == 30.0 and card["episode"]["host_speed"] is None
    assert card["controller"] == {"name": "acc", "checkpoint": None, "checkpoint_sha256": None, "human_file": None, "human_file_sha256": None}
    assert card["end"]["steps"] == 20 and card["end"]["collision"] is False and card["end"]["reason"] == "end"
    assert card["columns"][:3] == ["t", "frame", "v_host"]
    shown = CliRunner().invoke(metrics, [str(log)], catch_exceptions=False)
    assert shown.exit_code == 0 and shown.output.splitlines()[0] == f"run: ice/{trace} seed 3, set speed 33.5 m/s, traffic 5 a lane, the sun 0.35-1.2 rad high, acc"


def test_a_given_servers_traffic_comes_from_its_welcome(tmp_path):
    checkpoint = "models/ice-eco.pt"
    log = tmp_path / "run.csv"
    with local_server("--traffic", "7", "--sun-elevation", "0.4,0.5") as (host, port):
        result = _drive("--controller", "ddqn", "--checkpoint", checkpoint, "--server", f"{host}:{port}", "--duration", "1", "--log", str(log))
    assert result.exit_code == 0, result.output
    card = read_card(log)
    assert card is not None
    assert card["road"]["traffic"] == 7 and card["road"]["spawned"] is False and card["road"]["address"] == f"{host}:{port}"
    assert card["road"]["sun_elevation"] == [0.4, 0.5]
    assert card["controller"]["checkpoint_sha256"] == file_sha256(checkpoint)
    assert card["episode"]["preroll"] == 14  # the stack's span: 7 gaps of 2 control steps
    assert card["end"]["steps"] == 10
    shown = CliRunner().invoke(metrics, [str(log)], catch_exceptions=False)
    assert shown.output.splitlines()[0].endswith(f"traffic 7 a lane, the sun 0.4-0.5 rad high, ddqn ({checkpoint})")


def test_a_broken_card_is_a_warning_and_the_metrics_still_come(tmp_path):
    log = tmp_path / "run.csv"
    assert _drive("--controller", "acc", "--duration", "2", "--log", str(log)).exit_code == 0
    card_path(log).write_text("{not json")
    with pytest.raises(InputFileError, match=r"run\.card\.json: not JSON"):
        read_card(log)
    shown = CliRunner().invoke(metrics, [str(log), "--json"], catch_exceptions=False)
    assert shown.exit_code == 0 and "run's card is left out" in shown.stderr
    assert json.loads(shown.stdout)["gap_rmse_55m_m"] > 0
    write_card(log, {"end": {"gap_min": float("nan")}})  # JSON has no NaN: written as null
    assert read_card(log)["end"] == {"gap_min": None}  # type: ignore[index]
    card_path(log).write_text(json.dumps({"card": 99}))
    with pytest.raises(InputFileError, match="not a run card of version 1"):
        read_card(log)


def test_no_card_no_run_line(tmp_path):
    log = tmp_path / "run.csv"
    assert _drive("--controller", "acc", "--duration", "2", "--log", str(log)).exit_code == 0
    card_path(log).unlink()
    shown = CliRunner().invoke(metrics, [str(log)], catch_exceptions=False)
    assert shown.exit_code == 0 and shown.output.startswith("metric")
