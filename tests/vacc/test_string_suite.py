"""vacc evaluate --suite string: gains behind sinusoidal leads and platoons behind held-out leads."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from agent_client.controllers.acc import AccController, speed_transfer
from vacc.cli import main
from vacc.string_suite import (
    LEAD_SEEDS,
    LEAD_SPEEDS,
    STILL_SPEED,
    gain_rows,
    held_out_lead,
    law_maker,
    model_maker,
    platoon_rows,
    still_lead,
)

MODELS = Path(__file__).resolve().parents[2] / "models"


def test_the_acc_laws_gains_meet_its_linear_theory():
    rows = gain_rows("acc", law_maker("acc"))
    assert len(rows) == 10
    for r in rows:
        assert not r.collided and r.gain == pytest.approx(r.theory, rel=0.10, abs=0.02), r
        theory_lag = -np.angle(speed_transfer(AccController(), 2 * np.pi * r.freq)) / (2 * np.pi * r.freq)
        assert r.lag_s == pytest.approx(theory_lag, abs=0.1)  # measured: within 0.05 s (the 10 Hz hold)
    assert max(r.gain for r in rows) > 1.0  # the shipped gains amplify near 0.05 Hz (docs/platoons.md)


def test_the_platoon_teacher_attenuates_where_eco_firm_amplifies():
    assert max(r.gain for r in gain_rows("platoon", law_maker("platoon"))) < 1.0
    assert max(r.gain for r in gain_rows("eco-firm", law_maker("eco-firm"), speeds=(20.0,), freqs=(0.02,))) > 1.0


def test_held_out_leads_drive_at_openaccs_speeds_and_differ_by_seed():
    a, b = held_out_lead(LEAD_SEEDS[0]), held_out_lead(LEAD_SEEDS[1])
    assert a[0][-1] == pytest.approx(180.0, abs=0.01) and a[1].shape == a[0].shape
    assert LEAD_SPEEDS[0] <= a[1].min() and a[1].max() <= LEAD_SPEEDS[1] and a[1].std() > 0.5
    assert abs(np.diff(a[1])).max() / 0.1 < 2.0  # a driver's changes of speed, no jumps
    assert not (a[1] == b[1]).all()
    assert held_out_lead(LEAD_SEEDS[0])[1] == pytest.approx(a[1], abs=0.0)
    assert (still_lead(10.0)[1] == STILL_SPEED).all()


def test_a_camera_follower_gets_a_gain_and_a_platoon_row():
    make = model_maker(str(MODELS / "ice-eco.pt"))
    (row,) = gain_rows("ice-eco", make, speeds=(20.0,), freqs=(0.3,))
    assert not row.collided and math.isfinite(row.gain) and math.isnan(row.theory) and row.min_gap_m > 2.0


def test_the_command_writes_both_tables_and_refuses_what_it_would_ignore(tmp_path):
    out = tmp_path / "string"
    done = CliRunner().invoke(main, ["evaluate", "--suite", "string", "--methods", "acc,platoon", "--followers", "3", "--seeds", "7001", "--out", str(out)])
    assert done.exit_code == 0, done.output
    assert "| acc | 8 | 1.03 (1.03) |" in done.output and "| platoon | seed 7001 | 4 |" in done.output and "| platoon | still | 4 |" in done.output
    got = json.loads((out / "string.json").read_text())
    assert len(got["gains"]) == 20
    assert [(p["driver"], p["lead"]) for p in got["platoons"]] == [(d, k) for d in ("acc", "platoon") for k in ("seed 7001", "still")]
    for args, words in ((["--methods", "hdm"], "drives the laws"), (["--scenario", "ev"], "takes --out"), (["--jobs", "2"], "--jobs")):
        done = CliRunner().invoke(main, ["evaluate", "--suite", "string", "--out", str(out), *args])
        assert done.exit_code == 2 and words in done.output, done.output


def test_platoons_of_the_platoon_law_attenuate_and_hold_still_behind_a_still_lead():
    moving, still = platoon_rows("platoon", law_maker("platoon"), seeds=(7002,), followers=4)
    assert moving.lead == "seed 7002" and moving.cars == 5 and not moving.collided and moving.min_gap_m > 2.0
    assert moving.speed_rms < 1.0 and still.lead == "still" and still.last_dev_rms < 0.01


def test_followers_is_refused_by_the_suites_without_platoons(tmp_path):
    done = CliRunner().invoke(main, ["evaluate", "--suite", "safety", "--followers", "3", "--out", str(tmp_path)])
    assert done.exit_code == 2 and "--followers" in done.output and "openacc" in done.output
