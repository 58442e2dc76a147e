"""Property-based and mutation fuzzing of the codec and the reassembler."""

from __future__ import annotations

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol import codec, messages
from protocol.errors import ProtocolError
from protocol.fragment import HEADER, MAGIC, Reassembler, fragment
from protocol.messages import PROTOCOL_VERSION

SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])

msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=20) | st.binary(max_size=40),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=10), children, max_size=5),
    max_leaves=20,
)

VALID = [
    codec.encode({"type": "step", "session": b"\x01" * 16, "episode": 0, "frame": 3, "action": 0.5}),
    codec.encode({"type": "hello", "version": 1, "nonce": b"12345678", "client": "c", "image_format": "gray", "image_width": 200, "image_height": 200, "max_datagram": 65000}),
    codec.encode({"type": "reset", "session": b"\x01" * 16, "episode": 1, "scenario": "ev", "seed": 2, "trajectory": "trace", "trace_t": [0.0, 1.0], "trace_v": [3.0, 4.0], "duration": None, "host_speed": 0.0, "gap": None, "set_speed": None, "preroll": None}),
]  # fmt: skip


@SETTINGS
@given(st.binary(max_size=2000))
def test_random_bytes_only_raise_protocol_errors(data):
    try:
        msg = codec.decode(data)
    except ProtocolError:
        return
    messages.validate(msg)


@pytest.mark.slow  # over ~5 s alone
@SETTINGS
@given(msgpack_values)
def test_valid_msgpack_of_any_shape_is_validated(value):
    try:
        data = msgpack.packb(value, use_bin_type=True)
    except (OverflowError, ValueError):
        return
    try:
        msg = codec.decode(data)
    except ProtocolError:
        return
    assert msg["type"] in messages.MESSAGE_TYPES


@SETTINGS
@given(st.sampled_from(VALID), st.lists(st.tuples(st.integers(0, 400), st.integers(0, 255), st.sampled_from(["flip", "insert", "delete"])), min_size=1, max_size=6))
def test_mutated_messages_decode_or_raise_protocol_errors(data, edits):
    buf = bytearray(data)
    for pos, byte, op in edits:
        pos %= max(1, len(buf))
        if op == "flip" and buf:
            buf[pos] ^= byte or 1
        elif op == "insert":
            buf.insert(pos, byte)
        elif buf:
            del buf[pos]
    try:
        msg = codec.decode(bytes(buf))
    except ProtocolError:
        return
    messages.validate(msg)


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 5), st.integers(0, 6), st.integers(0, 2**32 - 1), st.binary(max_size=300)), max_size=60))
def test_reassembler_survives_hostile_fragment_headers(frags):
    r = Reassembler(max_pending=8, max_bytes=4000, timeout=1.0)
    for i, (msg_id, index, count, total, body) in enumerate(frags):
        datagram = HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, index, count, total % (1 << 23)) + body
        try:
            r.feed(datagram, ("127.0.0.1", 1), i * 0.1)
        except ProtocolError:
            pass
        assert r.pending <= 8 and r.pending_bytes <= 4000


@SETTINGS
@given(st.binary(min_size=1, max_size=5000), st.integers(576, 2000), st.randoms(use_true_random=False))
def test_any_message_reassembles_in_any_order(payload, max_datagram, rnd):
    datagrams = fragment(payload, 9, max_datagram)
    rnd.shuffle(datagrams)
    r = Reassembler()
    out = [r.feed(d, "peer", 0.0) for d in datagrams]
    assert out[-1] == payload and all(o is None for o in out[:-1])
