"""Run scalars (``scalars.csv``, and TensorBoard events when installed) and the progress line.

Metric names are grouped as CleanRL's: ``charts/``, ``losses/``, ``eval/``.
"""

from __future__ import annotations

import csv
import io
import sys
import time
from pathlib import Path
from typing import Any

__all__ = ["ScalarLog", "Progress", "logged_wall_s"]

FLUSH_EVERY_S = 10.0  # [s] scalars.csv reaches the disk at least this often while rows come


EPISODE_ROW = "charts/episodic_return"  # one row per finished episode, in both trainers


def _rows_up_to(path: Path, step: int, episodes: int | None = None) -> list[list[str]]:
    """The rows of ``scalars.csv`` at or before ``step``. A torn last line (a kill while the
    file was being written) is dropped: it was never a whole row.

    Args:
        path: the file.
        step: the resumed checkpoint's step.
        episodes: the checkpoint's episode count, which must match the episode rows up to
            ``step`` (a cut or foreign file fails); None: not checked.

    Raises:
        InputFileError: a missing file, a row that is not ``step,name,value,wall_s``, or
            other episodes than the checkpoint's (one line naming the file).
    """
    from agent_client.errors import InputFileError

    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputFileError(f"{path}: not found; latest.pt's run logged its scalars there") from None
    except (UnicodeDecodeError, OSError) as exc:
        raise InputFileError(f"{path}: not a scalars CSV ({type(exc).__name__})") from None
    whole = text[: text.rfind("\n") + 1]
    if not whole:
        raise InputFileError(f"{path}: not a scalars CSV (no header line)")
    kept = []
    try:
        for line, row in enumerate(csv.reader(io.StringIO(whole, newline="")), start=1):
            if line == 1 and row != ["step", "name", "value", "wall_s"]:
                raise InputFileError(f"{path}:1: not the header step,name,value,wall_s")
            if line == 1 or not row:
                continue
            if len(row) != 4 or not row[0].isdigit():
                raise InputFileError(f"{path}:{line}: not a step,name,value,wall_s row")
            if int(row[0]) <= step:
                kept.append(row)
    except csv.Error as exc:
        raise InputFileError(f"{path}: not a scalars CSV ({type(exc).__name__}: {exc})") from None
    if episodes is not None and (logged := sum(r[1] == EPISODE_ROW for r in kept)) != episodes:
        raise InputFileError(f"{path}: {logged} episodes logged up to step {step}, latest.pt counts {episodes}: the file is cut or of another run")
    return kept


def logged_wall_s(run_dir: Path) -> float:
    """[s] The wall time a run's ``scalars.csv`` spans: its rows' ``wall_s`` restart at 0 with
    each resume, so the last value of each run segment, summed. A resume drops the rows it
    redoes, so a run stopped and resumed counts about what it would have taken at once.

    Raises:
        InputFileError: see :func:`_rows_up_to`.
    """
    total = last = 0.0
    for row in _rows_up_to(run_dir / "scalars.csv", 2**62):
        wall = float(row[3])
        if wall < last:  # a resumed segment starts again
            total += last
        last = wall
    return total + last


class ScalarLog:
    """``scalars.csv`` (``step,name,value,wall_s``), plus TensorBoard if installed."""

    def __init__(self, run_dir: Path, resume_step: int | None = None, resume_episodes: int | None = None):
        """Open the log; with ``resume_step``, keep the rows up to it (see :func:`_rows_up_to`,
        which checks the file before anything is written).

        Raises:
            InputFileError: (resume) a missing or bad ``scalars.csv``.
        """
        path = run_dir / "scalars.csv"
        if resume_step is not None:  # drop rows the resumed run will redo
            kept = _rows_up_to(path, resume_step, resume_episodes)
            with open(path, "w", newline="") as f:
                csv.writer(f).writerows([["step", "name", "value", "wall_s"], *kept])
            self._file = open(path, "a", newline="")
        else:
            self._file = open(path, "w", newline="")
            self._file.write("step,name,value,wall_s\n")
        self._csv = csv.writer(self._file)
        self._t0 = self._flushed = time.time()
        self._tb = None
        try:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(run_dir))
        except ImportError:  # tensorboard is an optional extra
            pass

    def add(self, name: str, value: float, step: int) -> None:
        now = time.time()
        self._csv.writerow([step, name, f"{value:.6g}", f"{now - self._t0:.1f}"])
        if now - self._flushed > FLUSH_EVERY_S:  # so that a user tailing the file sees it move
            self.flush()
        if self._tb is not None:
            self._tb.add_scalar(name, value, step)

    def text(self, name: str, text: str) -> None:
        """A text summary (TensorBoard only), e.g. the run's hyperparameters."""
        if self._tb is not None:
            self._tb.add_text(name, text)

    def frames(self, name: str, frames: Any, step: int) -> None:
        """Camera frames ``[N, H, W]`` uint8 as images (TensorBoard only)."""
        if self._tb is not None:
            self._tb.add_images(name, frames[:, None], step, dataformats="NCHW")

    def flush(self) -> None:
        self._flushed = time.time()
        self._file.flush()
        if self._tb is not None:
            self._tb.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


class Progress:
    """The training progress bar (:func:`agent_client.progress.progress_bar`): steps,
    steps/s and ETA from tqdm, with what explores (``label``: ε, or the actor-critic's noise)
    and the recent return after them."""

    def __init__(self, total: int, enabled: bool = True, initial: int = 0, label: str = "eps"):
        from agent_client.progress import progress_bar

        self.enabled, self.label = enabled, label
        self.bar = progress_bar(total, "train", enabled=enabled, initial=initial, unit="step")
        self.tty = sys.stderr.isatty()

    def update(self, step: int, epsilon: float, recent_return: float, force: bool = False, extra: str = "") -> None:
        """Move to ``step``; ``force`` redraws at once (the final line)."""
        self.bar.set_postfix_str(f"{self.label} {epsilon:.3f}  return {recent_return:8.2f}" + (f"  {extra}" if extra else ""), refresh=False)
        self.bar.update(step - self.bar.n)
        if force and self.tty:  # a log gets its final line from close()
            self.bar.refresh()

    def write(self, message: str) -> None:
        """A line of its own on stderr, above a live bar."""
        if self.tty:
            self.bar.write(message, file=sys.stderr)
        else:
            sys.stderr.write(message + "\n")
            sys.stderr.flush()

    def close(self) -> None:
        self.bar.close()
