"""What protocol/SPEC.md promises a stranger, checked against a real server on 127.0.0.1."""

from __future__ import annotations

import contextlib
import re
import socket
import threading
import time
from pathlib import Path

import pytest

from agent_client.errors import FatalSessionError, ServerTimeout
from agent_client.session import Session
from protocol import codec
from protocol.fragment import HEADER, HEADER_BYTES, HELLO_BYTES, MAGIC, fragment, pad
from protocol.messages import PROTOCOL_VERSION, ErrorCode
from protocol.scenarios import LEAD_SCENARIOS, TRAJECTORIES
from sim_server.server import BAD_MESSAGE_RATE
from sim_server.world import World

SPEC = Path(__file__).resolve().parents[2] / "protocol" / "SPEC.md"
STEP = {"type": "step", "session": b"\x09" * 16, "episode": 0, "frame": 0, "action": 0.0}


def exchange(addr, datagram: bytes, wait: float = 0.5) -> list[bytes]:
    """Send one datagram from a fresh socket; every datagram answered within ``wait``."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.sendto(datagram, addr)
        sock.settimeout(wait)
        replies = []
        while True:
            try:
                replies.append(sock.recv(70000))
            except TimeoutError:
                return replies


@pytest.mark.parametrize(
    ("msg", "words"),
    [
        ({**STEP, "extra": 1}, "unknown fields ['extra']"),
        ({k: v for k, v in STEP.items() if k != "action"}, "missing fields ['action']"),
        ({**STEP, "frame": "0"}, "step.frame: expected int, got str"),
        ({"type": "teleport", "session": b"\x09" * 16, "pad": "x" * 100}, "unknown message type 'teleport'"),
        ({**STEP, "pad": "x" * 5000}, "exceeds 4096"),
    ],
)
def test_malformed_messages_get_bad_message_naming_the_fault(server, msg, words):
    data = codec.msgpack.packb(msg, use_bin_type=True)
    datagram = pad(fragment(data, 1)[0], HELLO_BYTES)  # room for the detail (no reply outgrows its request)
    [reply] = exchange(server, datagram)
    error = codec.decode(reply[HEADER_BYTES:])
    assert error["code"] == ErrorCode.BAD_MESSAGE and not error["fatal"] and words in error["detail"]
    assert len(reply) <= len(datagram)


def test_small_malformed_and_wrong_direction_messages_get_nothing(server):
    assert exchange(server, fragment(b"\x93\x01\x02\x03", 1)[0]) == []  # a reply would be larger than it
    obs_like = {"type": "error", "code": 1, "name": "BAD_MESSAGE", "detail": "x" * 200, "fatal": False, "episode": None, "frame": None}
    assert exchange(server, fragment(codec.encode(obs_like), 1)[0]) == []  # never an error for an error


def test_bad_message_replies_are_rate_limited_per_source(server):
    datagram = fragment(codec.encode({**STEP, "extra": "x" * 200}), 1)[0]
    sent = 400
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        started = time.monotonic()
        for _ in range(sent):
            sock.sendto(datagram, server)
        elapsed = time.monotonic() - started
        sock.settimeout(0.5)
        got = 0
        while got <= sent:
            try:
                sock.recv(70000)
            except TimeoutError:
                break
            got += 1
    assert 1 <= got <= BAD_MESSAGE_RATE * (1 + elapsed + 0.6)


def test_bad_version_reply_carries_the_servers_version_in_its_header(server):
    [reply] = exchange(server, pad(HEADER.pack(MAGIC, 9, 0, 1, 0, 1, 0), HELLO_BYTES))
    assert reply[2] == PROTOCOL_VERSION
    error = codec.decode(reply[HEADER_BYTES:])
    assert error["code"] == ErrorCode.BAD_VERSION and "2/3" in error["detail"]


def test_a_client_is_told_at_once_when_the_server_speaks_another_version():
    answer = codec.encode({"type": "error", "code": 2, "name": "BAD_VERSION", "detail": "", "fatal": True, "episode": None, "frame": None})
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as old_server:
        old_server.bind(("127.0.0.1", 0))
        old_server.settimeout(3.0)

        def answer_in_version_1() -> None:
            with contextlib.suppress(OSError):
                _, client = old_server.recvfrom(70000)
                old_server.sendto(fragment(answer, 1, version=1)[0], client)

        thread = threading.Thread(target=answer_in_version_1, daemon=True)
        thread.start()
        started = time.monotonic()
        with pytest.raises(FatalSessionError, match="another protocol version"):
            Session(old_server.getsockname(), give_up=5.0).open()
        assert time.monotonic() - started < 2.0  # not the 5 s give-up
        thread.join(3.0)


def test_resends_reuse_their_msg_id_which_starts_at_1():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        with pytest.raises(ServerTimeout):
            # 1 s: sends at 0, 20, 60, 140, 300, 620 ms; at 0.2 s a loaded host dropped one of four (flaky)
            Session(silent.getsockname(), give_up=1.0).open()
        silent.settimeout(0.1)
        ids = []
        while True:
            try:
                ids.append(HEADER.unpack_from(silent.recv(70000))[3])
            except TimeoutError:
                break
    assert len(ids) >= 3 and set(ids) == {1}


def test_the_first_reset_is_not_resent(server):
    # Before: the 20 ms (or hello-measured ~2 ms) timeout re-sent it 3-4 times.
    with Session(server, image_format="gray", image_size=(200, 200)) as s:
        before = s.resends
        s.reset(seed=0)
        assert s.resends == before == 0


def test_fragmented_requests_are_accepted(server):
    times = [0.1 * i for i in range(3000)]
    with Session(server, max_datagram=576) as s:  # the reset travels as about 100 fragments of 576 bytes
        obs = s.reset(trace=(times, [20.0] * len(times)))
        assert obs["frame"] == 0 and obs["v_lead"] == 20.0


def test_a_datagram_of_65507_bytes_is_accepted(server):
    with Session(server) as s:
        base = {"type": "reset", "session": s.token, "episode": 0, "scenario": "ice", "seed": 0, "trajectory": "trace",
                "trace_t": [0.0, 1.0], "trace_v": [10.0, 10.0], "duration": None, "host_speed": None, "gap": None, "set_speed": None, "preroll": None}  # fmt: skip
        n = (65507 - HEADER_BYTES - len(codec.encode(base)) + 18) // 18 + 1
        for k in range(n, n - 20, -1):
            base.update(trace_t=[float(i) for i in range(k)], trace_v=[10.0] * k)
            if len(codec.encode(base)) + HEADER_BYTES <= 65507:
                break
        data = codec.encode(base)
        datagram = fragment(data, 1, max_datagram=65507)
        assert len(datagram) == 1 and len(datagram[0]) >= 65507 - 20
        s.endpoint.sock.send(datagram[0])
        got = None
        deadline = time.monotonic() + 5
        while (got is None or got.msg is None) and time.monotonic() < deadline:
            got = s.endpoint.receive(1.0)
        assert got is not None and got.msg is not None and got.msg["type"] == "obs"


def spec_lengths() -> dict[str, float]:
    text = SPEC.read_text()
    table = text[text.index("| trajectory | episode length") :]
    return {name: float(length) for name, length in re.findall(r"^\| `([a-z0-9-]+)` \| ([0-9.]+) s", table, re.M)}


def test_the_spec_states_every_named_trajectorys_episode_length():
    stated = spec_lengths()
    assert set(stated) == set(TRAJECTORIES)
    for scenario in ("ice", "ev"):
        for name in TRAJECTORIES:
            world = World()
            world.reset(scenario, 0, name)
            assert world.last_frame * world.config.control_period == pytest.approx(stated[name]), (scenario, name)
    for name, spec in LEAD_SCENARIOS.items():
        assert stated[name] == spec.duration
