"""vacc evaluate --suite openacc: law platoons behind the real OpenACC leads, beside the real ones."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from click.testing import CliRunner

from agent_client.controllers.acc import AccController
from agent_client.controllers.hdm import HumanDriverModel
from energy.openacc import OPENACC_FILES, read_openacc
from energy.string_stability import amplification
from vacc.cli import main
from vacc.openacc_suite import PLATOONS, STILL_LEAD_MPS, openacc_rows, openacc_table

MODELS = Path(__file__).resolve().parents[2] / "models"
DYNAMIC = "short_setting_dynamic_part10.csv"  # 4 cars, a lead that moves
STILL = "mixed_dynamic_part5.csv"  # 10 cars behind a constant-speed lead


def test_each_file_gives_the_real_platoon_and_each_kind_of_its_length():
    rows = openacc_rows([DYNAMIC], ["acc", "hdm"])
    real = read_openacc(DYNAMIC)
    assert [r.platoon for r in rows] == ["real", "acc", "hdm"]
    assert all(r.cars == real.n_cars for r in rows)
    # the real row is the file's own amplification, after the first fifth
    assert rows[0].speed_rms == pytest.approx(amplification(real.t, real.speed).lead_to_last.speed_rms)
    for r in rows[1:]:
        assert not r.collided and r.min_gap_m > 2.0 and math.isfinite(r.speed_rms)
    # the same lead: every simulated platoon sees the real lead's deviation
    assert rows[1].lead_dev_rms == pytest.approx(rows[0].lead_dev_rms, rel=0.05)


def test_the_human_driver_model_amplifies_more_than_the_acc():
    """The HDM's 1 s reaction time makes its platoon string-unstable where the ACC's is not."""
    acc, hdm = openacc_rows([DYNAMIC], ["acc", "hdm"])[1:]
    assert hdm.speed_rms > 1.5 * acc.speed_rms


def test_mixed_alternates_acc_and_hdm_starting_with_the_acc():
    kinds = [type(PLATOONS["mixed"](i)[0]) for i in range(1, 5)]
    assert kinds == [AccController, HumanDriverModel, AccController, HumanDriverModel]


def test_behind_a_still_lead_the_table_gives_the_last_cars_deviation_not_a_ratio():
    rows = openacc_rows([STILL], ["acc"])
    assert rows[0].lead_dev_rms < STILL_LEAD_MPS
    line = openacc_table(rows)[-1]
    assert line.startswith(f"| {STILL} | 10, 10 |") and "dev " in line and " / " not in line


def test_the_command_writes_the_table_of_all_nine_files_and_refuses_what_it_would_ignore(tmp_path):
    out = tmp_path / "oacc"
    result = CliRunner().invoke(main, ["evaluate", "--suite", "openacc", "--methods", "acc", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "| real | acc |" in result.output and f"| {DYNAMIC} | 4, 4 |" in result.output
    assert sum(name in (out / "openacc.md").read_text() for name in OPENACC_FILES) == 9
    assert [r["platoon"] for r in json.loads((out / "openacc.json").read_text())] == ["real", "acc"] * 9
    for args, words in (
        (["--methods", "acc,ddqn"], "drives platoons of acc, hdm, mixed"),
        (["--seeds", "0-3"], "--seeds"),
        (["--scenario", "ev"], "--scenario"),
        (["--jobs", "3"], "--jobs"),
        (["--model", "x=y.pt"], "--model"),
    ):
        result = CliRunner().invoke(main, ["evaluate", "--suite", "openacc", "--out", str(out), *args])
        assert result.exit_code == 2 and words in result.output, result.output


def test_a_learned_platoon_drives_from_its_cameras_behind_a_real_lead():
    import dataclasses

    from vacc.openacc_suite import camera_row

    full = read_openacc(DYNAMIC)
    keep = full.t <= full.t[0] + 40.0  # 40 s of the real lead, two followers: a few seconds
    run = dataclasses.replace(full, t=full.t[keep], speed=full.speed[:3, keep], ivs=full.ivs[:2, keep], vehicles=full.vehicles[:3])
    row = camera_row(run, "ice-eco", str(MODELS / "ice-eco.pt"))
    assert row.platoon == "ice-eco" and row.cars == 3 and not row.collided
    assert row.min_gap_m > 2.0 and math.isfinite(row.speed_rms) and math.isfinite(row.last_dev_rms)


def test_openacc_refuses_a_bad_model_in_one_line(tmp_path):
    done = CliRunner().invoke(main, ["evaluate", "--suite", "openacc", "--model", "x=nothing.pt", "--out", str(tmp_path)])
    assert done.exit_code == 2 and "nothing.pt: no such checkpoint" in done.output
    done = CliRunner().invoke(main, ["evaluate", "--suite", "openacc", "--model", "acc=" + str(MODELS / "ice-eco.pt"), "--out", str(tmp_path)])
    assert done.exit_code == 2 and "taken" in done.output


def test_followers_sets_the_simulated_platoons_length_not_the_real_ones():
    rows = openacc_rows([DYNAMIC], ["acc"], followers=9)
    assert [r.cars for r in rows] == [4, 10]
    assert openacc_table(rows)[-1].startswith(f"| {DYNAMIC} | 4, 10 |")
