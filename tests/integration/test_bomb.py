"""msgpack allocation bombs, at both ends, while a real client drives (issue #17, item 1).

The issue's attack: valid fragments carrying one 4 MiB message of nested empty
arrays, each costing 3.5-4.8 s of CPU and 256 MB to decode, stalled the server and
the client. Now every such message is refused by a structural scan in
microseconds (or at its first fragment's header when over the request limit).

``VACC_FLOOD_SECONDS`` (default 6) sets the flood's length; the issue's full-size
figure is 30 s at 2 000 datagrams/s.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections import Counter

from agent_client.controllers.acc import AccController
from agent_client.drive import drive_episode
from agent_client.session import Session
from protocol import codec
from protocol.fragment import fragment

FLOOD_SECONDS = float(os.environ.get("VACC_FLOOD_SECONDS", "6"))  # [s]
FLOOD_RATE = 2000  # [datagrams/s]


def rss_bytes(pid: int) -> int:
    """Resident set size of a process [bytes], from /proc."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


def wide_bomb(size: int) -> bytes:
    """The issue's bomb: a map of 32 arrays of empty arrays, one object per byte, ``size`` bytes at most."""
    per = (size - 3) // 32 - 7
    return b"\xde\x00\x20" + b"".join(bytes([0xA1, 0x41 + k, 0xDD]) + per.to_bytes(4, "big") + b"\x90" * per for k in range(32))


def bomb_messages() -> list[bytes]:
    """Hostile messages within the datagram rules, each a different way to make a decoder allocate."""
    n = codec.MAX_ARRAY_LEN
    return [
        wide_bomb(codec.MAX_MESSAGE_BYTES),  # 4.2 M objects: 3.5-4.8 s and 256 MB each before
        wide_bomb(codec.MAX_REQUEST_BYTES),  # as large as a client message may be
        b"\x81\xa4type" + b"\x91" * (codec.MAX_REQUEST_BYTES - 8) + b"\x00",  # 2.4 M levels deep
        b"\x81\xa4type\xdd" + n.to_bytes(4, "big") + b"\xcd\x01\x01" * n,  # 131 072 int objects
        codec.encode({"type": "x", "a": [0.5] * n, "b": [0.25] * n}),  # legal shape, heaviest decode
    ]


def flood(targets: list[tuple[str, int]], seconds: float, rate: int, stop: threading.Event, sent: list[int]) -> None:
    """Send fragmented bombs to every target at ``rate`` datagrams/s, bounded in time."""
    datagrams = [d for i, msg in enumerate(bomb_messages()) for d in fragment(msg, 1000 + i)]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        t0 = time.monotonic()
        while not stop.is_set() and (now := time.monotonic()) - t0 < seconds:
            due = int((now - t0) * rate) - sent[0]
            for _ in range(max(0, min(due, 200))):
                d = datagrams[sent[0] % len(datagrams)]
                for addr in targets:
                    try:
                        sock.sendto(d, addr)
                    except OSError:
                        pass  # a full send buffer drops it; the rate is what counts
                sent[0] += 1
            time.sleep(0.002)
    finally:
        sock.close()


def test_bomb_flood_at_both_ends_leaves_runs_identical_and_memory_bounded(clean_log, spawn, tmp_path):
    clean, _ = clean_log
    stderr = tmp_path / "server.err"
    with spawn("--port", "0", stderr_path=stderr) as (proc, addr), Session(addr) as session:
        session.reset(seed=0, duration=0.5)  # warm the server before measuring it
        before = rss_bytes(proc.pid)
        client_port = session.endpoint.sock.getsockname()
        stop, sent = threading.Event(), [0]
        attacker = threading.Thread(target=flood, args=([addr, client_port], FLOOD_SECONDS, FLOOD_RATE, stop, sent))
        peak = before
        t0 = time.monotonic()
        attacker.start()
        runs = 0
        try:
            while attacker.is_alive() or runs == 0:
                log = tmp_path / f"bombed-{runs}.csv"
                drive_episode(session, AccController(), scenario="ice", seed=0, trajectory="test-1", log=log)
                assert log.read_bytes() == clean.read_bytes(), f"run {runs} changed under the bomb flood"
                peak = max(peak, rss_bytes(proc.pid))
                runs += 1
                assert time.monotonic() - t0 < FLOOD_SECONDS + 120  # bounded
        finally:
            stop.set()
            attacker.join()
        peak = max(peak, rss_bytes(proc.pid))
        assert proc.poll() is None
        rejected = dict(session.endpoint.rejected)
    growth = peak - before
    stats = stderr.read_text()
    print(f"bomb flood {FLOOD_SECONDS:g} s at {FLOOD_RATE}/s to server and client: {sent[0]} datagrams each, "
          f"{runs} identical runs, server RSS growth {growth / 1e6:.1f} MB; client rejected {rejected}")  # fmt: skip
    assert sent[0] >= 0.9 * FLOOD_RATE * FLOOD_SECONDS
    assert growth < 50e6
    assert "rejected.LimitError" in stats
    assert sum(rejected.values()) == 0  # the connected client socket never even sees them


def test_bombs_to_an_unconnected_endpoint_are_refused_cheaply():
    """Without the kernel's filter (a server's socket), each bomb costs microseconds, not seconds."""
    from protocol.codec import MAX_REQUEST_BYTES
    from protocol.transport import Endpoint

    rx_sock, tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx_sock.bind(("127.0.0.1", 0))
    rx = Endpoint(rx_sock, max_message=MAX_REQUEST_BYTES)
    rejected: Counter[str] = Counter()
    try:
        for i, msg in enumerate(bomb_messages()):
            # A fresh endpoint per bomb: strangers share one byte budget, which the bombs before
            # would have spent, and this test is of what the decoder spends on each.
            rejected += rx.rejected
            rx = Endpoint(rx_sock, max_message=MAX_REQUEST_BYTES)
            datagrams = fragment(msg, i)
            t0 = time.perf_counter()
            outcome = None
            for d in datagrams:
                tx.sendto(d, rx_sock.getsockname())
                got = rx.receive(1.0)
                assert got is not None
                outcome = got.error or outcome
            elapsed = time.perf_counter() - t0
            assert outcome is not None, f"bomb {i} was accepted"
            assert elapsed < 0.5, f"bomb {i} cost {elapsed:.2f} s"
        rejected += rx.rejected
        assert set(rejected) <= {"LimitError", "SchemaError"}  # the legal-shape one is decoded, then refused
        assert rx.reassembler.pending_bytes <= MAX_REQUEST_BYTES
    finally:
        rx_sock.close()
        tx.close()
