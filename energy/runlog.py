"""Reading and validating run logs (``vacc drive --log``).

A run log is a CSV with one row per control step, in SI units, and at least the
columns ``t,frame,v_host,v_lead,gap,accel,force,collision`` (t [s], speeds [m/s],
gap [m], accel [m/s^2], force in [-1, 1], collision 0/1). Other columns are
ignored. The control period is read from ``t``, never assumed.
"""

from __future__ import annotations

import csv
import math
from array import array
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from energy.errors import RunLogError
from protocol.numbers import PLAIN_FLOAT

REQUIRED_COLUMNS = ("t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision")
"""Columns every run log must have."""

FORCE_TOLERANCE = 1e-6  # [-] float slack on |force| <= 1


@dataclass(frozen=True)
class RunLog:
    """A validated run log; arrays have one entry per row (control step)."""

    path: str
    t: np.ndarray
    """Time [s], strictly increasing."""
    frame: np.ndarray
    """Lockstep frame counter."""
    v_host: np.ndarray
    """Host speed [m/s], >= 0."""
    v_lead: np.ndarray
    """Lead speed [m/s], >= 0."""
    gap: np.ndarray
    """Bumper-to-bumper gap [m]; negative only on a collision row."""
    accel: np.ndarray
    """Host acceleration [m/s^2]."""
    force: np.ndarray
    """Normalised force u in [-1, 1]."""
    collision: np.ndarray
    """Collision flag, 0 or 1."""

    @property
    def distance_m(self) -> float:
        """Distance the host travelled [m] (trapezoid rule on v_host)."""
        return float(np.sum(0.5 * (self.v_host[1:] + self.v_host[:-1]) * np.diff(self.t)))


def read_run_log(path: str | Path) -> RunLog:
    """Read and check a run log CSV, streaming: memory grows by 64 bytes a row, whatever
    the file holds.

    Args:
        path: the CSV file.

    Returns:
        The validated log.

    Raises:
        RunLogError: the file is missing or unreadable, a required column is missing,
            a column name repeats, a field is over the CSV field limit, a value is
            empty, not a plain number (``1_0``), NaN or infinite, a speed is negative,
            time does not strictly increase, force is outside [-1, 1], collision is not
            0/1, the gap is negative without a collision, there are fewer than two
            rows, or the host covers no distance. The message names the file, the row
            and the problem.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header = _header(path, reader)
            cols = _read_columns(path, reader, {c: header.index(c) for c in REQUIRED_COLUMNS})
    except FileNotFoundError:
        raise RunLogError(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RunLogError(path, None, f"cannot read file ({e})") from None
    n = len(cols["t"])
    if n < 2:
        raise RunLogError(path, None, f"need at least 2 data rows, got {n}")
    log = RunLog(path=str(path), **{c: np.frombuffer(a, dtype=np.float64) for c, a in cols.items()})  # type: ignore[arg-type]  # no copy
    if not log.distance_m > 0.0:
        raise RunLogError(
            path, None, f"zero distance travelled (v_host is 0 on all {n} rows)"
        )
    return log


def _header(path: Path, reader: Iterator[list[str]]) -> list[str]:
    """The header's names, stripped. Raises RunLogError: none, a repeat, a required one missing."""
    try:
        first = next(reader, None)
    except csv.Error as e:
        raise RunLogError(path, None, f"line 1: not a CSV header ({e})") from None
    if first is None:
        raise RunLogError(path, None, "empty file (no header)")
    header = [h.strip() for h in first]
    if repeated := sorted({h for h in header if header.count(h) > 1}):
        raise RunLogError(path, None, f"line 1: column(s) {', '.join(repeated)} named twice (header: {','.join(header)})")
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise RunLogError(
            path, None, f"missing column(s) {', '.join(missing)} (header: {','.join(header)})"
        )
    return header


def _read_columns(path: Path, reader: Iterator[list[str]], idx: dict[str, int]) -> dict[str, array]:
    """The required columns, row by row, each row checked as it is read.

    Raises:
        RunLogError: a bad row (see :func:`read_run_log`), naming it.
    """
    cols = {c: array("d") for c in REQUIRED_COLUMNS}
    last: dict[str, float] = {}
    r = 0
    while True:
        try:
            row = next(reader, None)
        except csv.Error as e:
            raise RunLogError(path, r + 1, f"not a CSV row ({e})") from None
        if row is None:
            return cols
        r += 1
        values = {}
        for c, i in idx.items():
            if i >= len(row) or not row[i].strip():
                raise RunLogError(path, r, f"column {c!r} is empty")
            if PLAIN_FLOAT.fullmatch(row[i]) is None:  # float() would take '1_0'
                raise RunLogError(path, r, f"column {c!r} is not a number ({row[i]!r})")
            x = float(row[i])
            if not math.isfinite(x):
                raise RunLogError(path, r, f"column {c!r} is {row[i].strip()} (must be finite)")
            values[c] = x
        _check_row(path, r, values, last)
        for c, x in values.items():
            cols[c].append(x)
        last = values


def _check_row(path: Path, r: int, row: dict[str, float], last: dict[str, float]) -> None:
    """Check data row ``r`` (``last``: the row before it, {} for the first). Raises RunLogError."""
    for c in ("v_host", "v_lead"):
        if row[c] < 0.0:
            raise RunLogError(path, r, f"negative speed in column {c!r} ({row[c]} m/s)")
    if last and not row["t"] > last["t"]:
        raise RunLogError(
            path,
            r,
            f"time not strictly increasing (t = {last['t']} s, then {row['t']} s)",
        )
    if abs(row["force"]) > 1.0 + FORCE_TOLERANCE:
        raise RunLogError(path, r, f"force {row['force']} outside [-1, 1]")
    if row["collision"] not in (0.0, 1.0):
        raise RunLogError(path, r, f"collision must be 0 or 1, got {row['collision']}")
    if row["frame"] != round(row["frame"]):
        raise RunLogError(path, r, f"frame must be an integer, got {row['frame']}")
    if row["gap"] < 0.0 and row["collision"] == 0.0:
        raise RunLogError(path, r, f"negative gap {row['gap']} m without a collision")
