"""Fitted parameters shipped as small CSV files in ``energy/data``.

Format: a header ``name,value,unit,note`` and one parameter per row. The
calibration scripts in ``scripts/`` write these files; the package only reads them.
"""

from __future__ import annotations

import csv
import io
from importlib import resources
from pathlib import Path

from energy.errors import DataError

PARAM_HEADER = ("name", "value", "unit", "note")


def read_params(filename: str) -> dict[str, float]:
    """Read ``energy/data/<filename>`` into {name: value}.

    Raises:
        DataError: file missing or malformed.
    """
    try:
        text = resources.files("energy").joinpath("data", filename).read_text(encoding="utf-8")
    except OSError as e:
        raise DataError(f"energy/data/{filename} is missing; re-run its script in scripts/") from e
    out: dict[str, float] = {}
    for r, row in enumerate(csv.DictReader(io.StringIO(text)), start=1):
        try:
            out[row["name"]] = float(row["value"])
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"energy/data/{filename}, row {r}: bad parameter row {row}") from e
    return out


def data_path(filename: str) -> Path:
    """Path of ``energy/data/<filename>`` in a source checkout (for the scripts)."""
    return Path(__file__).resolve().parent / "data" / filename


def write_params(filename: str, rows: list[tuple[str, float, str, str]]) -> Path:
    """Write (name, value, unit, note) rows to ``energy/data/<filename>``; returns the path."""
    path = data_path(filename)
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(PARAM_HEADER)
        for name, value, unit, note in rows:
            w.writerow((name, repr(float(value)), unit, note))
    return path
