"""Fixtures for the energy tests."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from energy_log_rows import COLUMNS


@pytest.fixture
def write_log(tmp_path: Path) -> Callable[..., Path]:
    """Write rows (dicts, or arrays by column) to a CSV in tmp_path and return its path."""

    def write(
        rows: list[dict[str, object]] | dict[str, np.ndarray], name: str = "run.csv", columns=None
    ) -> Path:
        if isinstance(rows, dict):
            keys = list(rows)
            rows = [dict(zip(keys, vals, strict=True)) for vals in zip(*rows.values(), strict=True)]
        cols = list(columns or (rows[0].keys() if rows else COLUMNS))
        path = tmp_path / name
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        return path

    return write
