"""A trained checkpoint driven briefly through `vacc drive` (a real server), for the tests
that end a training run by driving its policy."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from vacc.cli import main


def drive_briefly(checkpoint: Path, log: Path, trajectory: str = "stopped", duration: float = 2.0) -> Path:
    """Drive ``checkpoint`` for ``duration`` seconds of ``trajectory``; the run log (the drive
    must succeed)."""
    result = CliRunner().invoke(
        main, ["drive", "--controller", "ddqn", "--checkpoint", str(checkpoint), "--trajectory", trajectory, "--duration", str(duration), "--log", str(log)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return log
