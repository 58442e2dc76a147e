"""The OpenACC platoon files shipped in ``energy/data/openacc`` (provenance in its README).

A file holds five metadata rows (``Date``, ``Vehicle_order``, ``Number_of_vehicles``,
``ACC``, ``Distance_setting``), then a header ``Time,Speed1..SpeedN,IVS1..IVS(N-1)`` and
10 Hz rows. Car 1 is the manually driven lead; ``IVSi`` is the bumper-to-bumper spacing
between car i and car i + 1. Empty cells are gaps in the recording; they are NaN here.

:func:`read_openacc` reads one file into an :class:`OpenAccRun`; :data:`OPENACC_FILES`
names the nine shipped files; :func:`real_amplification` is the real platoon's
lead-to-last RMS speed-deviation ratio after the first fifth.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from energy.errors import DataError
from energy.string_stability import SKIP_FRACTION, Amplification, amplification

__all__ = ["OPENACC_FILES", "OpenAccRun", "read_openacc", "openacc_path", "real_amplification"]

OPENACC_FILES = (
    "long_setting_dynamic_part18.csv",
    "long_setting_dynamic_part19.csv",
    "long_setting_dynamic_part2.csv",
    "medium_setting_dynamic_part8.csv",
    "mixed_dynamic_part5.csv",
    "short_setting_dynamic_part1.csv",
    "short_setting_dynamic_part10.csv",
    "short_setting_dynamic_part20.csv",
    "short_setting_dynamic_part4.csv",
)
METADATA_ROWS = ("Date", "Vehicle_order", "Number_of_vehicles", "ACC", "Distance_setting")
PERIOD_S = 0.1  # [s] the database's sample period
TIME_JUMP_S = 0.15  # [s] a step between rows above this is a gap in the recording


@dataclass(frozen=True)
class OpenAccRun:
    """One OpenACC file: the platoon's speeds and spacings on a common time base."""

    name: str  # the file's name
    date: str  # "day.month.year"
    vehicles: tuple[str, ...]  # car models, lead first, those that took part
    acc: bool  # every follower on ACC
    distance_setting: str  # "S", "M", "L" (shortest to longest time gap)
    t: np.ndarray  # [s] [N]
    speed: np.ndarray  # [m/s] [n_cars, N], NaN in gaps
    ivs: np.ndarray  # [m] [n_cars - 1, N], row i: car i + 1 behind car i; NaN in gaps

    @property
    def n_cars(self) -> int:
        """Cars in the platoon, the lead included."""
        return self.speed.shape[0]

    def time_jumps(self) -> list[tuple[float, float]]:
        """(from, to) [s] of every step between rows longer than :data:`TIME_JUMP_S`."""
        dt = np.diff(self.t)
        return [(float(self.t[i]), float(self.t[i + 1])) for i in np.flatnonzero(dt > TIME_JUMP_S)]

    def missing(self) -> dict[str, int]:
        """Empty cells per column (``SpeedN``/``IVSN``), only the columns that have some."""
        out = {f"Speed{i + 1}": int(np.isnan(r).sum()) for i, r in enumerate(self.speed)}
        out |= {f"IVS{i + 1}": int(np.isnan(r).sum()) for i, r in enumerate(self.ivs)}
        return {k: n for k, n in out.items() if n}


def openacc_path(name: str) -> Path:
    """Path of a shipped OpenACC file in a source checkout or an installed package."""
    return Path(str(resources.files("energy").joinpath("data", "openacc", name)))


def _metadata(path: str, rows: list[list[str]]) -> dict[str, list[str]]:
    meta = {}
    for key, row in zip(METADATA_ROWS, rows, strict=True):
        if not row or row[0] != key:
            raise DataError(f"{path}: metadata row {key!r} expected, got {row[:1]}")
        meta[key] = [c for c in row[1:] if c != ""]
    return meta


def _column(path: str, header: list[str], name: str) -> int:
    try:
        return header.index(name)
    except ValueError:
        raise DataError(f"{path}: no column {name!r} in the header {header}") from None


def read_openacc(path: str | Path) -> OpenAccRun:
    """Read one OpenACC file (a path, or a name of :data:`OPENACC_FILES`).

    Raises:
        DataError: missing file, bad metadata, missing columns, a bad number, or times
            that do not increase.
    """
    p = openacc_path(str(path)) if str(path) in OPENACC_FILES else Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise DataError(f"{p}: cannot read the OpenACC file ({e.strerror})") from e
    rows = list(csv.reader(io.StringIO(text)))
    if len(rows) < len(METADATA_ROWS) + 3:
        raise DataError(f"{p}: too short for an OpenACC file ({len(rows)} rows)")
    meta = _metadata(str(p), rows[: len(METADATA_ROWS)])
    try:
        n = int(meta["Number_of_vehicles"][0])
    except (IndexError, ValueError):
        raise DataError(f"{p}: Number_of_vehicles is not a number: {meta['Number_of_vehicles']}") from None
    header = rows[len(METADATA_ROWS)]
    cols = [_column(str(p), header, c) for c in ["Time", *(f"Speed{i}" for i in range(1, n + 1)), *(f"IVS{i}" for i in range(1, n))]]
    body = [r for r in rows[len(METADATA_ROWS) + 1 :] if r]
    data = np.full((len(body), len(cols)), np.nan)
    for r, row in enumerate(body):
        for j, c in enumerate(cols):
            cell = row[c] if c < len(row) else ""
            if cell != "":
                try:
                    data[r, j] = float(cell)
                except ValueError:
                    raise DataError(f"{p}, data row {r + 1}: {header[c]} is not a number: {cell!r}") from None
    t = data[:, 0]
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0.0)):
        raise DataError(f"{p}: Time must be present and strictly increasing")
    return OpenAccRun(
        name=p.name,
        date=".".join(meta["Date"]),
        vehicles=tuple(meta["Vehicle_order"][:n]),
        acc=meta["ACC"][:1] == ["1"],
        distance_setting="".join(meta["Distance_setting"]),
        t=t,
        speed=data[:, 1 : n + 1].T.copy(),
        ivs=data[:, n + 1 :].T.copy(),
    )


def real_amplification(run: OpenAccRun, skip_fraction: float = SKIP_FRACTION) -> Amplification:
    """The real platoon's amplification (per pair and lead to last) after the first fifth."""
    return amplification(run.t, run.speed, skip_fraction=skip_fraction)
