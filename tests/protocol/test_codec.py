from __future__ import annotations

import msgpack
import pytest

from protocol import codec, messages
from protocol.errors import DecodeError, LimitError, ProtocolError, SchemaError

SESSION = b"\x01" * 16

EXAMPLES = {
    "hello": {"version": 1, "nonce": b"12345678", "client": "t", "image_format": "gray", "image_width": 200, "image_height": 200, "max_datagram": 65000},
    "welcome": {"version": 1, "nonce": b"12345678", "session": SESSION, "server": "s", "physics_dt": 0.02, "control_period": 0.1, "image_format": "none", "image_width": 0, "image_height": 0, "max_datagram": 1400, "session_timeout": 10.0, "seed_salt": 0, "traffic": 3, "sun_elevation": [0.35, 1.2]},
    "reset": {"session": SESSION, "episode": 0, "scenario": "ice", "seed": 3, "trajectory": "test-1", "trace_t": None, "trace_v": None, "duration": None, "host_speed": None, "gap": 30.0, "set_speed": 33.5, "preroll": 14},
    "step": {"session": SESSION, "episode": 0, "frame": 7, "action": -0.3},
    "obs": {"episode": 0, "frame": 8, "t": 0.8, "v_host": 30.0, "v_lead": 29.5, "gap": 50.2, "accel": 0.1, "a_lead": -0.2, "force": -0.3, "collision": False, "terminated": False, "truncated": False, "reason": "", "set_speed": 33.5, "image": b"\x00" * 12, "image_shape": [2, 2, 3]},
    "close": {"session": SESSION},
    "error": {"code": 5, "name": "BAD_FRAME", "detail": "x", "fatal": False, "episode": 0, "frame": 3},
    "heartbeat": {"session": SESSION, "seq": 4},
}  # fmt: skip


def test_every_type_has_an_example():
    assert set(EXAMPLES) == messages.MESSAGE_TYPES


@pytest.mark.parametrize("kind", sorted(EXAMPLES))
def test_round_trip(kind):
    msg = {"type": kind, **EXAMPLES[kind]}
    assert codec.decode(codec.encode(msg)) == msg


def test_int_accepted_where_float_expected_but_not_bool_for_int():
    msg = {"type": "step", **EXAMPLES["step"], "action": 1}
    assert codec.decode(codec.encode(msg))["action"] == 1
    msg = {"type": "step", **EXAMPLES["step"], "frame": True}
    with pytest.raises(SchemaError, match="frame"):
        codec.decode(codec.encode(msg))


@pytest.mark.parametrize(
    "value, match",
    [
        ([1, 2, 3], "not a map"),
        ({"type": "nope"}, "unknown message type"),
        ({"type": "step", "session": SESSION, "episode": 0, "frame": 1}, "missing"),
        ({"type": "close", "session": SESSION, "evil": 1}, "unknown fields"),
        ({"type": "step", "session": SESSION, "episode": 0, "frame": "1", "action": 0.0}, "step.frame"),
        ({"type": "close", "session": "text-not-bin"}, "close.session"),
    ],
)
def test_schema_errors(value, match):
    with pytest.raises(SchemaError, match=match):
        codec.decode(msgpack.packb(value, use_bin_type=True))


def test_errors_subclass_builtin_and_package_base():
    with pytest.raises(ValueError):
        codec.decode(b"\xc1")
    with pytest.raises(ProtocolError):
        codec.decode(b"\xc1")


@pytest.mark.parametrize(
    "data",
    [b"", b"\xc1", b"\x92\x01", b"\x81\xa4type"],  # empty, reserved byte, truncated array, truncated map
)
def test_bad_bytes_raise_decode_error(data):
    with pytest.raises(DecodeError):
        codec.decode(data)


def test_trailing_bytes_rejected():
    with pytest.raises(DecodeError):
        codec.decode(codec.encode({"type": "close", "session": SESSION}) + b"\x00")


def test_non_string_map_key_rejected():
    with pytest.raises(DecodeError):
        codec.decode(msgpack.packb({1: 2}))


def test_ext_type_rejected():
    with pytest.raises((DecodeError, LimitError)):
        codec.decode(msgpack.packb({"type": msgpack.ExtType(1, b"abc")}))


def test_limit_string_length():
    with pytest.raises(LimitError):
        codec.decode(msgpack.packb({"type": "x" * (codec.MAX_STR_LEN + 1)}))


def test_limit_array_length():
    with pytest.raises(LimitError):
        codec.decode(msgpack.packb({"type": "reset", "trace_t": [0] * (codec.MAX_ARRAY_LEN + 1)}))


def test_limit_map_length():
    with pytest.raises(LimitError):
        codec.decode(msgpack.packb({f"k{i}": i for i in range(codec.MAX_MAP_LEN + 1)}))


def test_limit_message_size_on_decode_and_encode():
    with pytest.raises(LimitError):
        codec.decode(b"\x00" * (codec.MAX_MESSAGE_BYTES + 1))
    with pytest.raises(LimitError):
        codec.encode({"type": "obs", "image": b"\x00" * codec.MAX_MESSAGE_BYTES})


def test_declared_bin_length_larger_than_data_is_rejected_cheaply():
    # bin32 header claiming 3.9 MB with 3 bytes of data
    with pytest.raises(DecodeError):
        codec.decode(b"\x81\xa4type\xc6\x00\x3b\x9a\xca\x00abc")


def test_error_builder_marks_fatal_codes():
    err = messages.error(messages.ErrorCode.NO_SESSION, "gone")
    assert err["fatal"] is True and err["name"] == "NO_SESSION"
    assert messages.error(messages.ErrorCode.BAD_FRAME, "x")["fatal"] is False
    messages.validate(err)


def test_a_platoons_seat_fields_are_optional_and_typed():
    from protocol.messages import validate

    hello = {"type": "hello", "version": 5, "nonce": b"n" * 8, "client": "c", "image_format": "none", "image_width": 0,
             "image_height": 0, "max_datagram": 1400}  # fmt: skip
    assert validate(dict(hello)) and validate({**hello, "seat": 3})
    with pytest.raises(SchemaError, match="hello.seat: expected int, got str"):
        validate({**hello, "seat": "3"})
    with pytest.raises(SchemaError, match=r"unknown fields \['seats'\]"):
        validate({**hello, "seats": 3})  # a welcome's field, not a hello's
