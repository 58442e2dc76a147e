"""The run log: one CSV row per control step, in SI units.

Columns (DESIGN.md): ``t`` [s], ``frame``, ``v_host`` and ``v_lead`` [m/s], ``gap``
[m], ``accel`` [m/s^2] (host, over the last control period), ``force`` (the u that
produced this frame, in [-1, 1]), ``collision`` (0/1), then ``a_lead`` [m/s^2], then
a controller's own columns, if it has any (a DDQN model with a gap head: ``gap_est`` [m],
its estimate of the gap from the frames up to that row; empty where it did not decide).
Floats are written with Python's shortest round-trip repr, so a log is exact and
byte-identical for identical runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import IO, Any

__all__ = ["COLUMNS", "RunLog"]

COLUMNS = ("t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision", "a_lead")


class RunLog:
    """Writes observations as rows; a context manager. ``path=None`` writes nothing.
    ``extra``: the names of columns after :data:`COLUMNS`."""

    def __init__(self, path: str | Path | None, extra: tuple[str, ...] = ()):
        self.path = Path(path) if path is not None else None
        self.extra = tuple(extra)
        self._file: IO[str] | None = None
        self.rows = 0

    def __enter__(self) -> RunLog:
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self.path.open("w", newline="\n", encoding="ascii")
            self._file.write(",".join(COLUMNS + self.extra) + "\n")
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Flush and close; safe to call twice."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def write(self, obs: dict[str, Any], extra: tuple[float, ...] = ()) -> None:
        """Append one observation, with the values of the ``extra`` columns (missing ones empty)."""
        self.rows += 1
        if self._file is None:
            return
        tail = "".join("," + (repr(extra[i]) if i < len(extra) else "") for i in range(len(self.extra)))
        self._file.write(
            f"{obs['t']!r},{obs['frame']},{obs['v_host']!r},{obs['v_lead']!r},{obs['gap']!r},"
            f"{obs['accel']!r},{obs['force']!r},{int(obs['collision'])},{obs['a_lead']!r}{tail}\n"
        )
