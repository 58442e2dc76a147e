from __future__ import annotations

import subprocess
import sys

import pytest

from agent_client.launcher import local_server


def vacc(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess[str]:
    """Run the real `vacc` CLI in its own process."""
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout, **kw)


@pytest.fixture
def run_vacc():
    """The `vacc` CLI runner, as a fixture."""
    return vacc


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
