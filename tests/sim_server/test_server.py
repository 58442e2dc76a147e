"""The server's message handler, driven in-process with real datagrams to a loopback socket.

Each request goes through the codec as it would on the wire, then to
``SimServer.handle``; the replies are read back from a real socket on 127.0.0.1.
"""

from __future__ import annotations

import itertools
import math
import socket
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol import codec
from protocol import messages as m
from protocol.constants import SUN_ELEVATION, TRAFFIC_PER_LANE
from protocol.fragment import HEADER_BYTES, HELLO_BYTES
from protocol.messages import ErrorCode
from protocol.scenarios import TRAJECTORIES
from protocol.transport import Endpoint, Received
from sim_server.server import ServerConfig, SimServer
from sim_server.world import World, WorldConfig

TOKEN_FIELDS = ("reset", "step", "heartbeat", "close")


class Harness:
    """A server object and one client socket; requests are handed to ``handle``."""

    def __init__(self, seed: int = 0, traffic: int = TRAFFIC_PER_LANE):
        self.server = SimServer(ServerConfig(port=0, seed=seed, world=WorldConfig(traffic_per_lane=traffic)))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = self.sock.getsockname()
        self.client = Endpoint(self.sock, versions=m.SUPPORTED_VERSIONS)
        self.token = b""
        self.version = m.PROTOCOL_VERSION

    def close(self) -> None:
        self.client.close()
        self.server.close()

    def ask(self, msg: dict, *, version: int = m.PROTOCOL_VERSION, addr=None, wait: float = 2.0) -> list[tuple[int, dict]]:
        """Hand one request to the server; its answer as [(header version, message)], or []."""
        while self.client.receive(0.0) is not None:
            pass  # nothing stale
        data = codec.encode(msg)
        decoded = codec.decode(data, version=version)  # what the wire would deliver
        size = max(len(data) + HEADER_BYTES, HELLO_BYTES)  # as a padded hello
        self.server.handle(Received(addr or self.addr, msg=decoded, size=size, version=version))
        deadline = time.monotonic() + wait
        while (left := deadline - time.monotonic()) > 0:
            got = self.client.receive(left)
            if got is not None and got.msg is not None:
                return [(got.version, got.msg)]
        return []

    def hello(self, fmt: str = "none", size: tuple[int, int] = (0, 0), version: int = m.PROTOCOL_VERSION, nonce: bytes = b"12345678") -> dict:
        msg = {"type": "hello", "version": version, "nonce": nonce, "client": "t", "image_format": fmt,
               "image_width": size[0], "image_height": size[1], "max_datagram": 65000}  # fmt: skip
        [(_, reply)] = self.ask(msg, version=version)
        if reply["type"] == "welcome":
            self.token, self.version = reply["session"], version
        return reply

    def reset(self, episode: int = 0, **fields) -> dict:
        msg = {"type": "reset", "session": self.token, "episode": episode, "scenario": "ice", "seed": 0, "trajectory": "test-1",
               "trace_t": None, "trace_v": None, "duration": None, "host_speed": None, "gap": None, "set_speed": None, "preroll": None}  # fmt: skip
        [(_, reply)] = self.ask(m.for_version({**msg, **fields}, self.version), version=self.version)
        return reply

    def step(self, episode: int, frame: int, action: float) -> dict:
        [(_, reply)] = self.ask({"type": "step", "session": self.token, "episode": episode, "frame": frame, "action": action})
        return reply


@pytest.fixture
def h():
    harness = Harness()
    yield harness
    harness.close()


@pytest.mark.parametrize(("seed", "salt"), [(0, 0), (7, 7), (-1, 2**32 - 1), (2**32 + 5, 5)])
def test_welcome_carries_the_salt_as_mixed(seed, salt):
    harness = Harness(seed=seed)
    try:
        assert harness.hello()["seed_salt"] == salt
    finally:
        harness.close()


@pytest.mark.parametrize("traffic", [0, TRAFFIC_PER_LANE, 10])
def test_welcome_carries_the_servers_traffic(traffic):
    harness = Harness(traffic=traffic)
    try:
        assert harness.hello()["traffic"] == traffic
    finally:
        harness.close()


