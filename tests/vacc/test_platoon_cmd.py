"""`vacc platoon`'s parsing of its followers and lead (the runs are in tests/integration/test_platoon_seats.py)."""

from __future__ import annotations

import click
import pytest

from vacc.platoon_cmd import Follower, lead_args, parse_followers


def test_followers_parse_kinds_files_and_vehicles(tmp_path):
    ckpt = tmp_path / "m.pt"
    ckpt.write_bytes(b"x")
    got = parse_followers(f"acc, hdm@ev,ddqn:{ckpt}@ice", "ice")
    assert got == [Follower("acc", None, "ice"), Follower("hdm", None, "ev"), Follower("ddqn", str(ckpt), "ice")]
    assert got[2].drive_args() == ["--controller", "ddqn", "--scenario", "ice", "--checkpoint", str(ckpt)]


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("acc,bogus", "follower 2 ('bogus'): kind 'bogus' is not one of"),
        ("ddqn", "follower 1 ('ddqn'): ddqn needs its file"),
        ("acc:x.pt", "acc takes no file"),
        ("ddqn:/no/such.pt", "no file /no/such.pt"),
        ("acc@diesel", "vehicle 'diesel' is not one of"),
        (",".join(["acc"] * 17), "1..16 followers, got 17"),
    ],
)
def test_bad_followers_are_refused_naming_which(spec, says):
    with pytest.raises(click.BadParameter, match=says.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        parse_followers(spec, "ice")


def test_a_lead_that_is_nothing_known_is_refused(tmp_path):
    assert lead_args("test-2", tmp_path) == (["--trajectory", "test-2"], None)
    with pytest.raises(click.BadParameter, match="no trajectory"):
        lead_args(str(tmp_path / "missing.csv"), tmp_path)


def test_an_openacc_lead_becomes_its_leaders_speed_trace(tmp_path):
    from energy.openacc import OPENACC_FILES, read_openacc

    args, v0 = lead_args(OPENACC_FILES[0], tmp_path)
    run = read_openacc(OPENACC_FILES[0])
    rows = (tmp_path / "lead.csv").read_text().splitlines()
    assert args == ["--trajectory", str(tmp_path / "lead.csv")] and rows[0] == "t_s,speed_mps"
    assert float(rows[1].split(",")[0]) == 0.0 and v0 == float(rows[1].split(",")[1]) == run.speed[0][0]
