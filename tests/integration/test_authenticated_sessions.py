"""Keyed sessions, and no amplification without a key (issues #17 item 3, #55 item 1).

A proxy between client and server plays the attacker on the path: it sees every
datagram both ways, forges observations, spoofs a close with the session's own
address and token, replays what it recorded (in the session, into a later session,
and a hello from a new port) and reflects the client's own datagrams back to it.
With ``--key-file`` each is rejected before it is even reassembled, counted by
reason, and the run log is byte-identical to a clean run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import select
import socket
import threading
import time
from pathlib import Path

import pytest
from lossy_runs import LOSSY_SECONDS, assert_prefix_of

from agent_client.controllers.acc import AccController
from agent_client.drive import drive_episode
from agent_client.session import Session
from protocol import codec
from protocol.auth import SID_BYTES, TRAILER_BYTES, Channel, load_key, session_keys
from protocol.fragment import FLAG_MAC, HEADER, HEADER_BYTES, HELLO_BYTES, MAGIC, fragment, pad
from protocol.messages import KEYED_VERSION, PROTOCOL_VERSION, ErrorCode
from protocol.transport import Endpoint

WRONG_KEY = b"w" * 32
TRIES = int(os.environ.get("VACC_ATTACK_TRIES", "2"))  # each attack, each try a whole run; 10 for the figures


@pytest.fixture
def key_file(tmp_path) -> Path:
    path = tmp_path / "vacc.key"
    path.write_bytes(b"0123456789abcdef0123456789abcdef")
    return path


def stat(stats: str, name: str) -> int:
    found = re.search(rf"\b{re.escape(name)}=(\d+)", stats)
    return int(found.group(1)) if found else 0


class Proxy:
    """Forwards datagrams between one client and a server, recording both ways."""

    def __init__(self, server: tuple[str, int]):
        self.server = server
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.address = self.front.getsockname()
        self.client: tuple[str, int] | None = None
        self.up: list[bytes] = []  # client -> server
        self.down: list[bytes] = []  # server -> client
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        deadline = time.monotonic() + 300  # bounded
        while not self._stop.is_set() and time.monotonic() < deadline:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.05)
            for sock in ready:
                data, addr = sock.recvfrom(70000)
                if sock is self.front:
                    self.client = addr
                    self.up.append(data)
                    self.back.sendto(data, self.server)
                elif self.client is not None:
                    self.down.append(data)
                    self.front.sendto(data, self.client)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.front.close()
        self.back.close()


def plain(msg: dict) -> bytes:
    return fragment(codec.encode(msg), 7)[0]


def sealed_with(key: bytes, msg: dict, sid: bytes = bytes(SID_BYTES), *, client: bool = False) -> bytes:
    """``msg`` sealed as a session datagram with ``key``, naming session ``sid`` (seen on the wire)."""
    keys = dataclasses.replace(session_keys(key, bytes(16), bytes(16)), token=sid + bytes(16 - SID_BYTES))
    plain_datagram = fragment(codec.encode(msg), 7, flags=FLAG_MAC, trailer=TRAILER_BYTES, version=KEYED_VERSION)[0]
    return Channel(keys, client=client).seal(plain_datagram)


def sid_of(datagram: bytes) -> bytes:
    return datagram[HEADER_BYTES : HEADER_BYTES + SID_BYTES]


def obs_for(frame: int) -> dict:
    return {"type": "obs", "episode": 0, "frame": frame, "t": 0.0, "v_host": 99.0, "v_lead": 0.0, "gap": 1.0, "accel": 0.0, "a_lead": 0.0, "force": 0.0, "collision": True, "terminated": True, "truncated": False, "reason": "collision", "set_speed": 33.5, "image": None, "image_shape": None}  # fmt: skip


def test_forged_spoofed_and_replayed_datagrams_are_rejected_and_counted(clean_log, spawn, key_file, tmp_path):
    clean, _ = clean_log
    key = load_key(key_file)
    stderr = tmp_path / "server.err"
    attack: dict[str, int] = {}
    with spawn("--port", "0", "--key-file", str(key_file), stderr_path=stderr) as (proc, addr):
        proxy = Proxy(addr)
        try:
            with Session(proxy.address, key=key) as session:
                session.reset(seed=0, duration=0.2)  # fills the proxy's records

                def attacker() -> None:
                    deadline = time.monotonic() + 30
                    while len(proxy.up) < 200 and time.monotonic() < deadline:
                        time.sleep(0.005)
                    token = session.token
                    assert token is not None and proxy.client is not None
                    attack["frame"] = session.frame
                    sid = sid_of(proxy.down[-1])  # the session id is on the wire
                    # Forged observations of the next frames, unsealed and sealed with a wrong key.
                    forged = [plain(obs_for(f)) for f in range(session.frame, session.frame + 20)]
                    forged += [sealed_with(WRONG_KEY, obs_for(f), sid) for f in range(session.frame, session.frame + 20)]
                    for d in forged:
                        proxy.front.sendto(d, proxy.client)
                    # A close with the session's own token, from the session's own address.
                    spoofed = [plain({"type": "close", "session": token}), sealed_with(WRONG_KEY, {"type": "close", "session": token}, sid, client=True)]
                    for d in spoofed:
                        proxy.back.sendto(d, addr)
                    # Replays of authentic datagrams, both ways.
                    up, down = proxy.up[10:60], proxy.down[10:60]
                    for d in up:
                        proxy.back.sendto(d, addr)
                    for d in down:
                        proxy.front.sendto(d, proxy.client)
                    attack.update(forged=len(forged), spoofed=len(spoofed), replayed_up=len(up), replayed_down=len(down))

                thread = threading.Thread(target=attacker)
                thread.start()
                log = tmp_path / "attacked.csv"
                try:
                    drive_episode(session, AccController(), scenario="ice", seed=0, trajectory="test-1", log=log)
                finally:
                    thread.join()
                rejected = dict(session.endpoint.rejected)
        finally:
            proxy.close()
    stats = stderr.read_text()
    assert attack["frame"] < 2000, "the attack came after the run"
    assert log.read_bytes() == clean.read_bytes()
    assert rejected.get("AuthError") == attack["forged"]
    assert rejected.get("ReplayError") == attack["replayed_down"]
    assert stat(stats, "rejected.AuthError") == attack["spoofed"]
    assert stat(stats, "rejected.ReplayError") == attack["replayed_up"]
    assert stat(stats, "sessions_closed") == 1  # only the real close


def test_takeover_from_a_dead_clients_port_is_refused(spawn, key_file, tmp_path):
    key = load_key(key_file)
    stderr = tmp_path / "server.err"
    with spawn("--port", "0", "--key-file", str(key_file), "--session-timeout", "2", stderr_path=stderr) as (proc, addr):
        owner = Session(addr, key=key)
        owner.open()
        owner.reset(seed=0, duration=1.0)
        owner.step(0.3)
        token, port = owner.token, owner.endpoint.sock.getsockname()
        owner._stop.set()  # the client dies: no close, its port is free
        owner.endpoint.close()
        thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        thief.bind(port)
        thief.settimeout(0.3)
        try:
            # A late reply to a step the owner re-sent under load may still be on its way to
            # this port: it answers the owner, not the thief. Let it land first (within 1 s,
            # well inside the 2 s session timeout that must not pass before the probe below).
            deadline = time.monotonic() + 1.0
            with contextlib.suppress(TimeoutError):
                while time.monotonic() < deadline:
                    thief.recv(70000)
            step = {"type": "step", "session": token, "episode": 0, "frame": 1, "action": -1.0}
            for d in (plain(step), sealed_with(WRONG_KEY, step, token[:SID_BYTES], client=True), plain({"type": "close", "session": token})):
                thief.sendto(d, addr)
            with pytest.raises(TimeoutError):
                thief.recv(70000)  # never answered
            # Who holds the world is not revealed to a keyed newcomer either.
            probe_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            probe_sock.bind(("127.0.0.1", 0))
            probe = Endpoint(probe_sock, key=key)
            try:
                hello = {"type": "hello", "version": KEYED_VERSION, "nonce": b"12345678", "client": "probe", "image_format": "none", "image_width": 0, "image_height": 0, "max_datagram": 65000}  # fmt: skip
                probe.send(hello, addr)
                got = probe.receive(2.0)
                assert got is not None and got.msg is not None and got.msg["code"] == ErrorCode.BUSY
                assert "127.0.0.1" not in got.msg["detail"] and str(port[1]) not in got.msg["detail"]
            finally:
                probe.close()
        finally:
            thief.close()
        with Session(addr, key=key) as after:  # the dead session times out; the world is free again
            assert after.reset(seed=0)["frame"] == 0
    stats = stderr.read_text()
    assert stat(stats, "rejected.AuthError") == 3
    assert stat(stats, "rx.step") == 1  # only the owner's


def test_keyed_run_under_20_percent_loss_is_byte_identical(clean_log, run_vacc, key_file, tmp_path):
    clean, _ = clean_log
    log = tmp_path / "keyed-lossy.csv"
    faults = "drop=0.2,dup=0.1,reorder=0.1,delay=0.05,delay_s=0.01"
    env = dict(os.environ, VACC_SERVER_LOG_LEVEL="info")  # the spawned server's stats line
    result = run_vacc("drive", "--controller", "acc", "--seed", "0", "--log", str(log), "--duration", str(LOSSY_SECONDS), "--key-file", str(key_file),
                      "--faults", faults + ",seed=31", "--server-faults", faults + ",seed=32", timeout=300, env=env)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert len(log.read_text().splitlines()) == 1 + round(LOSSY_SECONDS / 0.1) + 1
    assert_prefix_of(log, clean)
    assert "rejected.ReplayError" in result.stderr  # duplicates are replays: dropped, harmless


def test_mismatched_keys_fail_with_a_hint(spawn, key_file):
    with spawn("--port", "0", "--key-file", str(key_file)) as (proc, addr):
        with pytest.raises(Exception, match="same --key-file"):
            Session(addr, key=WRONG_KEY, give_up=0.5).open()
        with pytest.raises(Exception, match="no reply"):
            Session(addr, give_up=0.5).open()  # no key at all: never answered


def test_allow_remote_requires_a_key(run_vacc):
    result = run_vacc("serve", "--host", "0.0.0.0", "--allow-remote", "--max-seconds", "0.1")
    assert result.returncode != 0 and "--allow-remote needs --key-file" in result.stderr


def test_key_file_errors_are_one_line(run_vacc, tmp_path):
    short = tmp_path / "short.key"
    short.write_text("abc")
    result = run_vacc("serve", "--key-file", str(short), "--max-seconds", "0.1")
    assert result.returncode != 0 and "at least 16" in result.stderr and "Traceback" not in result.stderr
    result = run_vacc("drive", "--controller", "acc", "--log", str(tmp_path / "x.csv"), "--key-file", str(tmp_path / "missing.key"))
    assert result.returncode != 0 and "missing.key" in result.stderr and "Traceback" not in result.stderr


def probe(addr: tuple[str, int], datagram: bytes, wait: float = 0.3) -> list[bytes]:
    """Send one datagram from a fresh socket; every datagram answered within ``wait``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    replies = []
    try:
        sock.sendto(datagram, addr)
        sock.settimeout(wait)
        while True:
            try:
                replies.append(sock.recv(70000))
            except TimeoutError:
                return replies
    finally:
        sock.close()