def test_a_version_4_welcome_has_no_traffic(h):
    welcome = h.hello(version=4)
    assert welcome["version"] == 4 and "traffic" not in welcome and "sun_elevation" not in welcome and "seed_salt" in welcome


def test_welcome_carries_the_sun_elevation_range(h):
    assert h.hello()["sun_elevation"] == list(SUN_ELEVATION)


def test_the_salt_is_mixed_into_every_episode_seed():
    # Salts that the welcome reports alike give the same episodes; others do not.
    def first(salt: int) -> tuple[float, float]:
        state = World(salt=salt).reset("ice", 3, "random")
        return state.v_host, state.gap

    assert first(5) == first(2**32 + 5)
    assert first(5) != first(6)


def test_a_version_2_client_gets_version_2_replies_without_the_salt(h):
    welcome = h.hello(version=2)
    assert "seed_salt" not in welcome and welcome["version"] == 2
    [(header, echo)] = h.ask({"type": "heartbeat", "session": h.token, "seq": 1})
    assert header == 2 and echo["seq"] == 1
    obs = h.reset()
    assert obs["type"] == "obs" and obs["frame"] == 0


def test_a_hello_whose_version_is_not_its_headers_is_bad_version(h):
    [(header, reply)] = h.ask({"type": "hello", "version": 2, "nonce": b"12345678", "client": "t", "image_format": "none",
                               "image_width": 0, "image_height": 0, "max_datagram": 65000})  # fmt: skip
    assert reply["code"] == ErrorCode.BAD_VERSION and reply["fatal"] and header == m.PROTOCOL_VERSION


@pytest.mark.parametrize("size", [(1, 1), (7, 8), (8, 7), (1025, 8), (8, 2**63)])
def test_image_sizes_outside_8_to_1024_are_refused_at_hello(h, size):
    reply = h.hello("gray", size)
    assert reply["code"] == ErrorCode.BAD_MESSAGE and "outside 8..1024 px" in reply["detail"]
    assert h.server.session is None


@pytest.mark.parametrize(("fmt", "size", "channels"), [("gray", (8, 8), 1), ("rgb", (8, 13), 3), ("gray", (1024, 1024), 1)])
def test_image_sizes_at_the_bounds_render(h, fmt, size, channels):
    assert h.hello(fmt, size)["type"] == "welcome"
    obs = h.reset()
    assert obs["image_shape"] == [size[1], size[0], channels] and len(obs["image"]) == size[0] * size[1] * channels
    assert h.step(0, 0, 0.0)["frame"] == 1
    assert h.server.session.renderer.config.hfov == math.pi / 4  # the spec's horizontal field of view


def test_internal_ends_the_session_so_a_new_hello_is_answered_at_once(h):
    h.hello()
    h.reset()

    def broken(u: float):
        raise RuntimeError("a bug")

    h.server.world.step = broken  # type: ignore[method-assign]
    reply = h.step(0, 0, 0.0)
    assert reply["code"] == ErrorCode.INTERNAL and reply["fatal"]
    assert h.server.session is None and h.server.stats["sessions_ended_internal"] == 1
    assert h.hello(nonce=b"87654321")["type"] == "welcome"  # not BUSY


def test_internal_for_a_request_outside_the_session_leaves_it(h):
    h.hello()

    def broken(*args, **kwargs):
        raise RuntimeError("a bug")

    h.server._hello = broken  # type: ignore[method-assign]
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        other.bind(("127.0.0.1", 0))
        h.ask({"type": "hello", "version": m.PROTOCOL_VERSION, "nonce": b"x" * 8, "client": "t", "image_format": "none",
               "image_width": 0, "image_height": 0, "max_datagram": 65000}, addr=other.getsockname(), wait=0.05)  # fmt: skip
    finally:
        other.close()
    assert h.server.stats["internal_errors"] == 1 and h.server.session is not None


def test_errors_name_the_requests_episode_and_frame(h):
    h.hello()
    h.reset()
    reply = h.step(0, 0, 2.0)
    assert reply["code"] == ErrorCode.BAD_ACTION and (reply["episode"], reply["frame"]) == (0, 0)
    reply = h.step(0, 5, 0.0)
    assert reply["code"] == ErrorCode.BAD_FRAME and (reply["episode"], reply["frame"]) == (0, 5)
    reply = h.reset(episode=-3)
    assert reply["code"] == ErrorCode.BAD_RESET and (reply["episode"], reply["frame"]) == (-3, None)


