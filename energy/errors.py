"""Errors raised by :mod:`energy`.

Every error subclasses :class:`EnergyError`, and the ones about bad input also
subclass :class:`ValueError`, so callers may catch either (as msgpack does).
"""

from __future__ import annotations

from pathlib import Path


class EnergyError(Exception):
    """Base class of every error raised by the energy package."""


class TraceError(ValueError, EnergyError):
    """A time/speed trace given as arrays is unusable.

    Raised for NaN, negative speeds, non-increasing time, mismatched lengths or a
    trace that covers no distance. ``row`` is the 0-based sample index, or None
    when the problem concerns the whole trace.
    """

    def __init__(self, problem: str, row: int | None = None) -> None:
        self.problem = problem
        self.row = row
        where = f"sample {row}: " if row is not None else ""
        super().__init__(f"{where}{problem}")


class RunLogError(ValueError, EnergyError):
    """A run log or speed-trace CSV file is unreadable or invalid.

    The message names the file, the row and the problem. ``row`` is the 1-based
    data row (the header is line 1, so data row r is line r + 1), or None when the
    problem concerns the whole file (missing file, missing column, no distance).
    """

    def __init__(self, path: str | Path, row: int | None, problem: str) -> None:
        self.path = str(path)
        self.row = row
        self.problem = problem
        where = f", row {row} (line {row + 1})" if row is not None else ""
        super().__init__(f"{self.path}{where}: {problem}")


class DataError(EnergyError):
    """Package data shipped with :mod:`energy` is missing or malformed (a bug)."""
