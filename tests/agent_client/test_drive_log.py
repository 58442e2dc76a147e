"""`drive_episode`'s run log over a real server: one row per frame, the controller's own
columns once it decided, and the rows so far kept when it stops or fails."""

from __future__ import annotations

import csv

import pytest

from agent_client.drive import StopEpisode, drive_episode
from agent_client.launcher import local_server
from agent_client.runlog import COLUMNS
from agent_client.session import Session


class _Counting:
    """Coasts, logs the frame it decided on as its own column, and stops or fails at ``last``."""

    log_columns = ("seen",)

    def __init__(self, last: int, error: type[BaseException] = StopEpisode):
        self.last, self.error, self.log_values = last, error, ()

    def __call__(self, obs):
        if obs["frame"] == self.last:
            raise self.error("here")
        self.log_values = (float(obs["frame"]),)
        return 0.0


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def session():
    with local_server() as addr, Session(addr) as s:
        yield s


def test_a_controllers_columns_follow_the_usual_ones_and_a_stop_keeps_its_row(session, tmp_path):
    log = tmp_path / "stop.csv"
    summary = drive_episode(session, _Counting(last=5), scenario="ice", seed=0, trajectory="test-1", log=log)
    assert summary.reason == ""
    rows = _rows(log)
    assert list(rows[0]) == [*COLUMNS, "seen"]
    assert [int(r["frame"]) for r in rows] == list(range(6))  # the stop frame's row too
    assert [r["seen"] for r in rows] == ["0.0", "1.0", "2.0", "3.0", "4.0", ""]  # no decision at the stop


def test_a_failing_controller_keeps_the_rows_so_far_and_the_end_row_has_no_decision(session, tmp_path):
    log = tmp_path / "fail.csv"
    with pytest.raises(RuntimeError, match="here"):
        drive_episode(session, _Counting(last=3, error=RuntimeError), scenario="ice", seed=0, trajectory="test-1", log=log)
    assert [int(r["frame"]) for r in _rows(log)] == [0, 1, 2, 3]
    log = tmp_path / "end.csv"
    drive_episode(session, _Counting(last=-1), scenario="ice", seed=0, trajectory="test-1", duration=1.0, log=log)
    rows = _rows(log)
    assert len(rows) == 11 and rows[-1]["seen"] == "" and rows[-2]["seen"] == "9.0"
