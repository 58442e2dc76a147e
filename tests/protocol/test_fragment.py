from __future__ import annotations

import numpy as np
import pytest

from protocol import codec, fragment
from protocol.errors import DecodeError, FragmentError, LimitError, VersionError
from protocol.fragment import HEADER, HEADER_BYTES, MAGIC, Reassembler
from protocol.messages import PROTOCOL_VERSION

PEER = ("127.0.0.1", 1)


def image_message() -> bytes:
    pixels = np.random.default_rng(0).integers(0, 256, size=(400, 400, 3), dtype=np.uint8)
    msg = {"type": "obs", "episode": 0, "frame": 1, "t": 0.1, "v_host": 1.0, "v_lead": 1.0, "gap": 1.0, "accel": 0.0, "a_lead": 0.0, "force": 0.0, "collision": False, "terminated": False, "truncated": False, "reason": "", "set_speed": 33.5, "image": pixels.tobytes(), "image_shape": [400, 400, 3]}  # fmt: skip
    return codec.encode(msg)


@pytest.mark.parametrize("max_datagram", [1400, 65000])
def test_full_rgb_image_survives_shuffled_and_duplicated_fragments(max_datagram):
    payload = image_message()
    assert len(payload) > 480_000
    datagrams = fragment.fragment(payload, msg_id=7, max_datagram=max_datagram)
    assert all(len(d) <= max_datagram for d in datagrams)
    order = np.random.default_rng(1).permutation(len(datagrams))
    r = Reassembler()
    results = []
    for i in order[:-1]:
        results.append(r.feed(datagrams[i], PEER, 0.0))
        results.append(r.feed(datagrams[i], PEER, 0.0))  # a duplicate is ignored
    assert results == [None] * len(results)
    out = r.feed(datagrams[order[-1]], PEER, 0.0)
    assert out == payload
    assert r.pending == 0 and r.pending_bytes == 0
    assert codec.decode(out)["image_shape"] == [400, 400, 3]


def test_single_fragment_fast_path():
    payload = codec.encode({"type": "close", "session": b"x" * 16})
    [d] = fragment.fragment(payload, 1)
    assert Reassembler().feed(d, PEER, 0.0) == payload


def test_peers_do_not_mix():
    payload = b"a" * 3000
    d = fragment.fragment(payload, 5, max_datagram=1400)
    r = Reassembler()
    assert r.feed(d[0], ("127.0.0.1", 1), 0.0) is None
    assert r.feed(d[1], ("127.0.0.1", 2), 0.0) is None
    assert r.feed(d[2], ("127.0.0.1", 1), 0.0) is None
    assert r.pending == 2


def test_header_checks():
    good = fragment.fragment(b"abc", 1)[0]
    with pytest.raises(DecodeError):
        fragment.parse_header(good[:10])
    with pytest.raises(DecodeError):
        fragment.parse_header(b"XX" + good[2:])
    with pytest.raises(VersionError):
        fragment.parse_header(good[:2] + b"\x09" + good[3:])
    with pytest.raises(FragmentError):  # index >= count
        fragment.parse_header(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 1, 3, 3, 3) + b"abc")
    with pytest.raises(FragmentError):  # single fragment, truncated body
        fragment.parse_header(good[:-1])
    with pytest.raises(LimitError):  # huge declared length
        fragment.parse_header(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 1, 0, 2, 2**31) + b"abc")


def test_repeated_fragment_with_other_length_drops_assembly():
    r = Reassembler()
    r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 0, 3, 2500) + b"x" * 1000, PEER, 0.0)
    with pytest.raises(FragmentError):
        r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 0, 3, 2500) + b"x" * 900, PEER, 0.0)
    assert r.pending == 0


def test_changed_count_drops_assembly():
    r = Reassembler()
    r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 0, 3, 2500) + b"x" * 1000, PEER, 0.0)
    with pytest.raises(FragmentError):
        r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 1, 4, 2500) + b"x" * 700, PEER, 0.0)


def test_inconsistent_lengths_detected_at_join():
    r = Reassembler()
    r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 0, 3, 2500) + b"x" * 1000, PEER, 0.0)
    r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 1, 3, 2500) + b"x" * 900, PEER, 0.0)
    with pytest.raises(FragmentError):
        r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, 9, 2, 3, 2500) + b"x" * 600, PEER, 0.0)


def test_unfinished_messages_expire():
    r = Reassembler(timeout=1.0)
    d = fragment.fragment(b"a" * 3000, 5, max_datagram=1400)
    r.feed(d[0], PEER, 0.0)
    assert r.pending == 1
    r.feed(fragment.fragment(b"b" * 3000, 6, max_datagram=1400)[0], PEER, 5.0)
    assert r.pending == 1 and r.evicted == 1


def test_pending_count_and_bytes_are_capped():
    r = Reassembler(max_pending=4, max_bytes=10_000)
    for msg_id in range(100):
        r.feed(HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, 0, 10, 14000) + b"x" * 1400, PEER, 0.0)
        assert r.pending <= 4 and r.pending_bytes <= 10_000
    assert r.evicted >= 96


def test_fragment_limits():
    with pytest.raises(LimitError):
        fragment.fragment(b"x", 1, max_datagram=100)
    with pytest.raises(LimitError):
        fragment.fragment(b"x" * (codec.MAX_MESSAGE_BYTES + 1), 1)
    assert HEADER_BYTES == 16
