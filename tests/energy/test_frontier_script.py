"""scripts/energy_frontier.py refuses bad grids in one line, before driving or writing anything."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "energy_frontier.py"


@pytest.mark.parametrize(
    ("option", "value", "why"),
    [
        ("--copy-lags", "0,late", "comma-separated numbers"),
        ("--copy-lags", "-0.1", "each must be finite and >= 0"),
        ("--copy-speed-gains", "nan", "each must be finite and >= 0"),
        ("--copy-gap-gains", "0.1,,0.2", "comma-separated numbers"),
        ("--lag", "-1", "a lag is a time, >= 0 s"),
    ],
)
def test_a_bad_grid_is_refused_in_one_line(tmp_path, option, value, why):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, str(SCRIPT), "--tests", "--copy", f"{option}={value}", "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"energy_frontier.py: error: {option}: ") and why in last
    assert not out.exists()  # refused before anything was driven
