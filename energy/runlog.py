"""Reading and validating run logs (``vacc drive --log``).

A run log is a CSV with one row per control step, in SI units, and at least the
columns ``t,frame,v_host,v_lead,gap,accel,force,collision`` (t [s], speeds [m/s],
gap [m], accel [m/s^2], force in [-1, 1], collision 0/1). Other columns are
ignored. The control period is read from ``t``, never assumed.

:func:`read_run_log` reads a log whole; :func:`iter_run_log` yields it in chunks of at most
:data:`SEGMENT_ROWS` rows, for a scorer that streams (:mod:`energy.metrics`). Both are the
same reader: the same checks, the same messages.
"""

from __future__ import annotations

import csv
import math
import operator
import re
from array import array
from collections.abc import Iterable, Iterator
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

    def chunks(self, rows: int) -> Iterator[RunLog]:
        """The log in consecutive chunks of at most ``rows`` rows (views, no copy), as
        :func:`iter_run_log` gives a file."""
        for i in range(0, self.t.size, rows):
            yield RunLog(self.path, *(getattr(self, c)[i : i + rows] for c in REQUIRED_COLUMNS))


SEGMENT_ROWS = 65536
"""Rows in one chunk of :func:`iter_run_log` (4 MiB of columns), and in one segment of
:func:`energy.metrics.evaluate_run`."""

_FIELD = r"[+-]?[0-9]{1,20}(?:\.[0-9]{0,20})?(?:[eE][+-]?[0-9]{1,2})?"
_FAST_ROW = re.compile(",".join([_FIELD] * len(REQUIRED_COLUMNS)))
"""The required fields of a row joined by commas, when each is a number as a log writes it:
float() reads it, and it cannot overflow. Any other row is read field by field, which names
the problem; the two agree on every row this matches (``float`` of the same text)."""


def read_run_log(path: str | Path) -> RunLog:
    """Read and check a run log CSV, streaming (:func:`iter_run_log`): memory grows by 64
    bytes a row, whatever the file holds.

    Args:
        path: the CSV file.

    Returns:
        The validated log.

    Raises:
        RunLogError: see :func:`iter_run_log`.
    """
    path = Path(path)
    parts = list(_chunks(path, SEGMENT_ROWS))
    if len(parts) == 1:
        return RunLog(path=str(path), **parts[0])  # type: ignore[arg-type]
    # column by column, each chunk's copy freed as it goes: 8 bytes a row over the 64
    cols = {c: np.concatenate([p.pop(c) for p in parts]) for c in REQUIRED_COLUMNS}
    return RunLog(path=str(path), **cols)  # type: ignore[arg-type]


def iter_run_log(path: str | Path, rows: int | None = None) -> Iterator[RunLog]:
    """Read and check a run log CSV in chunks of at most ``rows`` rows (default
    :data:`SEGMENT_ROWS`), never holding more than one chunk.

    Each row is checked as it is read, against the row before it even across a chunk's
    edge; the whole-file checks (two rows, a distance) come after the last chunk, so a
    caller must not trust what it computed until the iterator has ended.

    Args:
        path: the CSV file.
        rows: rows a chunk holds at most.

    Yields:
        Consecutive rows of the log as a :class:`RunLog` (``path`` the file's; a chunk
        may be a single row).

    Raises:
        RunLogError: the file is missing or unreadable, a required column is missing,
            a column name repeats, a field is over the CSV field limit, a value is
            empty, not a plain number (``1_0``), NaN or infinite, a speed is negative,
            time does not strictly increase, force is outside [-1, 1], collision is not
            0/1, frame is not an integer, the gap is negative without a collision, there
            are fewer than two rows, or the host covers no distance. The message names
            the file, the row and the problem.
    """
    path = Path(path)
    for cols in _chunks(path, SEGMENT_ROWS if rows is None else rows):
        yield RunLog(path=str(path), **cols)  # type: ignore[arg-type]


