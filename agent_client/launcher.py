"""Spawn a local simulator server process and always reap it.

The server binds port 0, so the OS picks a free port and there is no race between
choosing a port and binding it; the launcher reads the bound address from the
server's first line of output. If the process fails to start, the launch is retried.

A server whose log shares our stderr gets ``--log-level`` from ``VACC_SERVER_LOG_LEVEL``
(``vacc -v`` / ``vacc --log-level`` set it), else ``warning``: quiet on a terminal.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import shlex
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

from agent_client.errors import ServerLaunchError
from protocol.constants import SUN_ELEVATION, TRAFFIC_PER_LANE
from protocol.logs import LOG_LEVELS

__all__ = ["Road", "DEFAULT_ROAD", "local_server", "launch", "KeptServers", "start_server", "reap", "READY_PREFIX", "START_TIMEOUT", "SERVER_LOG_LEVEL_ENV", "server_log_level"]

READY_PREFIX = "vacc-server listening on "
START_TIMEOUT = 30.0  # [s] a cold start imports numpy and pymunk
SERVER_LOG_LEVEL_ENV = "VACC_SERVER_LOG_LEVEL"  # inherited by actor processes, so their servers follow it too
SERVER_LOG_LEVEL = "warning"  # the default: a spawned server's counters only when asked

log = logging.getLogger("vacc.client")


def server_log_level() -> str:
    """The ``--log-level`` of spawned servers: ``$VACC_SERVER_LOG_LEVEL``, else ``warning``.

    Raises:
        ServerLaunchError: the variable holds no level of :data:`~protocol.logs.LOG_LEVELS`.
    """
    level = os.environ.get(SERVER_LOG_LEVEL_ENV, SERVER_LOG_LEVEL).strip().lower()
    if level not in LOG_LEVELS:
        raise ServerLaunchError(f"{SERVER_LOG_LEVEL_ENV}={os.environ[SERVER_LOG_LEVEL_ENV]!r}: not a log level ({', '.join(LOG_LEVELS)})")
    return level


def start_server(args: list[str], timeout: float, stderr: int | None = None) -> tuple[subprocess.Popen[str], tuple[str, int]]:
    """Start ``python -m sim_server --port 0 ARGS``; returns the process and its bound address.

    The caller owns the process and must :func:`reap` it.

    Raises:
        ServerLaunchError: if it does not report its address within ``timeout`` [s],
            or ``VACC_SERVER_LOG_LEVEL`` is not a log level.
    """
    # --parent-pid: the server exits by itself if we die without reaping it.
    if stderr is None and "--log-level" not in args:  # a terminal's: quiet unless asked
        args = [*args, "--log-level", server_log_level()]
    cmd = [sys.executable, "-m", "sim_server", "--port", "0", "--parent-pid", str(os.getpid()), *args]
    log.debug("starting a simulator server: %s", shlex.join(cmd))
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    # A session of its own: a terminal's Ctrl-C goes to the whole foreground process group,
    # and the server must outlive it until we have finished the step in flight and reap it.
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=stderr, text=True, env=env, start_new_session=True)
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.1)
        if ready:
            line = proc.stdout.readline()
            if line.startswith(READY_PREFIX):
                host, _, port = line[len(READY_PREFIX) :].strip().rpartition(":")
                log.info("simulator server pid %d listening on %s:%s", proc.pid, host, port)
                return proc, (host, int(port))
            if not line:  # EOF: the process died
                break
        elif proc.poll() is not None:
            break
    reap(proc)
    raise ServerLaunchError(f"simulator server did not start (exit code {proc.returncode}): {' '.join(cmd)}")


def reap(proc: subprocess.Popen[str]) -> None:
    """Stop a server process (SIGTERM, then SIGKILL after 5 s) and close its pipe."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()
    log.debug("simulator server pid %d stopped (exit code %s)", proc.pid, proc.returncode)


