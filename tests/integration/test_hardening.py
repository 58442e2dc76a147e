"""The server trusts nothing it receives: hostile traffic, hijacks, restarts, floods."""

from __future__ import annotations

import os
import socket
import threading
import time

import numpy as np
import pytest
from lossy_runs import LOSSY_SECONDS, assert_prefix_of

from agent_client.controllers.acc import AccController
from agent_client.drive import drive_episode
from agent_client.errors import FatalSessionError
from agent_client.session import Session
from protocol import codec
from protocol.faults import FaultConfig
from protocol.fragment import HEADER, MAGIC, fragment
from protocol.messages import PROTOCOL_VERSION, ErrorCode


def rss_bytes(pid: int) -> int:
    """Resident set size of a process [bytes], from /proc."""
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


def hostile_datagrams(rng: np.random.Generator, n: int, token: bytes) -> list[bytes]:
    """A mix of every kind of bad input, each kind in turn."""
    good_step = {"type": "step", "session": token, "episode": 0, "frame": 0, "action": 0.0}
    out = []
    for i in range(n):
        kind = i % 12
        msg_id = int(rng.integers(2**32))
        if kind == 0:
            out.append(rng.bytes(int(rng.integers(1, 300))))  # random bytes
        elif kind == 1:
            out.append(fragment(codec.encode(good_step), msg_id)[0][: int(rng.integers(1, 40))])  # truncated
        elif kind == 2:
            out.append(HEADER.pack(MAGIC, int(rng.integers(2, 255)), 0, msg_id, 0, 1, 3) + b"abc")  # bad version
        elif kind == 3:
            out.append(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, 0, 64, 4_000_000) + rng.bytes(1400))  # never completes
        elif kind == 4:
            out.append(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, 0, 1, 2**32 - 1) + b"x")  # huge declared length
        elif kind == 5:
            out.append(fragment(b"\x93\x01\x02\x03", msg_id)[0])  # valid msgpack, wrong shape
        elif kind == 6:
            out.append(fragment(codec.encode({**good_step, "frame": "0"}), msg_id)[0])  # wrong types
        elif kind in (7, 8):
            bad = [float("nan"), float("inf"), -float("inf"), 7.5, -1e300][int(rng.integers(5))]
            out.append(fragment(codec.encode({**good_step, "action": bad}), msg_id)[0])  # bad actions, stolen token
        elif kind == 9:
            hello = {"type": "hello", "version": int(rng.integers(2, 99)), "nonce": rng.bytes(8), "client": "x", "image_format": "rgb", "image_width": 400, "image_height": 400, "max_datagram": 1400}  # fmt: skip
            out.append(fragment(codec.encode(hello), msg_id)[0])  # bad protocol version in a hello
        elif kind == 10:
            # Overlapping and repeated fragments of one message with changing lengths.
            out.append(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 7, int(rng.integers(3)), 3, 3000) + rng.bytes(int(rng.integers(1, 1500))))
        else:
            out.append(fragment(codec.encode({**good_step, "session": rng.bytes(16)}), msg_id)[0])  # foreign token
    return out


def test_50k_hostile_datagrams_do_not_change_runs(clean_log, spawn, tmp_path):
    clean, _ = clean_log
    stderr = tmp_path / "server.err"
    target = 50_000
    with spawn("--port", "0", stderr_path=stderr) as (proc, addr):
        with Session(addr) as session:
            state = {"sent": 0, "replies": []}
            stop = threading.Event()

            def attack() -> None:
                rng = np.random.default_rng(0)
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                sock.settimeout(0.0)
                deadline = time.monotonic() + 120  # bounded in count and time
                try:
                    while state["sent"] < target and time.monotonic() < deadline and not stop.is_set():
                        for d in hostile_datagrams(rng, 120, session.token):
                            sock.sendto(d, addr)
                        state["sent"] += 120
                        try:
                            while True:
                                state["replies"].append(codec.decode(sock.recv(70000)[16:]))
                        except (BlockingIOError, ValueError):
                            pass
                        time.sleep(0.002)  # leave the client some of the CPU
                finally:
                    sock.close()

            thread = threading.Thread(target=attack)
            thread.start()
            runs = 0
            try:
                while thread.is_alive() or runs == 0:
                    log = tmp_path / f"attacked-{runs}.csv"
                    drive_episode(session, AccController(), scenario="ice", seed=0, trajectory="test-1", log=log)
                    assert log.read_bytes() == clean.read_bytes(), f"run {runs} changed under attack"
                    runs += 1
            finally:
                stop.set()
                thread.join()
        assert proc.poll() is None  # still serving
        with Session(addr) as again:
            assert again.reset(seed=0)["frame"] == 0
    assert state["sent"] >= target
    codes = {r["code"] for r in state["replies"] if r["type"] == "error"}
    assert ErrorCode.BAD_VERSION in codes and ErrorCode.NO_SESSION in codes
    stats = stderr.read_text()
    for reason in ("rejected.DecodeError", "rejected.SchemaError", "rejected.FragmentError", "rejected.LimitError", "rejected.wrong_address", "rejected.no_session"):
        assert reason in stats, reason


