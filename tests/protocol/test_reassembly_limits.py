"""Reassembly bounded per direction and per peer; padded hellos (issue #17)."""

from __future__ import annotations

import pytest

from protocol import codec
from protocol.errors import FragmentError, LimitError
from protocol.fragment import (
    FLAG_PADDED,
    HEADER,
    HELLO_BYTES,
    MAGIC,
    Reassembler,
    fragment,
    pad,
    parse_header,
)
from protocol.messages import PROTOCOL_VERSION

V = PROTOCOL_VERSION


def test_limit_request_size_on_the_server_side():
    r = Reassembler(max_message=codec.MAX_REQUEST_BYTES)
    with pytest.raises(LimitError, match="exceeds"):
        r.feed(HEADER.pack(MAGIC, V, 0, 1, 0, 65, codec.MAX_REQUEST_BYTES + 1) + b"x" * 65000, "attacker", 0.0)
    assert r.pending == 0


def test_limit_pending_messages_per_peer():
    r = Reassembler(max_pending_per_peer=4)
    r.feed(HEADER.pack(MAGIC, V, 0, 1, 0, 2, 2000) + b"v" * 1000, "victim", 0.0)
    for msg_id in range(100):
        r.feed(HEADER.pack(MAGIC, V, 0, msg_id, 0, 2, 2000) + b"x" * 1000, "attacker", 0.0)
    assert r.pending == 5  # the attacker's 4 newest and the victim's one
    assert r.feed(HEADER.pack(MAGIC, V, 0, 1, 1, 2, 2000) + b"v" * 1000, "victim", 0.0) == b"v" * 2000


def test_limit_bytes_per_peer():
    r = Reassembler(max_bytes_per_peer=3000, max_pending_per_peer=100)
    r.feed(HEADER.pack(MAGIC, V, 0, 1, 0, 2, 2000) + b"v" * 1000, "victim", 0.0)
    for msg_id in range(10):
        r.feed(HEADER.pack(MAGIC, V, 0, msg_id, 0, 2, 2000) + b"x" * 1000, "attacker", 0.0)
    assert r.pending_bytes <= 1000 + 3000
    with pytest.raises(LimitError, match="for one peer"):
        Reassembler(max_bytes_per_peer=500).feed(HEADER.pack(MAGIC, V, 0, 1, 0, 2, 2000) + b"x" * 1000, "p", 0.0)


def test_padded_hello_round_trip():
    payload = codec.encode({"type": "close", "session": b"\x01" * 16})
    padded = pad(fragment(payload, 3)[0], HELLO_BYTES)
    assert len(padded) == HELLO_BYTES and padded[3] & FLAG_PADDED
    assert Reassembler().feed(padded, "p", 0.0) == payload


def test_padding_only_on_single_fragments():
    with pytest.raises(FragmentError, match="padded fragment"):
        parse_header(HEADER.pack(MAGIC, V, FLAG_PADDED, 1, 0, 2, 2000) + b"x" * 1000)
    with pytest.raises(FragmentError, match="single-fragment"):
        pad(HEADER.pack(MAGIC, V, 0, 1, 0, 2, 2000) + b"x" * 1000, 1200)
    with pytest.raises(FragmentError, match="single fragment carries"):
        parse_header(HEADER.pack(MAGIC, V, 0, 1, 0, 1, 3) + b"abcdef")  # unflagged padding


def test_message_in_progress_survives_its_peers_stale_fragments():
    r = Reassembler(max_pending_per_peer=2)
    for index in (0, 1):  # the current reply, half there
        r.feed(HEADER.pack(MAGIC, V, 0, 50, index, 4, 4000) + b"c" * 1000, "server", 0.0)
    for msg_id in range(10):  # late duplicates of earlier, finished replies
        r.feed(HEADER.pack(MAGIC, V, 0, msg_id, 3, 4, 4000) + b"s" * 1000, "server", 0.0)
    r.feed(HEADER.pack(MAGIC, V, 0, 50, 2, 4, 4000) + b"c" * 1000, "server", 0.0)
    assert r.feed(HEADER.pack(MAGIC, V, 0, 50, 3, 4, 4000) + b"c" * 1000, "server", 0.0) == b"c" * 4000