def test_no_reply_to_an_unauthenticated_datagram_is_larger_than_it(server):
    """Without a key: the issue's 16-byte bad-version datagram got 121 bytes back (7.6x)."""
    hello = {"type": "hello", "version": PROTOCOL_VERSION, "nonce": b"abcdefgh", "client": "amp", "image_format": "none", "image_width": 0, "image_height": 0, "max_datagram": 65000}  # fmt: skip
    cases = {
        "bad version header": HEADER.pack(MAGIC, PROTOCOL_VERSION + 1, 0, 1, 0, 1, 0),
        "bad version, padded": pad(HEADER.pack(MAGIC, PROTOCOL_VERSION + 1, 0, 1, 0, 1, 0), HELLO_BYTES),
        "unpadded hello": plain(hello),
        "foreign heartbeat": plain({"type": "heartbeat", "session": b"\x09" * 16, "seq": 1}),
        "foreign step": plain({"type": "step", "session": b"\x09" * 16, "episode": 0, "frame": 0, "action": 0.0}),
        "foreign close": plain({"type": "close", "session": b"\x09" * 16}),
        "sealed, no key here": sealed_with(WRONG_KEY, {"type": "close", "session": b"\x09" * 16}, client=True),
    }
    answered = {}
    for name, datagram in cases.items():
        replies = probe(server, datagram)
        assert sum(map(len, replies)) <= len(datagram), f"{name}: {len(datagram)} bytes answered with {sum(map(len, replies))}"
        answered[name] = [codec.decode(r[HEADER_BYTES:]) for r in replies]
    assert answered["bad version header"] == []  # 16 bytes: nothing fits
    assert answered["bad version, padded"][0]["code"] == ErrorCode.BAD_VERSION
    assert answered["unpadded hello"][0]["code"] == ErrorCode.BAD_MESSAGE and "pad" in answered["unpadded hello"][0]["detail"]
    assert answered["foreign heartbeat"] == [] and answered["sealed, no key here"] == []
    # A padded hello is answered with a welcome, which fits in it.
    replies = probe(server, pad(plain(hello), HELLO_BYTES))
    assert codec.decode(replies[0][HEADER_BYTES:])["type"] == "welcome" and len(replies[0]) <= HELLO_BYTES


