"""The lossy runs drive the head of test-1 and compare it with the clean run's log."""

from __future__ import annotations

from pathlib import Path

LOSSY_SECONDS = 30.0  # [s] of test-1 the lossy runs drive: an eighth of it, 300 lockstep steps


def assert_prefix_of(short: Path, full: Path) -> None:
    """A run cut short by --duration is, byte for byte, the head of the whole run's log."""
    head = short.read_bytes()
    assert head and full.read_bytes().startswith(head), f"{short} is not the head of {full}"
