"""The run log: one CSV row per control step, in SI units.

Columns (DESIGN.md): ``t`` [s], ``frame``, ``v_host`` and ``v_lead`` [m/s], ``gap``
[m], ``accel`` [m/s^2] (host, over the last control period), ``force`` (the u that
produced this frame, in [-1, 1]), ``collision`` (0/1), then ``a_lead`` [m/s^2], then
a controller's own columns, if it has any (a DDQN model with a gap head: ``gap_est`` [m],
its estimate of the gap from the frames up to that row; empty where it did not decide).
Floats are written with Python's shortest round-trip repr, so a log is exact and
byte-identical for identical runs.

``vacc drive`` writes a **card** beside it (:func:`card_path`: ``run.csv`` ->
``run.card.json``): what the CSV cannot say, the episode asked for, the road it was
driven on (the server's traffic, sun range and seed salt), the controller and its checkpoint's
digest, and how the run ended. The CSV stays byte-identical; the card has a clock time.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import IO, Any

from agent_client.errors import InputFileError

__all__ = ["COLUMNS", "format_row", "RunLog", "CARD_VERSION", "card_path", "write_card", "read_card", "file_sha256"]

CARD_VERSION = 1

COLUMNS = ("t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision", "a_lead")


def format_row(obs: dict[str, Any]) -> str:
    """The :data:`COLUMNS` of one observation as a log row writes them (no newline)."""
    return (
        f"{obs['t']!r},{obs['frame']},{obs['v_host']!r},{obs['v_lead']!r},{obs['gap']!r},"
        f"{obs['accel']!r},{obs['force']!r},{int(obs['collision'])},{obs['a_lead']!r}"
    )


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
        self._file.write(f"{format_row(obs)}{tail}\n")


def card_path(log: str | Path) -> Path:
    """Where the card of run log ``log`` goes: ``run.csv`` -> ``run.card.json``, beside it."""
    p = Path(log)
    return p.with_name((p.stem if p.suffix else p.name) + ".card.json")


def write_card(log: str | Path, card: dict[str, Any]) -> Path:
    """Write ``card`` (JSON-able) as the card of run log ``log``, whole or not at all
    (a temporary file renamed over it); returns its path."""
    path = card_path(log)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(_finite({"card": CARD_VERSION, **card}), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float as None (JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def read_card(log: str | Path) -> dict[str, Any] | None:
    """The card of run log ``log``; None where it has none.

    Raises:
        InputFileError: one line: the card is not JSON, or not a card of a version this reads.
    """
    path = card_path(log)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: cannot read it ({exc})") from None
    try:
        card = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputFileError(f"{path}: not JSON ({exc})") from None
    if not isinstance(card, dict) or card.get("card") != CARD_VERSION:
        got = card.get("card") if isinstance(card, dict) else type(card).__name__
        raise InputFileError(f"{path}: not a run card of version {CARD_VERSION} (card: {got!r})")
    return card


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes: which checkpoint or trace a card names."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()