def attacked_run(addr: tuple[str, int], key: bytes, log: Path, attack) -> tuple[Proxy, dict[str, int]]:
    """One keyed ACC run of test-1 through a proxy; ``attack(proxy, session)`` runs in a
    thread once the run is under way. Returns the proxy (its records) and the client's
    rejection counts."""
    proxy = Proxy(addr)
    try:
        with Session(proxy.address, key=key) as session:
            session.reset(seed=0, duration=0.2)

            def attacker() -> None:
                deadline = time.monotonic() + 30  # bounded
                while len(proxy.up) < 200 and time.monotonic() < deadline:
                    time.sleep(0.005)
                attack(proxy, session)

            thread = threading.Thread(target=attacker)
            thread.start()
            try:
                drive_episode(session, AccController(), scenario="ice", seed=0, trajectory="test-1", log=log)
            finally:
                thread.join()
            rejected = dict(session.endpoint.rejected)
    finally:
        proxy.close()
    return proxy, rejected


def from_new_ports(datagram: bytes, addr: tuple[str, int], n: int, wait: float = 0.0) -> int:
    """Send ``datagram`` once from each of ``n`` fresh sockets; the datagrams answered within ``wait``."""
    answered = 0
    for _ in range(n):
        answered += len(probe(addr, datagram, wait)) if wait else 0
        if not wait:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                sock.sendto(datagram, addr)
    return answered


