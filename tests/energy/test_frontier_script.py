"""scripts/energy_frontier.py: bad grids are refused in one line, before driving or writing
anything; the predictive follower plans as a follower should."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "energy_frontier.py"
# the checkout's packages first: the script's own folder, not the checkout, is its sys.path[0]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(SCRIPT.parents[1]), os.environ.get("PYTHONPATH")]))}


@pytest.mark.parametrize(
    ("option", "value", "why"),
    [
        ("--copy-lags", "0,late", "comma-separated numbers"),
        ("--copy-lags", "-0.1", "each must be finite and >= 0"),
        ("--copy-speed-gains", "nan", "each must be finite and >= 0"),
        ("--copy-gap-gains", "0.1,,0.2", "comma-separated numbers"),
        ("--lag", "-1", "a lag is a time, >= 0 s"),
        ("--betas", "0.3,high", "comma-separated numbers"),
        ("--gammas", "-2", "each must be finite and >= 0"),
        ("--lams", "0.01,0", "each preview gap weight must be > 0"),
        ("--limits", "4,2,0.9,1.1", "X0,X1,Y0,Y1 with X0 < X1 and Y0 < Y1"),
        ("--limits", "0,12,0.9", "X0,X1,Y0,Y1"),
    ],
)
def test_a_bad_grid_is_refused_in_one_line(tmp_path, option, value, why):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, str(SCRIPT), "--tests", "--copy", f"{option}={value}", "--out", str(out)], capture_output=True, text=True, timeout=60, env=ENV)
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"energy_frontier.py: error: {option}: ") and why in last
    assert not out.exists()  # refused before anything was driven


def test_the_predictive_followers_are_refused_for_the_ice_car_in_one_line(tmp_path):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, str(SCRIPT), "--scenario", "ice", "--tests", "--mpc", "--out", str(out)], capture_output=True, text=True, timeout=60, env=ENV)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines()[-1] == "energy_frontier.py: error: --mpc: the predictive followers plan on eq. 6, the EV's energy; use --scenario ev"
    assert not out.exists()


def test_replot_redraws_a_runs_figure_from_its_summary_and_refuses_without_one(tmp_path):
    """--replot drives nothing: it draws OUT/summary.json again within --limits."""
    rows = [{"follower": "acc", "rmse": [2.8, 2.9], "energy": [68.0, 68.2], "ratio": 1.0},
            {"follower": "law beta 0.1 gamma 0.3 lag 0.5 s", "beta": 0.1, "gamma": 0.3, "lag": 0.5, "rmse": [3.1, 3.2], "energy": [65.0, 66.0], "ratio": 0.96},
            {"follower": "m", "model": "m.pt", "rmse": [3.7, 3.8], "energy": [66.0, 66.5], "ratio": 0.97}]  # fmt: skip
    import json

    (tmp_path / "summary.json").write_text(json.dumps({"episodes": [["test-1", 0], ["test-2", 0]], "rows": rows}))
    cmd = [sys.executable, str(SCRIPT), "--scenario", "ice", "--tests", "--out", str(tmp_path), "--replot", "--limits", "2.6,4.2,0.94,1.02"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=ENV)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "energy-frontier.png").stat().st_size > 10_000 and not (tmp_path / "logs").exists()
    cmd[cmd.index("--out") + 1] = str(tmp_path / "none")
    missing = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=ENV)
    assert missing.returncode == 1 and "summary.json: no summary of an earlier run to redraw" in missing.stderr and missing.stderr.count("\n") == 1


def _script():
    import importlib.util

    spec = importlib.util.spec_from_file_location("energy_frontier", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_predictive_follower_holds_a_steady_lead_and_brakes_for_a_braking_one():
    ef = _script()
    steady = {"gap": 55.0, "v_host": 20.0, "v_lead": 20.0, "a_lead": 0.0}
    hold = ef.PredictiveFollower(0.0, 0.01)(steady)
    assert abs(hold) < 0.05  # at most a light coast: the plan trades a little gap for energy
    braking = {**steady, "a_lead": -3.0}
    assert ef.PredictiveFollower(0.0, 0.01)(braking) < hold - 0.3
    # told 0.5 s late, it has not yet seen the brake that began since
    late = ef.PredictiveFollower(0.5, 0.01)
    for _ in range(3):
        late(steady)
    assert late(braking) == pytest.approx(hold, abs=1e-9)
