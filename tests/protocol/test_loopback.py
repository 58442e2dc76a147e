"""Loopback is a resolved address, not a name that starts with "127."."""

from __future__ import annotations

import subprocess
import sys

import pytest

from protocol.transport import is_loopback


@pytest.mark.parametrize("host", ["127.0.0.1", "127.3.2.1", "::1", "localhost"])
def test_loopback_addresses(host):
    assert is_loopback(host)


@pytest.mark.parametrize("host", ["127.evil.invalid", "0.0.0.0", "10.0.0.1", "::", "no-such-host.invalid", ""])
def test_anything_else_is_not_loopback(host):
    assert not is_loopback(host)


def test_serve_refuses_a_name_that_only_looks_like_loopback():
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "serve", "--host", "127.evil.invalid", "--max-seconds", "0.1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2 and "is not a loopback address" in result.stderr and "Traceback" not in result.stderr
