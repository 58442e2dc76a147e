"""Learning-curve exports: the PNG and the binned ``models/<name>.curve.csv``."""

from __future__ import annotations

import csv

from agent_client.curves import export_curve, plot_learning_curve


def _scalars(path):
    rows = [("step", "name", "value", "wall_s")]
    # three episodes in the first 5,000-step bin, one in the second
    for step, ret, length in ((1000, 60.0, 600), (2000, -30.0, 300), (5000, 0.0, 600), (7000, 300.0, 600)):
        rows += [(step, "charts/episodic_return", ret, 0), (step, "charts/episodic_length", length, 0)]
    rows += [(5000, "eval/gap_rmse_m", 12.0, 0), (5000, "eval/gap_rmse_mean_m", 10.0, 0)]
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)


def test_curve_csv_is_reward_per_step_in_bins(tmp_path):
    _scalars(tmp_path / "scalars.csv")
    n = export_curve(tmp_path / "scalars.csv", tmp_path / "c.csv", bin_steps=5000, offset=100)
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert lines[0].startswith("#") and lines[1] == "step,avg_reward"
    assert n == 2 and lines[2:] == ["5100,0.0200", "10100,0.5000"]  # (60 - 30 + 0) / 1500; 300 / 600


def test_learning_curve_png_is_written(tmp_path):
    _scalars(tmp_path / "scalars.csv")
    plot_learning_curve(tmp_path / "scalars.csv", tmp_path / "c.png", "t")
    assert (tmp_path / "c.png").stat().st_size > 1000
