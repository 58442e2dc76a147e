"""Shared-key seals and the replay window (issue #17, item 3)."""

from __future__ import annotations

import socket

import pytest

from protocol import codec
from protocol.auth import REPLAY_WINDOW, TAG_BYTES, TRAILER_BYTES, ReplayWindow, Sealer, load_key
from protocol.errors import AuthError, KeyFileError, ProtocolError, ReplayError
from protocol.fragment import FLAG_MAC, HEADER_BYTES, fragment
from protocol.transport import Endpoint

KEY = b"k" * 32
PEER = ("127.0.0.1", 9)


def sealed_datagram(sealer: Sealer, msg: dict | None = None) -> bytes:
    msg = msg or {"type": "close", "session": b"\x01" * 16}
    return sealer.seal(fragment(codec.encode(msg), 1, flags=FLAG_MAC, trailer=TRAILER_BYTES)[0])


def test_seal_round_trip_and_layout():
    tx, rx = Sealer(KEY), Sealer(KEY)
    plain = fragment(codec.encode({"type": "close", "session": b"\x01" * 16}), 1, flags=FLAG_MAC, trailer=TRAILER_BYTES)[0]
    sealed = tx.seal(plain)
    assert len(sealed) == len(plain) + TRAILER_BYTES and sealed[3] & FLAG_MAC
    assert rx.open(sealed, PEER) == plain


def test_every_transmission_gets_a_fresh_sequence_number():
    tx = Sealer(KEY)
    plain = fragment(b"\x80", 1, flags=FLAG_MAC, trailer=TRAILER_BYTES)[0]
    a, b = tx.seal(plain), tx.seal(plain)
    assert a != b and a[:-TRAILER_BYTES] == b[:-TRAILER_BYTES]


@pytest.mark.parametrize("where", [0, 5, HEADER_BYTES + 2, -TRAILER_BYTES, -1])
def test_any_flipped_byte_fails_the_mac(where):
    sealed = bytearray(sealed_datagram(Sealer(KEY)))
    sealed[where] ^= 0x40
    with pytest.raises(AuthError):
        Sealer(KEY).open(bytes(sealed), PEER)


def test_wrong_key_and_missing_mac_are_refused():
    sealed = sealed_datagram(Sealer(b"x" * 32))
    with pytest.raises(AuthError, match="does not match"):
        Sealer(KEY).open(sealed, PEER)
    plain = fragment(codec.encode({"type": "close", "session": b"\x01" * 16}), 1)[0]
    with pytest.raises(AuthError, match="no MAC"):
        Sealer(KEY).open(plain + bytes(TRAILER_BYTES), PEER)
    with pytest.raises(AuthError, match="no MAC"):
        Sealer(KEY).open(plain[:HEADER_BYTES], PEER)


def test_replayed_datagram_is_refused():
    tx, rx = Sealer(KEY), Sealer(KEY)
    sealed = sealed_datagram(tx)
    rx.open(sealed, PEER)
    with pytest.raises(ReplayError, match="already received"):
        rx.open(sealed, PEER)
    rx.open(sealed, ("127.0.0.1", 10))  # windows are per peer address


def test_replay_window_accepts_reordering_and_refuses_old_numbers():
    w = ReplayWindow(size=64)
    for seq in (100, 98, 99, 101, 90):
        w.check(PEER, seq)
    for seq in (98, 101, 90):
        with pytest.raises(ReplayError, match="already"):
            w.check(PEER, seq)
    w.check(PEER, 300)
    with pytest.raises(ReplayError, match="older than the window"):
        w.check(PEER, 300 - 64)
    w.check(PEER, 300 - 63)


def test_replay_window_default_size():
    assert REPLAY_WINDOW >= 1024  # room for 8-fragment images reordered by a lossy link


def test_short_key_refused(tmp_path):
    path = tmp_path / "k"
    path.write_bytes(b"short\n")
    with pytest.raises(KeyFileError, match="at least 16"):
        load_key(path)
    with pytest.raises(KeyFileError, match="no-such"):
        load_key(tmp_path / "no-such")
    path.write_text("0123456789abcdef0123456789abcdef\n")
    assert load_key(path) == b"0123456789abcdef0123456789abcdef"


def test_auth_errors_subclass_builtin_and_package_base():
    assert issubclass(AuthError, ValueError) and issubclass(AuthError, ProtocolError)
    assert issubclass(ReplayError, AuthError) and issubclass(KeyFileError, ValueError)


def test_tag_is_truncated_hmac_sha256():
    import hashlib
    import hmac

    sealed = sealed_datagram(Sealer(KEY))
    assert sealed[-TAG_BYTES:] == hmac.new(KEY, sealed[:-TAG_BYTES], hashlib.sha256).digest()[:TAG_BYTES]


def endpoints(key_a: bytes | None, key_b: bytes | None) -> tuple[Endpoint, Endpoint]:
    a, b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    a.bind(("127.0.0.1", 0))
    b.bind(("127.0.0.1", 0))
    return Endpoint(a, key=key_a), Endpoint(b, key=key_b)


@pytest.mark.parametrize("keys, reason", [((KEY, KEY), None), ((None, KEY), "AuthError"), ((KEY, None), "AuthError"), ((b"y" * 32, KEY), "AuthError")])
def test_endpoints_accept_only_their_key(keys, reason):
    a, b = endpoints(*keys)
    try:
        a.send({"type": "heartbeat", "session": b"\x01" * 16, "seq": 3}, b.sock.getsockname())
        got = b.receive(1.0)
        assert got is not None
        if reason is None:
            assert got.msg is not None and got.msg["seq"] == 3
        else:
            assert got.msg is None and b.rejected[reason] == 1
    finally:
        a.close()
        b.close()


def test_sealed_fragments_respect_max_datagram():
    a, b = endpoints(KEY, KEY)
    try:
        a.max_datagram = 1400
        datagrams = a.pack({"type": "obs", "episode": 0, "frame": 1, "t": 0.1, "v_host": 1.0, "v_lead": 1.0, "gap": 1.0, "accel": 0.0, "a_lead": 0.0, "force": 0.0, "collision": False, "terminated": False, "truncated": False, "reason": "", "image": bytes(5000), "image_shape": [50, 100, 1]})  # fmt: skip
        assert len(datagrams) > 1
        assert all(len(a.seal(d)) <= 1400 for d in datagrams)
    finally:
        a.close()
        b.close()
