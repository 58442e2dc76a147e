"""`vacc demo`: the paper beside ours, which way is better, a reading derived from the numbers."""

from __future__ import annotations

import subprocess
import sys

from vacc.demo import beside_paper, reading

# docs/results.md, ICE: our means
OURS = {
    "lead": {"fuel_g_per_mi": 95.6, "gap_rmse_55m_m": None, "jerk_rms_mps3": 1.133},
    "ddqn-gap": {"fuel_g_per_mi": 382.3, "gap_rmse_55m_m": 2.759, "jerk_rms_mps3": 14.479},
    "ddqn-force": {"fuel_g_per_mi": 95.5, "gap_rmse_55m_m": 4.418, "jerk_rms_mps3": 6.947},
    "acc": {"fuel_g_per_mi": 68.1, "gap_rmse_55m_m": 2.774, "jerk_rms_mps3": 0.172},
    "human": {"fuel_g_per_mi": 70.9, "gap_rmse_55m_m": 12.277, "jerk_rms_mps3": 0.591},
}


def test_reading_of_the_shipped_numbers():
    text = reading(OURS, "ice")
    assert text.startswith("The gap-based DDQN follows tightest (2.76 m gap RMSE) and burns the most fuel (382 g/mi, 5.6x the traditional ACC's 68).")
    # the paper's Table 3: gap-DDQN 3.423 m is the tightest, its human 198.6 g/mi the thirstiest
    assert "In the paper, too, the gap-based DDQN follows tightest, but the human driver burns the most fuel." in text
    assert "The roughest ride is the gap-based DDQN's (jerk RMS 14.48 m/s^3 against 0.17 for the traditional ACC)" in text
    assert "\n" not in text


def test_reading_follows_the_numbers():
    ours = {m: dict(v) for m, v in OURS.items()}
    ours["human"]["fuel_g_per_mi"] = 400.0  # now the paper's order on both
    assert "The gap-based DDQN follows tightest (2.76 m gap RMSE); the human driver burns the most fuel (400 g/mi" in reading(ours, "ice")
    assert reading(ours, "ice").split(" The roughest")[0].endswith(", as in the paper.")
    ours["acc"]["gap_rmse_55m_m"] = 1.0
    assert "The traditional ACC follows tightest (1.00 m" in reading(ours, "ice")
    assert "In the paper the gap-based DDQN follows tightest, and the human driver burns the most fuel too." in reading(ours, "ice")
    only = {"lead": OURS["lead"], "acc": OURS["acc"]}
    assert reading(only, "ice").startswith("Fewer than two of the paper's methods were evaluated (acc)")


def test_beside_paper_says_which_way_is_better():
    lines = beside_paper(OURS, "ice")
    fuel = next(line for line in lines if line.startswith("Fuel (g/mi)"))
    assert "lower" in fuel and "382.3 / 169.3" in fuel and "68.1 / 143.8" in fuel
    gap = next(line for line in lines if line.startswith("Gap RMSE"))
    assert "lower" in gap and "2.774 / 6.667" in gap
    assert "Eco" not in " ".join(lines)  # the paper has no eco column; only its four methods


def test_demo_prints_the_paper_beside_ours_and_a_reading(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "demo", "--out", str(tmp_path / "demo"), "--models", str(tmp_path / "none"), "--duration", "2", "--jobs", "2"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "ice-gap.pt is not shipped" in out
    assert "| Metric | Better | Lead vehicle | Traditional ACC |" in out
    assert "Ours beside the paper's Table 3" in out and "/ 143.8" in out
    reading_line = next(line for line in out.splitlines() if line.startswith("Reading: "))
    assert "follows tightest" in reading_line and "burns the most fuel" in reading_line
