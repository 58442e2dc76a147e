"""Stopping a training by signal.

The first SIGINT (Ctrl-C) or SIGTERM (``kill``, a batch system's pre-emption) sets
:data:`STOP`: the loop ends at its next step with a checkpoint, and the run resumes.
A second signal aborts at once (``SystemExit``; the ``finally`` blocks reap servers
and actors).

The first signal does not raise: an exception raised from a handler can land while a
library thread's lock is held (TensorBoard's event-writer queue), and the clean-up
after it would then wait on that lock forever.
"""

from __future__ import annotations

import signal
import threading

import click

__all__ = ["STOP", "install_stop_handlers", "stop_exit_code", "stop_cause"]

# Set by the first SIGINT or SIGTERM to end either training loop at its next step with a checkpoint.
STOP = threading.Event()
_first_signal: list[int] = []  # the signal that set STOP

_NAMES: dict[int, str] = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


def install_stop_handlers(prog: str, then: str) -> None:
    """Handle SIGINT and SIGTERM in the main thread; ``then`` says what follows the stop."""

    def handler(signum: int, frame: object) -> None:
        if STOP.is_set():
            raise SystemExit(128 + signum)
        _first_signal[:] = [signum]
        STOP.set()
        again = "Ctrl-C" if signum == signal.SIGINT else "signal"
        click.echo(f"\n{prog}: {_NAMES.get(signum, 'signal')}: stopping after this step with a checkpoint{then} ({again} again to abort)", err=True)

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


def stop_cause() -> str:
    """What set :data:`STOP`: "Ctrl-C" or "SIGTERM"."""
    return _NAMES.get(_first_signal[0], "signal") if _first_signal else "Ctrl-C"


def stop_exit_code() -> int:
    """The exit status of a run stopped by a signal: 128 + its number, as the shell reports a killed job."""
    return 128 + (_first_signal[0] if _first_signal else signal.SIGINT)