@pytest.mark.parametrize("kind", ["cross-session replay", "reflection", "hello replay"])
def test_keyed_session_attacks_leave_the_run_identical(clean_log, spawn, key_file, tmp_path, kind):
    """The issue's three attacks without the key, each TRIES times against a live keyed session."""
    clean, _ = clean_log
    key = load_key(key_file)
    stderr = tmp_path / "server.err"
    sent = 0
    rejected_total: dict[str, int] = {}
    with spawn("--port", "0", "--key-file", str(key_file), stderr_path=stderr) as (proc, addr):
        earlier, _ = attacked_run(addr, key, tmp_path / "earlier.csv", lambda proxy, session: None)
        old_obs = [d for d in earlier.down[-200:] if d[3] & FLAG_MAC][:100]
        for attempt in range(TRIES):
            def attack(proxy: Proxy, session: Session) -> None:
                nonlocal sent
                if kind == "cross-session replay":
                    for d in old_obs:  # an earlier session's observations, as if from the server
                        proxy.front.sendto(d, proxy.client)
                    sent += len(old_obs)
                elif kind == "reflection":
                    own = proxy.up[-50:]  # the client's own steps, sent back to it
                    for d in own:
                        proxy.front.sendto(d, proxy.client)
                    sent += len(own)
                else:
                    hellos = [proxy.up[0], earlier.up[0]]  # this session's hello and an earlier one
                    for d in hellos:
                        sent += 5
                        assert from_new_ports(d, addr, 5, wait=0.05) == 0  # not even answered

            log = tmp_path / f"attacked-{attempt}.csv"
            proxy, rejected = attacked_run(addr, key, log, attack)
            assert log.read_bytes() == clean.read_bytes(), f"{kind}: try {attempt} changed the run"
            for k, v in rejected.items():
                rejected_total[k] = rejected_total.get(k, 0) + v
        if kind == "hello replay":
            # After the session closed: a replayed hello still opens nothing, and a real
            # client is served at once.
            from_new_ports(proxy.up[0], addr, 20)
            started = time.monotonic()
            with Session(addr, key=key) as after:
                assert after.reset(seed=0)["frame"] == 0
            assert time.monotonic() - started < 1.0
    stats = stderr.read_text()
    print(f"{kind}: {TRIES} tries, {sent} datagrams sent, client rejected {rejected_total}, server: {stats.strip().splitlines()[-1]}")
    if kind == "cross-session replay":
        assert rejected_total.get("ForeignSessionError") == sent
    elif kind == "reflection":
        assert rejected_total.get("AuthError") == sent
    else:
        assert stat(stats, "rejected.hello_replay") == sent + 20
    sessions = 1 + TRIES + (kind == "hello replay")  # the earlier one, the attacked ones, the one after
    assert stat(stats, "sessions_opened") == stat(stats, "handshakes") == sessions
    assert stat(stats, "sessions_closed") == sessions  # every session ended by its own close


def test_a_replayed_hello_after_a_restart_holds_no_world(spawn, key_file, tmp_path):
    """A server that forgot the hello's nonce answers the replay, but the handshake
    it opens holds nothing: a real client is served at once."""
    key = load_key(key_file)
    with spawn("--port", "0", "--key-file", str(key_file)) as (proc, addr):
        proxy = Proxy(addr)
        try:
            with Session(proxy.address, key=key) as s:
                s.reset(seed=0, duration=0.2)
            hello = proxy.up[0]
        finally:
            proxy.close()
    stderr = tmp_path / "server.err"
    with spawn("--port", "0", "--key-file", str(key_file), "--session-timeout", "10", stderr_path=stderr) as (proc, addr):
        # The first replay gets a welcome nobody can use; the same hello from other ports is known.
        assert from_new_ports(hello, addr, 3, wait=0.1) == 1
        started = time.monotonic()
        with Session(addr, key=key) as real:
            assert real.reset(seed=0)["frame"] == 0
        assert time.monotonic() - started < 1.0  # not the 10 s session timeout
    stats = stderr.read_text()
    assert stat(stats, "handshakes") == 2 and stat(stats, "sessions_opened") == 1
    assert stat(stats, "rejected.hello_replay") == 2
