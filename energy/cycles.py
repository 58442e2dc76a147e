"""Standard driving cycles shipped as package data (1 Hz, ``t_s,speed_mps``).

See ``energy/data/README.md`` for provenance: EPA UDDS, HWFET and US06 (U.S.
government works) and WLTC class 3b, converted from NREL's fastsim 2.1.5.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from energy.errors import RunLogError

CYCLES = ("udds", "hwfet", "us06", "wltc_3b")
"""Names of the shipped cycles."""

UDDS_BAG2_START_S = 505.0  # [s] start of the FTP's hot-stabilised phase (bag 2) within the UDDS


@dataclass(frozen=True)
class Cycle:
    """A speed trace: times [s] and speeds [m/s]."""

    name: str
    t: np.ndarray
    v: np.ndarray

    def window(self, start_s: float, end_s: float = np.inf) -> Cycle:
        """The part of the cycle with start_s <= t <= end_s (e.g. FTP bag 2)."""
        keep = (self.t >= start_s) & (self.t <= end_s)
        return Cycle(f"{self.name}[{start_s:g}:{end_s:g}]", self.t[keep], self.v[keep])


def read_speed_csv(path: str | Path, time_col: str = "t_s", speed_col: str = "speed_mps") -> Cycle:
    """Read a speed-trace CSV with a time column [s] and a speed column [m/s].

    Raises:
        RunLogError: file unreadable, column missing, a value not a finite number,
            negative speed or time not strictly increasing; the message names the
            file and row.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise RunLogError(path, None, f"cannot read file ({e.strerror or e})") from e
    return _parse_trace(str(path), rows, time_col, speed_col, path.stem)


def load_cycle(name: str) -> Cycle:
    """Load a shipped cycle by name (one of :data:`CYCLES`).

    Raises:
        KeyError: unknown name.
    """
    if name not in CYCLES:
        raise KeyError(f"unknown cycle {name!r}; known: {', '.join(CYCLES)}")
    res = resources.files("energy").joinpath("data", "cycles", f"{name}.csv")
    rows = list(csv.reader(res.read_text(encoding="utf-8-sig").splitlines()))
    return _parse_trace(f"energy/data/cycles/{name}.csv", rows, "t_s", "speed_mps", name)


def _parse_trace(
    where: str, rows: list[list[str]], time_col: str, speed_col: str, name: str
) -> Cycle:
    if not rows:
        raise RunLogError(where, None, "empty file")
    header = [h.strip() for h in rows[0]]
    for col in (time_col, speed_col):
        if col not in header:
            raise RunLogError(where, None, f"missing column {col!r} (header: {','.join(header)})")
    it, iv = header.index(time_col), header.index(speed_col)
    t = np.empty(len(rows) - 1)
    v = np.empty(len(rows) - 1)
    for r, row in enumerate(rows[1:], start=1):
        for col, idx, out in ((time_col, it, t), (speed_col, iv, v)):
            try:
                out[r - 1] = float(row[idx])
            except (IndexError, ValueError):
                raise RunLogError(where, r, f"column {col!r} is not a number") from None
            if not np.isfinite(out[r - 1]):
                raise RunLogError(where, r, f"column {col!r} is not finite ({row[idx]})")
        if v[r - 1] < 0:
            raise RunLogError(where, r, f"negative speed {v[r - 1]} m/s")
        if r > 1 and t[r - 1] <= t[r - 2]:
            raise RunLogError(
                where, r, f"time not strictly increasing ({t[r - 2]} s then {t[r - 1]} s)"
            )
    if t.size < 2:
        raise RunLogError(where, None, f"need at least 2 data rows, got {t.size}")
    return Cycle(name, t, v)
