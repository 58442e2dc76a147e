"""Spawn a local simulator server process and always reap it.

The server binds port 0, so the OS picks a free port and there is no race between
choosing a port and binding it; the launcher reads the bound address from the
server's first line of output. If the process fails to start, the launch is retried.
"""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
import time
from collections.abc import Iterator

from agent_client.errors import ServerLaunchError

__all__ = ["local_server", "start_server", "reap", "READY_PREFIX", "START_TIMEOUT"]

READY_PREFIX = "vacc-server listening on "
START_TIMEOUT = 30.0  # [s] a cold start imports numpy and pymunk


def start_server(args: list[str], timeout: float, stderr: int | None = None) -> tuple[subprocess.Popen[str], tuple[str, int]]:
    """Start ``python -m sim_server --port 0 ARGS``; returns the process and its bound address.

    The caller owns the process and must :func:`reap` it.

    Raises:
        ServerLaunchError: if it does not report its address within ``timeout`` [s].
    """
    # --parent-pid: the server exits by itself if we die without reaping it.
    if stderr is None and "--log-level" not in args:  # a terminal's: quiet unless asked (VACC_SERVER_LOG_LEVEL)
        args = [*args, "--log-level", os.environ.get("VACC_SERVER_LOG_LEVEL", "warning")]
    cmd = [sys.executable, "-m", "sim_server", "--port", "0", "--parent-pid", str(os.getpid()), *args]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=stderr, text=True, env=env)
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.1)
        if ready:
            line = proc.stdout.readline()
            if line.startswith(READY_PREFIX):
                host, _, port = line[len(READY_PREFIX) :].strip().rpartition(":")
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
    last: ServerLaunchError | None = None
    for _ in range(retries + 1):
        try:
            proc, addr = start_server([*args, *(["--key-file", os.fspath(key_file)] if key_file else [])], timeout, stderr)
            break
        except ServerLaunchError as exc:
            last = exc
    else:
        assert last is not None
        raise last
    try:
        yield addr
    finally:
        reap(proc)
