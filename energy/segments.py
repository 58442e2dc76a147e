"""A run log in segments with context rows, so that it can be scored piece by piece.

A scorer that cannot hold a long log whole (:func:`energy.metrics.evaluate_run`) adds up
what each :class:`Segment` contributes. A metric that needs a row's neighbours (the next
row's time, the row before, the windows after it, a look-back before it) finds them as
context: a segment holds its core rows, the rows before them back to a time the caller
names, and the rows after them for a time ahead, or up to the log's last row.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from energy.runlog import REQUIRED_COLUMNS, RunLog

__all__ = ["Segment", "segments"]


@dataclass(frozen=True)
class Segment:
    """Core rows of a log with their context: ``rows.t[c0:c1]`` and so on are the core."""

    rows: RunLog
    """Consecutive rows of the log: context before, the core, context after."""
    c0: int
    """The core's first row in ``rows``; > 0 unless the core starts the log."""
    c1: int
    """One past the core's last row in ``rows``."""
    start: int
    """The log's index of ``rows``' first row (0: this segment holds the log's first row)."""
    end: bool
    """Whether ``rows`` reaches the log's last row."""

    @property
    def first(self) -> bool:
        """Whether the core starts the log (``start`` is 0 for every segment whose context
        reaches back to the log's first row)."""
        return self.c0 == 0


def segments(
    chunks: Iterable[RunLog], rows: int, back: Callable[[float], float], ahead_s: float
) -> Iterator[Segment]:
    """The log that ``chunks`` (consecutive rows) make up, in segments of at most ``rows``
    core rows, holding one segment's rows and a chunk at a time.

    Args:
        chunks: the log's rows in order, e.g. :func:`energy.runlog.iter_run_log`.
        rows: core rows a segment holds at most (fewer only at the log's end).
        back: for the time [s] of a core's first row, the time [s] its context before
            must reach back past: a segment starts at the last row earlier than that, or
            at the log's first row; it always holds the row before its core.
        ahead_s: context after [s]: a segment reaches the first row at or after its last
            core row's time plus ``ahead_s``, at least the row after its core, or the log's
            last row (then ``end``), however many rows that takes.
    """
    buf: dict[str, np.ndarray] = {}
    start = s0 = 0  # the log's index of buf's first row; of the next core's first row
    path = ""
    for chunk in chunks:
        path = chunk.path
        new = {c: getattr(chunk, c) for c in REQUIRED_COLUMNS}
        buf = {c: np.concatenate([buf[c], a]) for c, a in new.items()} if buf else new
        while (seg := _take(buf, path, start, s0, rows, back, ahead_s, end=False)) is not None:
            yield seg
            s0 = seg.start + seg.c1
            buf, start = _trim(buf, start, s0, back)
    while buf and s0 < start + buf["t"].size:
        seg = _take(buf, path, start, s0, rows, back, ahead_s, end=True)
        assert seg is not None
        yield seg
        s0 = seg.start + seg.c1


def _take(
    buf: dict[str, np.ndarray], path: str, start: int, s0: int, rows: int,
    back: Callable[[float], float], ahead_s: float, end: bool,
) -> Segment | None:
    """The segment whose core starts at the log's row ``s0``, if ``buf`` holds its context
    (``end``: buf holds the log's last row); else None."""
    t = buf["t"]
    c0 = s0 - start
    c1 = min(c0 + rows, t.size)
    if end:
        e1 = t.size
    else:
        if c1 - c0 < rows:
            return None
        e1 = max(int(np.searchsorted(t, t[c1 - 1] + ahead_s)) + 1, c1 + 1)
        if e1 > t.size:
            return None
    e0 = _first_context_row(t, c0, back)
    cols = {c: a[e0:e1] for c, a in buf.items()}
    return Segment(RunLog(path=path, **cols), c0 - e0, c1 - e0, start + e0, end)  # type: ignore[arg-type]


def _first_context_row(t: np.ndarray, c0: int, back: Callable[[float], float]) -> int:
    """The last row earlier than ``back(t[c0])``, at most ``c0 - 1`` (0 if none: buf's first
    row is then the log's, or was kept for an earlier core whose look-back reached further)."""
    if c0 == 0:
        return 0
    return min(max(int(np.searchsorted(t, back(t[c0]))) - 1, 0), c0 - 1)


def _trim(
    buf: dict[str, np.ndarray], start: int, s0: int, back: Callable[[float], float]
) -> tuple[dict[str, np.ndarray], int]:
    """``buf`` from the first row the core at the log's row ``s0`` needs; its new start."""
    if s0 - start >= buf["t"].size:
        return buf, start
    e0 = _first_context_row(buf["t"], s0 - start, back)
    return {c: a[e0:] for c, a in buf.items()}, start + e0