def test_a_negative_first_episode_is_refused_not_ignored(h):
    h.hello()
    reply = h.reset(episode=-1)  # once answered by nothing: -1 was the "no episode yet" marker
    assert reply["code"] == ErrorCode.BAD_RESET and "count from 0" in reply["detail"]


# -- INTERNAL is unreachable from well-formed input -------------------------------

FLOATS = st.floats() | st.sampled_from([0.0, -0.0, 1.0, -1.0, 0.5, 1e-300, 1e300, 2.0**63, 14_400.0, 0.05])
INTS = st.integers(-(2**63), 2**64 - 1) | st.integers(-3, 12)
NUMBER = FLOATS | st.integers(-(2**63), 2**64 - 1)
SCALAR = st.none() | st.booleans() | NUMBER | st.text(max_size=5) | st.binary(max_size=5)
TRACE = st.one_of(
    st.none(),
    st.lists(NUMBER, max_size=8),
    st.lists(SCALAR, max_size=4),
    st.lists(st.floats(0, 300, allow_nan=False), min_size=2, max_size=8, unique=True).map(sorted),
)


def value_of(kind: str, name: str, types: tuple[str, ...]) -> st.SearchStrategy:
    """Any value of a field's wire types, with the interesting ones likely."""
    named = {
        "scenario": st.sampled_from(["ice", "ev", "diesel", ""]),
        "trajectory": st.sampled_from([*TRAJECTORIES, "trace", "nope"]),
        "image_format": st.sampled_from([*m.IMAGE_FORMATS, "bgr"]),
        "image_width": st.integers(-1, 24) | st.sampled_from([1025, 2**64 - 1]),
        "image_height": st.integers(-1, 24) | st.sampled_from([1025, -(2**63)]),
        "max_datagram": st.sampled_from([0, 575, 576, 1400, 65000, 65507, 65508]),
        "version": st.sampled_from([0, 1, 2, 3, 4, 2**64 - 1]),
        "nonce": st.binary(min_size=7, max_size=9),
        "trace_t": TRACE,
        "trace_v": TRACE,
        "action": FLOATS | st.integers(-2, 2),
    }
    if name in named:
        return named[name]
    parts = []
    for t in types:
        parts.append({"int": INTS, "float": NUMBER, "nil": st.none(), "str": st.text(max_size=10), "bin": st.binary(max_size=20),
                      "bool": st.booleans(), "array": st.lists(SCALAR, max_size=4)}[t])  # fmt: skip
    return st.one_of(parts)


@st.composite
def trace(draw) -> tuple[list, list]:
    """Increasing times with gaps from tiny to huge, and speeds around the limits."""
    start = draw(st.sampled_from([0.0, -5.0, 100.0, 1e300]))
    gaps = draw(st.lists(st.floats(1e-300, 1e300) | st.sampled_from([1e-9, 0.02, 0.1, 1.0, 1e4, 2.0**63]), min_size=1, max_size=6))
    times = list(itertools.accumulate(gaps, initial=start))
    speeds = draw(st.lists(st.floats(0, 80) | st.sampled_from([0.0, 70.0, 70.1, -0.0, 30.0]), min_size=len(times), max_size=len(times)))
    return times, speeds


OPTIONAL = st.none() | FLOATS | st.sampled_from([0.0, 1.0, 33.5, 80.0, 299.9, 300.0, 1e308])


@st.composite
def near_valid_reset(draw) -> dict:
    trajectory = draw(st.sampled_from(["trace"]) | st.sampled_from(TRAJECTORIES))
    times, speeds = draw(trace()) if trajectory == "trace" else (None, None)
    return {"type": "reset", "session": "token", "episode": draw(INTS), "scenario": draw(st.sampled_from(["ice", "ev"])), "seed": draw(INTS),
            "trajectory": trajectory, "trace_t": times, "trace_v": speeds, "duration": draw(OPTIONAL | st.just(0.05)),
            "host_speed": draw(OPTIONAL), "gap": draw(OPTIONAL), "set_speed": draw(OPTIONAL),
            "preroll": draw(st.none() | INTS | st.sampled_from([0, 1, 14, 100, 101, -1]))}  # fmt: skip


