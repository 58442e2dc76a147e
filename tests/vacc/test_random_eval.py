"""scripts/random_eval.py refuses a road the server would refuse, before driving anything."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "random_eval.py"


@pytest.mark.parametrize("traffic", ["-1", "11"])
def test_a_traffic_outside_the_servers_range_is_refused_in_one_line(tmp_path, traffic):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, str(SCRIPT), "--traffic", traffic, "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert f"--traffic: {traffic} is not in 0..10" in result.stderr.strip().splitlines()[-1]
    assert not out.exists()  # refused before anything was written


@pytest.mark.parametrize(("sun", "why"), [("0.01,0.5", "must have 0.05 <= LOW <= HIGH <= 1.5 rad"), ("low", "is not LOW,HIGH in radians"), ("0.7,0.4", "got 0.7,0.4")])
def test_a_sun_outside_the_servers_range_is_refused_in_one_line(tmp_path, sun, why):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, str(SCRIPT), "--sun-elevation", sun, "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("random_eval.py: error: --sun-elevation: ") and why in last
    assert not out.exists()