@dataclass(frozen=True)
class Road:
    """What a spawned server shows around the lead and the host (neither changes their drive):
    its ``--traffic`` and ``--sun-elevation``."""

    traffic: int = TRAFFIC_PER_LANE  # cars in each adjacent lane, twice as many oncoming
    sun_elevation: tuple[float, float] = SUN_ELEVATION  # [rad] the range each episode's sun height is drawn from

    def server_args(self) -> tuple[str, ...]:
        """The server options that set it up."""
        return ("--traffic", str(self.traffic), "--sun-elevation", ",".join(map(str, self.sun_elevation)))

    def note(self) -> str:
        """Words for a table's title: nothing for the default road."""
        parts = [f"{self.traffic} cars in each adjacent lane (default {TRAFFIC_PER_LANE})"] if self.traffic != TRAFFIC_PER_LANE else []
        if tuple(self.sun_elevation) != SUN_ELEVATION:
            parts.append("the sun {:g}-{:g} rad high (default {:g}-{:g})".format(*self.sun_elevation, *SUN_ELEVATION))
        return "".join(", " + p for p in parts)


DEFAULT_ROAD = Road()  # the servers' defaults


def launch(
    *args: str,
    retries: int = 2,
    timeout: float = START_TIMEOUT,
    stderr: int | None = None,
    key_file: str | os.PathLike[str] | None = None,
) -> tuple[subprocess.Popen[str], tuple[str, int]]:
    """Start ``python -m sim_server ARGS`` on 127.0.0.1, retrying a failed start ``retries``
    more times; returns the process, which the caller must :func:`reap`, and its address.

    Raises:
        ServerLaunchError: if it would not start.
    """
    if stderr is None:
        server_log_level()  # a bad VACC_SERVER_LOG_LEVEL fails here, not once per try
    last: ServerLaunchError | None = None
    for attempt in range(retries + 1):
        try:
            return start_server([*args, *(["--key-file", os.fspath(key_file)] if key_file else [])], timeout, stderr)
        except ServerLaunchError as exc:
            last = exc
            if attempt < retries:
                log.warning("%s; retrying", exc)
    assert last is not None
    raise last


@contextlib.contextmanager
def local_server(
    *args: str,
    retries: int = 2,
    timeout: float = START_TIMEOUT,
    stderr: int | None = None,
    key_file: str | os.PathLike[str] | None = None,
) -> Iterator[tuple[str, int]]:
    """Run ``python -m sim_server ARGS`` on 127.0.0.1 for the ``with`` block.

    ``stderr`` is where the server's log goes (``subprocess.DEVNULL`` to hide its
    counters); by default it shares ours. ``key_file`` is passed as ``--key-file``:
    the client's :class:`~agent_client.session.Session` then needs the same key.

    Yields:
        The server's (host, port).

    Raises:
        ServerLaunchError: if it would not start after ``retries`` more tries.
    """
    proc, addr = launch(*args, retries=retries, timeout=timeout, stderr=stderr, key_file=key_file)
    try:
        yield addr
    finally:
        reap(proc)


class KeptServers:
    """Servers kept for a sequence of runs in one process: the first run with some server
    options starts one, the runs after it reuse it. Each episode is seeded at its reset, so a
    kept server drives as a fresh one would (tests/vacc/test_kept_servers.py), and a run
    saves the server's start (about 0.4 CPU-s). :meth:`close` reaps them all."""

    def __init__(self, stderr: int | None = subprocess.DEVNULL):
        self._stderr = stderr
        self._servers: dict[tuple[str, ...], tuple[subprocess.Popen[str], tuple[str, int]]] = {}

    def address(self, *args: str) -> tuple[str, int]:
        """The (host, port) of this process's server started with ``args``; started if none runs.

        Raises:
            ServerLaunchError: if it would not start.
        """
        kept = self._servers.get(args)
        if kept is not None and kept[0].poll() is None:
            return kept[1]
        self._servers[args] = launch(*args, stderr=self._stderr)
        return self._servers[args][1]

    def discard(self, *args: str) -> None:
        """Reap the server of ``args`` (after a failed run: a session of it may still be open)."""
        kept = self._servers.pop(args, None)
        if kept is not None:
            reap(kept[0])

    def close(self) -> None:
        """Reap every kept server."""
        while self._servers:
            reap(self._servers.popitem()[1][0])
