from __future__ import annotations

import socket

import pytest

from protocol.faults import FaultConfig, FaultySender


def test_parse():
    cfg = FaultConfig.parse("drop=0.1, dup=0.05,reorder=0.2,seed=3")
    assert cfg == FaultConfig(drop=0.1, dup=0.05, reorder=0.2, seed=3)
    assert cfg.active and not FaultConfig().active


@pytest.mark.parametrize("spec, match", [("drop", "NAME=VALUE"), ("lose=0.1", "expected one of"), ("drop=x", "not a number"), ("drop=2", "outside")])
def test_parse_errors(spec, match):
    with pytest.raises(ValueError, match=match):
        FaultConfig.parse(spec)


def test_rates_are_applied_and_seeded():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        counts = []
        for _ in range(2):
            s = FaultySender(tx, FaultConfig(drop=0.2, dup=0.1, reorder=0.1, seed=5))
            for i in range(2000):
                s.sendto(i.to_bytes(2, "big"), rx.getsockname())
            counts.append(dict(s.counts))
        assert counts[0] == counts[1]
        assert 300 < counts[0]["dropped"] < 500
        assert counts[0]["duplicated"] > 100 and counts[0]["reordered"] > 100
    finally:
        rx.close()
        tx.close()


def test_delay_holds_datagrams_then_releases_them():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.0)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s = FaultySender(tx, FaultConfig(delay=1.0, delay_s=0.05, seed=1))
        for i in range(20):
            s.sendto(bytes([i]), rx.getsockname())
        assert s.counts["delayed"] == 20 and s.counts["sent"] == 0
        assert s.next_due() is not None
        import time

        time.sleep(0.06)
        s.flush()
        assert s.counts["sent"] == 20 and s.next_due() is None
        got = set()
        while True:
            try:
                got.add(rx.recv(10)[0])
            except BlockingIOError:
                break
        assert got == set(range(20))
    finally:
        rx.close()
        tx.close()


def test_delay_s_is_checked():
    with pytest.raises(ValueError, match="delay_s"):
        FaultConfig(delay_s=-1.0)
