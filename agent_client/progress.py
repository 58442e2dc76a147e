"""Progress bars: tqdm for every command (training, evaluation, bench).

On a terminal, tqdm's own bar. Anywhere else (CI, a log file) the same line is written
as a whole line every :data:`LOG_PERIOD` seconds and once at the end, never with
carriage returns that turn a log into one unreadable line.
"""

from __future__ import annotations

import sys
from typing import Any, TextIO

from tqdm import tqdm

__all__ = ["progress_bar", "LOG_PERIOD"]

LOG_PERIOD = 30.0  # [s] between the lines of a progress bar written to a non-terminal
tqdm.monitor_interval = 0  # no monitor thread: trainers fork actors and evaluations fork runs


class _Lines:
    """A text stream that drops tqdm's bare newline at close: each line already ends in one."""

    def __init__(self, out: TextIO):
        self.out = out

    def write(self, s: str) -> int:
        return 0 if s == "\n" else self.out.write(s)

    def flush(self) -> None:
        self.out.flush()

    def isatty(self) -> bool:
        return False


class _LogLines(tqdm):  # type: ignore[type-arg]
    """tqdm that writes each refresh as its own line."""

    def display(self, msg: str | None = None, pos: int | None = None) -> bool:
        self.fp.write((msg if msg is not None else self.__str__()) + "\n")
        self.fp.flush()
        return True


def progress_bar(total: int, label: str, *, enabled: bool = True, initial: int = 0, unit: str = "it", file: TextIO | None = None, **kw: Any) -> tqdm:  # type: ignore[type-arg]
    """A tqdm bar on stderr (or ``file``): a live bar on a terminal, whole lines elsewhere.

    Args:
        total: the count at the end.
        label: what is counted, shown first.
        enabled: False: no output at all.
        initial: the count already done (a resumed run), left out of the rate.
        unit: the unit of the count ("step", "run").
    """
    out = file if file is not None else sys.stderr
    tty = out.isatty()
    cls = tqdm if tty else _LogLines
    return cls(
        total=total, desc=label, initial=initial, unit=unit, file=out if tty else _Lines(out), disable=not enabled, dynamic_ncols=tty,
        mininterval=0.5 if tty else LOG_PERIOD, ascii=not tty, **kw,
    )  # fmt: skip
