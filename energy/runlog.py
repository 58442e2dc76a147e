"""Reading and validating run logs (``vacc drive --log``).

A run log is a CSV with one row per control step, in SI units, and at least the
columns ``t,frame,v_host,v_lead,gap,accel,force,collision`` (t [s], speeds [m/s],
gap [m], accel [m/s^2], force in [-1, 1], collision 0/1). Other columns are
ignored. The control period is read from ``t``, never assumed.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from energy.errors import RunLogError

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
    """Read and check a run log CSV.

    Args:
        path: the CSV file.

    Returns:
        The validated log.

    Raises:
        RunLogError: the file is missing or unreadable, a required column is missing,
            a value is empty, not a number, NaN or infinite, a speed is negative, time
            does not strictly increase, force is outside [-1, 1], collision is not
            0/1, the gap is negative without a collision, there are fewer than two
            rows, or the host covers no distance. The message names the file, the row
            and the problem.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except FileNotFoundError:
        raise RunLogError(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RunLogError(path, None, f"cannot read file ({e})") from None
    if not rows:
        raise RunLogError(path, None, "empty file (no header)")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise RunLogError(
            path, None, f"missing column(s) {', '.join(missing)} (header: {','.join(header)})"
        )
    idx = {c: header.index(c) for c in REQUIRED_COLUMNS}
    body = [r for r in rows[1:]]
    if len(body) < 2:
        raise RunLogError(path, None, f"need at least 2 data rows, got {len(body)}")

    cols = {c: np.empty(len(body)) for c in REQUIRED_COLUMNS}
    for r, row in enumerate(body, start=1):
        for c, i in idx.items():
            if i >= len(row) or not row[i].strip():
                raise RunLogError(path, r, f"column {c!r} is empty")
            try:
                x = float(row[i])
            except ValueError:
                raise RunLogError(path, r, f"column {c!r} is not a number ({row[i]!r})") from None
            if not math.isfinite(x):
                raise RunLogError(path, r, f"column {c!r} is {row[i].strip()} (must be finite)")
            cols[c][r - 1] = x
        _check_row(path, r, cols, r - 1)

    log = RunLog(path=str(path), **cols)  # type: ignore[arg-type]
    if not log.distance_m > 0.0:
        raise RunLogError(
            path, None, f"zero distance travelled (v_host is 0 on all {len(body)} rows)"
        )
    return log


def _check_row(path: Path, r: int, cols: dict[str, np.ndarray], i: int) -> None:
    for c in ("v_host", "v_lead"):
        if cols[c][i] < 0.0:
            raise RunLogError(path, r, f"negative speed in column {c!r} ({cols[c][i]} m/s)")
    if i > 0 and not cols["t"][i] > cols["t"][i - 1]:
        raise RunLogError(
            path,
            r,
            f"time not strictly increasing (t = {cols['t'][i - 1]} s, then {cols['t'][i]} s)",
        )
    if abs(cols["force"][i]) > 1.0 + FORCE_TOLERANCE:
        raise RunLogError(path, r, f"force {cols['force'][i]} outside [-1, 1]")
    if cols["collision"][i] not in (0.0, 1.0):
        raise RunLogError(path, r, f"collision must be 0 or 1, got {cols['collision'][i]}")
    if cols["frame"][i] != round(cols["frame"][i]):
        raise RunLogError(path, r, f"frame must be an integer, got {cols['frame'][i]}")
    if cols["gap"][i] < 0.0 and cols["collision"][i] == 0.0:
        raise RunLogError(path, r, f"negative gap {cols['gap'][i]} m without a collision")
