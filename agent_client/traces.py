"""Reading a lead speed trace CSV (``t_s,speed_mps``) given by the user."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from agent_client.errors import InputFileError
from protocol.scenarios import TRACE_MAX_SAMPLES, check_trace_size

__all__ = ["load_trace"]


def load_trace(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Times [s] and speeds [m/s] from a CSV with header ``t_s,speed_mps``.

    Raises:
        InputFileError: naming the file and line of the first problem.
    """
    path = Path(path)
    t: list[float] = []
    v: list[float] = []
    try:
        with path.open(encoding="utf-8-sig", newline="") as f:  # -sig: a BOM is not part of the header  # streamed: a huge file stops at the limit
            rows = csv.reader(f)
            header = next(rows, [])
            if [c.strip() for c in header[:2]] != ["t_s", "speed_mps"]:
                raise InputFileError(f"{path}:1: expected header 't_s,speed_mps'")
            for line, row in enumerate(rows, start=2):
                if not row:
                    continue
                if len(t) == TRACE_MAX_SAMPLES:
                    raise InputFileError(f"{path}:{line}: a trace holds at most {TRACE_MAX_SAMPLES} samples (docs/scenarios.md)")
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
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read trace: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(f"{path}: not a text CSV ({type(exc).__name__})") from None
    if len(t) < 2:
        raise InputFileError(f"{path}: a trace needs at least two samples")
    try:
        check_trace_size(len(t), t[-1] - t[0])
    except ValueError as exc:
        raise InputFileError(f"{path}: {exc} (docs/scenarios.md)") from None
    return np.array(t), np.array(v)
