"""Stopping a training by signal.

Inside :func:`stop_handlers`, the first SIGINT (Ctrl-C) or SIGTERM (``kill PID``) sets
:data:`STOP`: the loop ends with a checkpoint where it can resume (the single-stream loop at
the episode's end, so exactly; the K-stream one after the batch in flight), and the run resumes.
The step in flight finishes first (an evaluation, a checkpoint being written). A second
signal aborts at once (``SystemExit``; the ``finally`` blocks reap servers and actors).

The first signal does not raise: an exception raised from a handler can land while a
library thread's lock is held (TensorBoard's event-writer queue), and the clean-up
after it would then wait on that lock forever.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

__all__ = ["STOP", "stop_handlers", "reinstall_stop_handler", "stop_exit_code", "stop_cause", "worker_signals", "handlers_active"]

# Set by the first SIGINT or SIGTERM to end either training loop with a checkpoint it can resume from.
STOP = threading.Event()
_first_signal: list[int] = []  # the signal that set STOP
_handler: list[object] = []  # the handler installed by the innermost stop_handlers

_NAMES: dict[int, str] = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}
SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_handlers(prog: str, then: str) -> Iterator[None]:
    """Handle SIGINT and SIGTERM (main thread) for the block; ``then`` says what follows
    the stop. On leaving, the previous handlers come back and :data:`STOP` is cleared."""

    def handler(signum: int, frame: object) -> None:
        if STOP.is_set():
            raise SystemExit(128 + signum)
        _first_signal[:] = [signum]
        STOP.set()
        again = "Ctrl-C" if signum == signal.SIGINT else "signal"
        # os.write, not print: a handler that runs inside a write to stderr (a progress
        # bar's) must not write through the same buffer.
        os.write(2, f"\n{prog}: {_NAMES.get(signum, 'signal')}: stopping at the next point it can resume from, with a checkpoint{then} ({again} again to abort)\n".encode())

    previous = {s: signal.getsignal(s) for s in SIGNALS}
    for s in SIGNALS:
        signal.signal(s, handler)
    _handler.append(handler)
    try:
        yield
    finally:
        _handler.pop()
        for s, h in previous.items():
            signal.signal(s, h)
        STOP.clear()
        _first_signal.clear()


def reinstall_stop_handler() -> None:
    """Put the stop handler back on SIGTERM after a library took it (``ray.init`` installs
    its own, which exits at once); nothing outside :func:`stop_handlers`."""
    if _handler and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _handler[-1])  # type: ignore[arg-type]


def worker_signals() -> None:
    """(A pool worker forked inside :func:`stop_handlers`) leave Ctrl-C to the parent, which
    stops after the jobs in flight, and die of SIGTERM: a forked worker would otherwise
    inherit the stop handler, print the stop message and go on."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def handlers_active() -> bool:
    """Whether a :func:`stop_handlers` block is running (this process handles the stop)."""
    return bool(_handler)


def stop_cause() -> str:
    """What set :data:`STOP`: "Ctrl-C" or "SIGTERM"."""
    return _NAMES.get(_first_signal[0], "signal") if _first_signal else "Ctrl-C"


def stop_exit_code() -> int:
    """The exit status of a run stopped by a signal: 128 + its number, as the shell reports a killed job."""
    return 128 + (_first_signal[0] if _first_signal else signal.SIGINT)
