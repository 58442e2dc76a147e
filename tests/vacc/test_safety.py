"""`vacc evaluate --suite safety`: seeds, per-run verdicts on hand-made logs, and a real run of the ACC."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import click
import pytest

from protocol.scenarios import LEAD_SCENARIOS
from vacc.runs import parse_seeds
from vacc.safety import MIN_GAP, SPEED_MARGIN, safety_table, score_run

MODELS = Path(__file__).resolve().parents[2] / "models"
HEADER = "t,frame,v_host,v_lead,gap,accel,force,collision,a_lead\n"
# The suite runs below wait up to 600 s for their subprocess: the test waits longer, so the
# subprocess's own timeout, not the suite's default 300 s, says what took too long.
pytestmark = pytest.mark.timeout(660)


def _log(tmp_path, rows, accel=None):
    path = tmp_path / "run.csv"
    accel = accel if accel is not None else [0.0] * len(rows)
    path.write_text(HEADER + "".join(f"{i * 0.1},{i},{v},{v},{g},{a},0,{c},0\n" for i, ((v, g, c), a) in enumerate(zip(rows, accel, strict=True))))
    return path


def test_seed_lists():
    assert parse_seeds("0-9") == list(range(10))
    assert parse_seeds("0,3,5") == [0, 3, 5]
    assert parse_seeds("0-2,7,2") == [0, 1, 2, 7]
    for bad in ("", "a", "3-1", "-2", "1-"):
        with pytest.raises(ValueError):
            parse_seeds(bad)


def test_a_run_passes_only_without_collision_close_gap_or_overspeed(tmp_path):
    assert score_run(_log(tmp_path, [(20.0, 30.0, 0), (10.0, MIN_GAP, 0), (0.0, 4.0, 0)]))["passed"]
    hit = score_run(_log(tmp_path, [(20.0, 30.0, 0), (10.0, 0.0, 1)]))
    assert hit["collision"] and not hit["passed"]
    close = score_run(_log(tmp_path, [(20.0, 30.0, 0), (5.0, MIN_GAP - 0.01, 0)]))
    assert not close["collision"] and close["min_gap_m"] == pytest.approx(MIN_GAP - 0.01) and not close["passed"]
    fast = score_run(_log(tmp_path, [(33.5 + SPEED_MARGIN + 0.01, 60.0, 0)] * 2))
    assert fast["max_speed_mps"] > 34.0 and not fast["passed"]
    assert score_run(_log(tmp_path, [(33.5 + SPEED_MARGIN, 60.0, 0)] * 2))["passed"]


def test_unprompted_hard_brakes_are_counted_from_engagement_but_do_not_fail_a_run(tmp_path):
    # 30 s behind a lead at the same speed, 55 m ahead; a full brake at 1 s (inside the
    # comfort figures' 15 s settle: a phantom brake at engagement is one too) and one at 20 s
    accel = [-6.0 if i in (10, 11, 200, 201) else 0.0 for i in range(300)]
    score = score_run(_log(tmp_path, [(25.0, 55.0, 0)] * 300, accel))
    assert score["passed"] and score["unprompted_hard_brakes"] == 2
    job = SimpleNamespace(method="acc", checkpoint=None, scenario="ev", trajectory="constant")
    table, rows = safety_table([job, job], [score, score_run(_log(tmp_path, [(25.0, 55.0, 0)] * 300))])
    assert rows[0]["unprompted_hard_brakes"] == 2 and rows[0]["runs_with_unprompted"] == 1
    assert "| acc (ev) | constant | 2/2 | 0 | 55.00 | 25.00 | 2 | PASS |" in table
    assert "| acc (ev) | 2/2 | 2 (1) |" in table


def test_a_bad_run_log_fails_naming_the_file(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(HEADER + "0,0,20,20,30,0,0,0,0\n")
    with pytest.raises(click.ClickException, match="run.csv"):
        score_run(path)


def test_the_acc_passes_every_scenario(tmp_path):
    out = tmp_path / "safety"
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "evaluate", "--suite", "safety", "--seeds", "0", "--models", str(tmp_path / "none"), "--out", str(out), "--jobs", "2"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    table = (out / "safety.md").read_text()
    for name in LEAD_SCENARIOS:
        assert f"| acc (ice) | {name} | 1/1 | 0 |" in table and f"| acc (ev) | {name} | 1/1 |" in table, name
    assert "FAIL" not in table


def test_a_given_scenario_and_lead_scenarios_drive_only_those(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    out = tmp_path / "safety"
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "evaluate", "--suite", "safety", "--scenario", "ev", "--lead-scenarios", "cut-in,stopped",
         "--seeds", "0,1", "--models", str(models), "--out", str(out), "--jobs", "2", "--traffic", "0"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    table = (out / "safety.md").read_text()
    assert table.startswith("# Safety suite, 0 cars in each adjacent lane (default 3)\n")
    assert "| acc (ev) | stopped | 2/2 |" in table and "| acc (ev) | cut-in | 2/2 |" in table
    assert "acc (ice)" not in table and "slow-lead" not in table
    assert len(list((out / "logs").glob("*.csv"))) == 4


def test_a_low_sun_is_named_and_leaves_the_accs_drive_alone(tmp_path):
    # The ACC reads the gap, not the picture: under a low sun it drives the same, and the
    # table says which sun it was.
    logs = {}
    for sun in ("0.35,0.5", "0.35,1.2"):
        out = tmp_path / sun
        result = subprocess.run(
            [sys.executable, "-m", "vacc", "evaluate", "--suite", "safety", "--scenario", "ice", "--lead-scenarios", "constant",
             "--seeds", "227", "--models", str(tmp_path), "--out", str(out), "--jobs", "1", "--sun-elevation", sun],
            capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        title = (out / "safety.md").read_text().splitlines()[0]
        assert title == ("# Safety suite, the sun 0.35-0.5 rad high (default 0.35-1.2)" if sun == "0.35,0.5" else "# Safety suite"), title
        logs[sun] = (out / "logs" / "acc-ice-constant-227.csv").read_bytes()
    assert logs["0.35,0.5"] == logs["0.35,1.2"]


def test_methods_choose_the_drivers(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    shutil.copy(MODELS / "ev-eco.pt", models / "ev-eco-candidate.pt")
    shutil.copy(MODELS / "ev-gap.pt", models / "ev-gap.pt")
    out = tmp_path / "safety"
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "evaluate", "--suite", "safety", "--scenario", "ev", "--lead-scenarios", "stopped",
         "--seeds", "0", "--methods", "ddqn-eco", "--models", str(models), "--out", str(out), "--jobs", "1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    table = (out / "safety.md").read_text()
    assert "| ev-eco-candidate (ev) | stopped | 1/1 |" in table
    assert "acc" not in table and "ev-gap" not in table
    assert [p.name for p in (out / "logs").glob("*.csv")] == ["ev-eco-candidate-ev-stopped-0.csv"]


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--suite", "safety", "--seeds", "9-1"], "--seeds"),
        (["--suite", "safety", "--lead-scenarios", "stopped,moose"], "--lead-scenarios"),
        (["--suite", "safety", "--lead-scenarios", ","], "--lead-scenarios"),
        (["--lead-scenarios", "stopped"], "--lead-scenarios"),  # the paper suite drives test-1..4
        (["--suite", "safety", "--methods", "acc,human"], "--methods"),  # the suite has no human driver
        (["--suite", "safety", "--traffic", "11"], "--traffic"),
        (["--suite", "safety", "--sun-elevation", "0.5,0.4"], "--sun-elevation"),
        (["--sun-elevation", "0.35,0.5"], "--sun-elevation"),  # the paper suite's test trajectories keep a fixed sun
        (["--suite", "safety", "--methods", "ddqn-eco", "--models", "no-such-models"], "--methods"),
    ],
)
def test_bad_options_fail_naming_the_option(tmp_path, args, option):
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "evaluate", *args, "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2 and option in result.stderr, result.stderr
    assert not (tmp_path / "o").exists()


def test_a_named_model_drives_its_own_vehicle_and_keeps_its_name_in_the_table(tmp_path):
    """--model NAME=PATH in the safety suite: the vehicle is the checkpoint's, not the name's
    prefix, and the table names the model NAME, not its file."""
    from vacc.safety import safety_jobs

    jobs = safety_jobs(tmp_path, {"mine": "run/latest.pt", "ev-gap": "m/ev-gap.pt"}, [0], ["stopped"], vehicles=("ice",), acc=False,
                       model_vehicles={"mine": "ice"})  # fmt: skip
    assert [(j.scenario, Path(j.log).name) for j in jobs] == [("ev", "ev-gap-ev-stopped-0.csv"), ("ice", "mine-ice-stopped-0.csv")]
    score = score_run(_log(tmp_path, [(25.0, 55.0, 0)] * 300))
    _, rows = safety_table(jobs, [score, score])
    assert [r["driver"] for r in rows] == ["ev-gap (ev)", "mine (ice)"]