def _chunks(path: Path, rows: int) -> Iterator[dict[str, np.ndarray]]:
    """The columns of :func:`iter_run_log`'s chunks."""
    n, moved = 0, False
    last: dict[str, float] = {}
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header = _header(path, reader)
            idx = {c: header.index(c) for c in REQUIRED_COLUMNS}
            while (cols := _read_chunk(path, reader, idx, n, rows, last)) is not None:
                moved = moved or _moves(cols, last)
                n += cols["t"].size
                last = {c: float(a[-1]) for c, a in cols.items()}
                yield cols
    except FileNotFoundError:
        raise RunLogError(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RunLogError(path, None, f"cannot read file ({e})") from None
    if n < 2:
        raise RunLogError(path, None, f"need at least 2 data rows, got {n}")
    if not moved:
        raise RunLogError(path, None, f"zero distance travelled (v_host is 0 on all {n} rows)")


def _moves(cols: dict[str, np.ndarray], last: dict[str, float]) -> bool:
    """Whether the host covers distance over the chunk's intervals (and the one from the row
    before it): the distance's trapezoid sum is > 0 exactly when one of its terms is."""
    t, v = cols["t"], cols["v_host"]
    if last:
        t, v = np.concatenate([[last["t"]], t]), np.concatenate([[last["v_host"]], v])
    return bool(np.any(0.5 * (v[1:] + v[:-1]) * np.diff(t) > 0.0))


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


def _read_chunk(
    path: Path, reader: Iterator[list[str]], idx: dict[str, int], r0: int, rows: int,
    last: dict[str, float],
) -> dict[str, np.ndarray] | None:
    """The required columns of the next ``rows`` rows at most (data rows ``r0 + 1`` on),
    checked; None at the end of the file. ``last``: the row before them ({} for none).

    Raises:
        RunLogError: a bad row (see :func:`iter_run_log`), naming it; a bad row before it
            in the chunk is named first, as a row-by-row reader would.
    """
    cols = _Columns()
    get = operator.itemgetter(*idx.values())
    r = r0
    while r - r0 < rows:
        try:
            row = next(reader, None)
        except csv.Error as e:
            _check_rows(path, r0, cols.arrays(), last)
            raise RunLogError(path, r + 1, f"not a CSV row ({e})") from None
        if row is None:
            break
        r += 1
        try:
            fields = get(row)
        except IndexError:  # a short row: the field-by-field reading names its empty column
            fields = ()
        if fields and _FAST_ROW.fullmatch(",".join(fields)):
            cols.add(map(float, fields))
            continue
        try:
            cols.add(_parse_row(path, r, row, idx))
        except RunLogError:
            _check_rows(path, r0, cols.arrays(), last)
            raise
    return _check_rows(path, r0, cols.arrays(), last) if r > r0 else None


class _Columns:
    """Rows' values gathered into one ``array('d')`` a column: 8 bytes a value, and one
    ``extend`` a row (a batch of rows is moved to the columns at a time)."""

    BATCH = 1024  # [rows]

    def __init__(self) -> None:
        self.batch = array("d")
        self.cols = [array("d") for _ in REQUIRED_COLUMNS]

    def add(self, values: Iterable[float]) -> None:
        self.batch.extend(values)
        if len(self.batch) >= self.BATCH * len(self.cols):
            self._flush()

    def _flush(self) -> None:
        block = np.frombuffer(self.batch, dtype=np.float64).reshape(-1, len(self.cols))
        for j, col in enumerate(self.cols):
            col.frombytes(block[:, j].tobytes())
        del block  # releases the batch's buffer, so that it can shrink
        del self.batch[:]

    def arrays(self) -> dict[str, np.ndarray]:
        """The columns as float64 arrays over the same memory; no row may be added after."""
        self._flush()
        return {c: np.frombuffer(a, dtype=np.float64) for c, a in zip(REQUIRED_COLUMNS, self.cols, strict=True)}


def _parse_row(path: Path, r: int, row: list[str], idx: dict[str, int]) -> list[float]:
    """The required values of data row ``r``, field by field. Raises RunLogError: empty,
    not a plain number, not finite."""
    values = []
    for c, i in idx.items():
        if i >= len(row) or not row[i].strip():
            raise RunLogError(path, r, f"column {c!r} is empty")
        if PLAIN_FLOAT.fullmatch(row[i]) is None:  # float() would take '1_0'
            raise RunLogError(path, r, f"column {c!r} is not a number ({row[i]!r})")
        x = float(row[i])
        if not math.isfinite(x):
            raise RunLogError(path, r, f"column {c!r} is {row[i].strip()} (must be finite)")
        values.append(x)
    return values


def _check_rows(
    path: Path, r0: int, cols: dict[str, np.ndarray], last: dict[str, float]
) -> dict[str, np.ndarray]:
    """``cols`` (data rows ``r0 + 1`` on), each row checked against the one before (``last``
    for the first). Raises RunLogError: the first bad row.

    A vectorised screen flags the rows :func:`_check_row` refuses; only then are the rows
    checked one by one from the first flagged, for its message.
    """
    t, coll, frame = cols["t"], cols["collision"], cols["frame"]
    bad = (cols["v_host"] < 0.0) | (cols["v_lead"] < 0.0)
    bad |= np.abs(cols["force"]) > 1.0 + FORCE_TOLERANCE
    bad |= (coll != 0.0) & (coll != 1.0)
    bad |= frame != np.floor(frame)  # an integer, as frame == round(frame)
    bad |= (cols["gap"] < 0.0) & (coll == 0.0)
    bad[1:] |= ~(t[1:] > t[:-1])
    if last and t.size:
        bad[0] |= not t[0] > last["t"]
    if bad.any():
        k = int(np.argmax(bad))
        prev = last if k == 0 else {c: float(a[k - 1]) for c, a in cols.items()}
        for j in range(k, t.size):
            row = {c: float(a[j]) for c, a in cols.items()}
            _check_row(path, r0 + j + 1, row, prev)
            prev = row
    return cols


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
