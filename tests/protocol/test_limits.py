"""The structural limits checked before msgpack allocates anything (issue #17, item 1)."""

from __future__ import annotations

import time

import msgpack
import pytest

from protocol import codec
from protocol.errors import DecodeError, LimitError, ProtocolError, SchemaError
from protocol.transport import DecodeBudget

SESSION = b"\x01" * 16


def trace_reset(n: int, fill: float = 1.0) -> dict:
    values = [fill + i for i in range(n)]
    return {"type": "reset", "session": SESSION, "episode": 0, "scenario": "ice", "seed": 0, "trajectory": "trace", "trace_t": values, "trace_v": values, "duration": None}  # fmt: skip


def nested_bomb(total: int) -> bytes:
    """The issue's bomb: a map whose value is an array of empty arrays, ``total`` bytes."""
    n = min(total - 12, codec.MAX_ARRAY_LEN)
    return b"\x81\xa4type\xdd" + n.to_bytes(4, "big") + b"\x90" * n


def test_scan_counts_objects_of_a_legal_message():
    data = codec.encode({"type": "close", "session": SESSION})
    assert codec.scan(data) == 5  # map, 2 keys, 2 values
    assert codec.scan(msgpack.packb(trace_reset(1000), use_bin_type=True)) == 1 + 2 * 9 + 2000


def test_limit_depth_nested_arrays():
    with pytest.raises(LimitError, match="nesting deeper than 2"):
        codec.decode(msgpack.packb({"type": "reset", "trace_t": [[1.0]]}))


def test_limit_depth_nested_map():
    with pytest.raises(LimitError, match="nesting deeper than 2"):
        codec.decode(msgpack.packb({"type": "reset", "trace_t": {"a": 1}}))


def test_limit_depth_deep_chain_is_refused_at_once():
    data = b"\x81\xa4type" + b"\x91" * 1_000_000 + b"\x00"
    t0 = time.perf_counter()
    with pytest.raises(LimitError, match="nesting"):
        codec.decode(data)
    assert time.perf_counter() - t0 < 0.05


def test_limit_total_objects():
    # Three arrays each within MAX_ARRAY_LEN, together over MAX_OBJECTS.
    n = codec.MAX_ARRAY_LEN
    msg = {"type": "x", "a": [0.5] * n, "b": [0.5] * n, "c": [0.5] * n}
    with pytest.raises(LimitError, match="more than .* objects"):
        codec.decode(msgpack.packb(msg))


def test_long_array_must_hold_floats_of_one_width():
    mixed = [0.5] * 100 + [1]
    with pytest.raises(LimitError, match="floats of one width"):
        codec.decode(msgpack.packb({"type": "reset", "trace_t": mixed}))
    ints = list(range(300, 400))
    with pytest.raises(LimitError, match="floats of one width"):
        codec.decode(msgpack.packb({"type": "reset", "trace_t": ints}))


def test_short_array_may_mix_scalars_but_not_containers():
    data = msgpack.packb({"type": "obs", "image_shape": [400, 400, 3]})
    with pytest.raises(SchemaError):  # structure fine, schema not
        codec.decode(data)
    with pytest.raises(LimitError, match="nesting"):
        codec.decode(msgpack.packb({"type": "obs", "image_shape": [400, [400], 3]}))


def test_float32_arrays_are_accepted():
    packer = msgpack.Packer(use_single_float=True, use_bin_type=True)
    msg = trace_reset(100)
    data = packer.pack(msg)
    assert codec.scan(data) == 1 + 2 * 9 + 200
    assert msgpack.unpackb(data)["trace_t"][:2] == [1.0, 2.0]


def test_largest_legal_reset_decodes_within_request_limit():
    data = codec.encode(trace_reset(codec.MAX_ARRAY_LEN))
    assert len(data) <= codec.MAX_REQUEST_BYTES
    assert codec.scan(data) <= codec.MAX_OBJECTS


@pytest.mark.parametrize("size", [65_000, codec.MAX_REQUEST_BYTES, codec.MAX_MESSAGE_BYTES])
def test_issue_bomb_is_refused_in_microseconds(size):
    data = nested_bomb(size)
    t0 = time.perf_counter()
    with pytest.raises(LimitError):
        codec.decode(data)
    assert time.perf_counter() - t0 < 0.01  # was 3.5-4.8 s and 256 MB


@pytest.mark.parametrize(
    "data",
    [
        b"\x81\xa4type\xdd\x00\x02\x00\x00\xcb",  # float array declared past the end
        b"\x81\xa4type\xc4\x10ab",  # bin declared past the end
        b"\x82\xa4type\xa1x",  # map with a missing entry
        b"\x81\x01\x02",  # integer key
        b"\x81\xa4type\xc7\x01\x01x",  # ext type
        b"\x81\xa4type\xc1",  # reserved byte
        b"\x81\xa4type\xa1x\x00",  # trailing byte
    ],
)
def test_malformed_structure_raises_decode_error(data):
    with pytest.raises(DecodeError):
        codec.scan(data)


def test_limit_string_in_scan():
    with pytest.raises(LimitError):
        codec.scan(b"\x81\xa4type\xda" + (codec.MAX_STR_LEN + 1).to_bytes(2, "big") + b"x" * (codec.MAX_STR_LEN + 1))


def test_limit_array_length_in_scan():
    with pytest.raises(LimitError, match="exceeds"):
        codec.scan(b"\x81\xa4type\xdd" + (codec.MAX_ARRAY_LEN + 1).to_bytes(4, "big"))


def test_limit_map_length_in_scan():
    with pytest.raises(LimitError, match="map of 33"):
        codec.scan(b"\xde\x00\x21")


def test_limit_decode_budget_per_source():
    budget = DecodeBudget(rate=1000.0, burst=2000.0)
    budget.charge("a", 2000, now=0.0)
    with pytest.raises(LimitError, match="decode budget"):
        budget.charge("a", 10, now=0.0)
    budget.charge("b", 2000, now=0.0)  # another source has its own bucket
    budget.charge("a", 1000, now=1.0)  # refilled at the rate


def test_decode_calls_check_before_unpacking():
    seen = []

    def refuse(objects: int) -> None:
        seen.append(objects)
        raise LimitError("no")

    with pytest.raises(LimitError):
        codec.decode(codec.encode({"type": "close", "session": SESSION}), check=refuse)
    assert seen == [5]


def test_scan_errors_are_protocol_errors_and_value_errors():
    with pytest.raises(ValueError):
        codec.scan(nested_bomb(1000))
    with pytest.raises(ProtocolError):
        codec.scan(nested_bomb(1000))
