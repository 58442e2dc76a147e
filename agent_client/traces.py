"""Reading a lead speed trace CSV (``t_s,speed_mps``) given by the user."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from agent_client.errors import InputFileError

__all__ = ["load_trace"]


def load_trace(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Times [s] and speeds [m/s] from a CSV with header ``t_s,speed_mps``.

    Raises:
        InputFileError: naming the file and line of the first problem.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read trace: {exc.strerror or exc}") from None
    rows = list(csv.reader(text.splitlines()))
    if not rows or [c.strip() for c in rows[0][:2]] != ["t_s", "speed_mps"]:
        raise InputFileError(f"{path}:1: expected header 't_s,speed_mps'")
    t: list[float] = []
    v: list[float] = []
    for line, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            ti, vi = float(row[0]), float(row[1])
        except (ValueError, IndexError):
            raise InputFileError(f"{path}:{line}: expected two numbers, got {','.join(row)!r}") from None
        if not (math.isfinite(ti) and math.isfinite(vi)):
            raise InputFileError(f"{path}:{line}: value is not finite")
        if vi < 0:
            raise InputFileError(f"{path}:{line}: negative speed {vi}")
        if t and ti <= t[-1]:
            raise InputFileError(f"{path}:{line}: time {ti} does not increase")
        t.append(ti)
        v.append(vi)
    if len(t) < 2:
        raise InputFileError(f"{path}: a trace needs at least two samples")
    return np.array(t), np.array(v)