def test_session_cannot_be_hijacked(server):
    with Session(server) as owner:
        owner.reset(seed=0, duration=2.0)
        owner.step(0.5)
        thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        thief.bind(("127.0.0.1", 0))
        thief.settimeout(0.3)
        try:
            # The owner's valid token from another address: dropped silently.
            steal = {"type": "step", "session": owner.token, "episode": 0, "frame": 1, "action": -1.0}
            thief.sendto(fragment(codec.encode(steal), 1)[0], server)
            with pytest.raises(socket.timeout):
                thief.recv(70000)
            # A forged token: refused.
            forged = {**steal, "session": os.urandom(16)}
            thief.sendto(fragment(codec.encode(forged), 2)[0], server)
            reply = codec.decode(thief.recv(70000)[16:])
            assert reply["code"] == ErrorCode.NO_SESSION
        finally:
            thief.close()
        # The session is untouched: frame 1 is still the owner's to step, with its action.
        obs = owner.step(0.0)
        assert obs["frame"] == 2 and obs["force"] == 0.0
    with Session(server, give_up=0.5) as after:  # a closed session frees the world at once
        assert after.reset(seed=0)["frame"] == 0


def test_restarted_server_reports_lost_session(spawn):
    with spawn("--port", "0") as (proc, addr):
        port = addr[1]
        s = Session(addr, give_up=2.0)
        s.open()
        s.reset(seed=0)
        s.step(0.0)
    with spawn("--port", str(port)):
        with pytest.raises(FatalSessionError, match="NO_SESSION") as info:
            s.step(0.0)
        assert f"127.0.0.1:{port}" in str(info.value)
        s.close()


def test_100k_fragment_starts_keep_memory_bounded(spawn):
    with spawn("--port", "0") as (proc, addr), Session(addr) as session:
        session.reset(seed=0)
        before = rss_bytes(proc.pid)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        body = b"x" * 1400
        deadline = time.monotonic() + 120
        try:
            for msg_id in range(100_000):
                sock.sendto(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, 0, 100, 140_000) + body, addr)
                if msg_id % 2000 == 0:
                    session.heartbeat()  # the real client is served throughout
                if time.monotonic() > deadline:
                    break
        finally:
            sock.close()
        session.heartbeat()
        after = rss_bytes(proc.pid)
        assert session.step(0.0)["frame"] == 1
    growth = after - before
    print(f"server RSS growth after 100k fragment starts: {growth / 1e6:.1f} MB")
    assert msg_id == 99_999
    assert growth < 50e6


def test_20_percent_loss_with_dup_and_reorder_is_byte_identical(clean_log, run_vacc, tmp_path):
    clean, clean_result = clean_log
    lossy = tmp_path / "lossy20.csv"
    faults = "drop=0.2,dup=0.1,reorder=0.1,delay=0.05,delay_s=0.01"
    t0 = time.monotonic()
    result = run_vacc("drive", "--controller", "acc", "--seed", "0", "--log", str(lossy), "--duration", str(LOSSY_SECONDS),
                      "--faults", faults + ",seed=21", "--server-faults", faults + ",seed=22", timeout=300)  # fmt: skip
    wall = time.monotonic() - t0
    assert result.returncode == 0, result.stderr
    assert len(lossy.read_text().splitlines()) == 1 + round(LOSSY_SECONDS / 0.1) + 1
    assert_prefix_of(lossy, clean)
    print(f"{LOSSY_SECONDS:.0f} s of the ACC's test-1 at 20% loss: {wall:.1f} s wall")


def test_fault_config_rejected_with_clear_error(run_vacc, tmp_path):
    result = run_vacc("drive", "--controller", "acc", "--log", str(tmp_path / "x.csv"), "--faults", "drop=3")
    assert result.returncode != 0 and "outside [0, 1]" in result.stderr


def test_fault_injection_counts(server):
    with Session(server, faults=FaultConfig(drop=0.3, seed=1)) as s:
        s.reset(seed=0, duration=1.0)
        while not s.step(0.0)["truncated"]:
            pass
        assert s.resends > 0
