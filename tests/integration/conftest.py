from __future__ import annotations

import contextlib
import subprocess
import sys

import pytest

from agent_client.launcher import START_TIMEOUT, local_server, reap, start_server


@contextlib.contextmanager
def spawn_server(*args: str, stderr_path=None):
    """A server process we can signal and measure: yields (proc, (host, port))."""
    with contextlib.ExitStack() as stack:
        err = stack.enter_context(open(stderr_path, "w")) if stderr_path else None
        proc, addr = start_server(list(args), START_TIMEOUT, err.fileno() if err else None)
        stack.callback(reap, proc)
        yield proc, addr


def vacc(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess[str]:
    """Run the real `vacc` CLI in its own process."""
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout, **kw)


@pytest.fixture
def run_vacc():
    """The `vacc` CLI runner, as a fixture."""
    return vacc


@pytest.fixture
def spawn():
    """The spawn_server context manager, as a fixture."""
    return spawn_server


@pytest.fixture
def server():
    """A real simulator server process on 127.0.0.1, reaped after the test."""
    with local_server() as addr:
        yield addr


@pytest.fixture(scope="session")
def clean_log(tmp_path_factory):
    """The reference ACC run of test-1 on a clean network."""
    path = tmp_path_factory.mktemp("clean") / "clean.csv"
    result = vacc("drive", "--controller", "acc", "--trajectory", "test-1", "--seed", "0", "--log", str(path))
    assert result.returncode == 0, result.stderr
    return path, result