@st.composite
def request(draw) -> dict:
    kind = draw(st.sampled_from(["hello", "reset", "reset", "reset", "step", "step", "step", "heartbeat", "close"]))
    if kind == "reset" and draw(st.integers(0, 9)) < 7:
        return draw(near_valid_reset())
    fields = {name: draw(value_of(kind, name, types)) for name, types in m.SCHEMAS[kind].items() if name != "session"}
    if kind == "step" and draw(st.booleans()):
        fields["action"] = draw(st.floats(-1, 1))
    if "session" in m.SCHEMAS[kind]:
        fields["session"] = draw(st.sampled_from(["token", "token", "token", b"\x00" * 16, b""]))
    return {"type": kind, **fields}


@st.composite
def session_script(draw) -> tuple[dict, list[dict]]:
    hello = draw(request().filter(lambda r: r["type"] == "hello"))
    hello.update(version=m.PROTOCOL_VERSION, nonce=b"12345678", max_datagram=65000)
    if hello["image_format"] != "none":  # keep rendering cheap: small valid sizes
        hello.update(image_width=draw(st.integers(8, 24)), image_height=draw(st.integers(8, 24)))
    return hello, draw(st.lists(request(), min_size=4, max_size=16))


@pytest.mark.slow  # over ~5 s alone
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(session_script(), st.data())
def test_internal_is_unreachable_from_well_formed_requests(h, script, data):
    """Every well-formed request of a session's client is answered, never with INTERNAL."""
    hello, requests = script
    if h.server.session is not None:  # a fresh world for every example
        h.ask({"type": "close", "session": h.server.session.token})
    h.hello(hello["image_format"], (hello["image_width"], hello["image_height"]))
    started = time.monotonic()
    for msg in requests:
        if msg.get("session") == "token":
            msg["session"] = h.token
        if msg["type"] in ("reset", "step") and h.server.session is not None and data.draw(st.booleans()):
            # Often aim at the live episode and frame, so deep paths are reached.
            s = h.server.session
            msg["episode"] = s.episode + (1 if msg["type"] == "reset" else 0)
            if msg["type"] == "step":
                msg["frame"] = s.frame
        m.validate(msg)  # well-formed by construction
        replies = h.ask(msg)
        assert replies, f"no answer to {msg}"
        for _, reply in replies:
            assert not (reply["type"] == "error" and reply["code"] == ErrorCode.INTERNAL), (msg, reply)
        if msg["type"] == "hello" and replies[0][1]["type"] == "welcome":
            h.token = replies[0][1]["session"]
    assert h.server.stats["internal_errors"] == 0
    assert time.monotonic() - started < 20.0  # bounded: a request never stalls the server


def test_a_preroll_reset_answers_frame_minus_n_and_steps_on_to_the_cold_start(h):
    h.hello()
    cold = h.reset(episode=0)
    first = h.reset(episode=1, preroll=3)
    assert (first["frame"], first["t"]) == (-3, pytest.approx(-0.3))
    obs = first
    for frame in (-3, -2, -1):
        obs = h.step(1, frame, -1.0)  # ignored before the start: the host coasts
        assert obs["force"] == 0.0 and obs["v_host"] == cold["v_host"]
    assert obs["frame"] == 0 and {k: v for k, v in obs.items() if k != "episode"} == {k: v for k, v in cold.items() if k != "episode"}
    refused = h.reset(episode=2, preroll=101)
    assert refused["code"] == ErrorCode.BAD_RESET and "preroll 101 is outside 0..100" in refused["detail"]


def test_a_version_3_client_resets_without_a_preroll_field(h):
    assert h.hello(version=3)["version"] == 3
    obs = h.reset()
    assert obs["type"] == "obs" and obs["frame"] == 0


def test_max_seconds_never_waits_past_its_deadline(monkeypatch):
    """serve(max_seconds) waits for a datagram at most until its deadline, not a whole
    receive timeout past it."""
    waits: list[float] = []
    with SimServer(ServerConfig(port=0)) as server:
        real = server.endpoint.receive

        def receive(timeout: float | None) -> Received | None:
            waits.append(timeout if timeout is not None else math.inf)
            return real(timeout)

        monkeypatch.setattr(server.endpoint, "receive", receive)
        server.serve(max_seconds=0.05)
    assert waits and max(waits) <= 0.05
