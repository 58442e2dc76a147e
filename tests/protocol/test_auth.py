"""Keyed sessions: per-session, per-direction AEAD seals and their replay windows (issues #17, #55)."""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import os
import socket

import pytest
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

from protocol import codec
from protocol.auth import (
    C2S,
    REPLAY_WINDOW,
    SLOT_BYTES,
    TAG_BYTES,
    TRAILER_BYTES,
    Channel,
    ClientKeys,
    ReplayWindow,
    ServerKeys,
    load_key,
    open_hello,
    seal_hello,
    session_keys,
)
from protocol.errors import AuthError, ForeignSessionError, KeyFileError, ProtocolError, ReplayError
from protocol.fragment import FLAG_HANDSHAKE, FLAG_MAC, HEADER_BYTES, fragment
from protocol.messages import KEYED_VERSION
from protocol.transport import Endpoint

KEY = b"k" * 32
NC, NS = bytes(range(16)), bytes(range(16, 32))
CLOSE = {"type": "close", "session": b"\x01" * 16}


def plain_datagram(msg: dict | None = None) -> bytes:
    return fragment(codec.encode(msg or CLOSE), 1, flags=FLAG_MAC, trailer=TRAILER_BYTES, version=KEYED_VERSION)[0]


def pair(key: bytes = KEY, ns: bytes = NS) -> tuple[Channel, Channel]:
    keys = session_keys(key, NC, ns)
    return Channel(keys, client=True), Channel(keys, client=False)


def test_seal_round_trip_and_layout():
    client, server = pair()
    plain = plain_datagram()
    sealed = client.seal(plain)
    assert len(sealed) == len(plain) + TRAILER_BYTES and sealed[3] & FLAG_MAC
    assert sealed[HEADER_BYTES : HEADER_BYTES + 8] == client.sid and sealed[HEADER_BYTES + 8 : HEADER_BYTES + SLOT_BYTES] == bytes(8)
    assert server.open(sealed) == plain
    assert client.open(server.seal(plain)) == plain


def test_every_transmission_gets_a_fresh_sequence_number():
    client, _ = pair()
    plain = plain_datagram()
    a, b = client.seal(plain), client.seal(plain)
    assert a != b and a[:HEADER_BYTES] == b[:HEADER_BYTES]


@pytest.mark.parametrize("where", [0, 2, 5, HEADER_BYTES + 2, HEADER_BYTES + 12, HEADER_BYTES + SLOT_BYTES + 1, -TAG_BYTES - 1, -1])
def test_any_flipped_byte_fails_the_seal(where):
    client, server = pair()
    sealed = bytearray(client.seal(plain_datagram()))
    sealed[where] ^= 0x40
    with pytest.raises(AuthError):
        ServerKeys(KEY, lambda sid: (server, PEER)).open(bytes(sealed), PEER)


PEER = ("127.0.0.1", 9)


def test_wrong_key_and_missing_seal_are_refused():
    _, server = pair()
    # A wrong key that even knows the session's id.
    client = Channel(dataclasses.replace(session_keys(b"x" * 32, NC, NS), token=server.keys.token), client=True)
    with pytest.raises(AuthError, match="does not open"):
        server.open(client.seal(plain_datagram()))
    keys = ServerKeys(KEY, lambda sid: (server, PEER))
    bare = fragment(codec.encode(CLOSE), 1, version=KEYED_VERSION)[0]
    with pytest.raises(AuthError, match="no seal"):
        keys.open(bare + bytes(TRAILER_BYTES), PEER)
    with pytest.raises(AuthError, match="no seal"):
        keys.open(bare[:HEADER_BYTES], PEER)


def test_replayed_datagram_is_refused():
    client, server = pair()
    sealed = client.seal(plain_datagram())
    server.open(sealed)
    with pytest.raises(ReplayError, match="already received"):
        server.open(sealed)
    # Windows are per session: another session's channel does not take it at all,
    # and its own first number opens although this one was seen.
    other_client, other_server = pair(ns=bytes(16))
    with pytest.raises(ForeignSessionError):
        other_server.open(sealed)
    other_server.open(other_client.seal(plain_datagram()))


def test_a_reflected_datagram_does_not_open():
    """The issue's reflection: a client's own step sent back to it as if from the server."""
    client, server = pair()
    own = client.seal(plain_datagram())
    with pytest.raises(AuthError, match="does not open"):
        client.open(own)
    with pytest.raises(AuthError, match="does not open"):
        server.open(server.seal(plain_datagram()))
    assert client.window.top == -1 and server.window.top == -1  # nothing moved


def test_a_datagram_of_another_session_is_foreign():
    """The issue's cross-session replay: an earlier session's obs sent into a new session."""
    old_client, old_server = pair(ns=b"\x00" * 16)
    new_client, _ = pair()
    with pytest.raises(ForeignSessionError):
        new_client.open(old_server.seal(plain_datagram()))
    assert issubclass(ForeignSessionError, AuthError)


def test_replay_window_accepts_reordering_and_refuses_old_numbers():
    w = ReplayWindow(size=64)
    for seq in (100, 98, 99, 101, 90):
        w.check(seq)
    for seq in (98, 101, 90):
        with pytest.raises(ReplayError, match="already"):
            w.check(seq)
    w.check(300)
    with pytest.raises(ReplayError, match="older than the window"):
        w.check(300 - 64)
    w.check(300 - 63)


def test_a_new_window_takes_any_first_number_and_reordering_below_it():
    w = ReplayWindow(size=64)
    w.check(5)
    w.check(0)  # below the first one seen, inside the window: accepted once
    with pytest.raises(ReplayError):
        w.check(0)


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
    with pytest.raises(KeyFileError, match="at least 16"):
        ClientKeys(b"short")


def test_auth_errors_subclass_builtin_and_package_base():
    assert issubclass(AuthError, ValueError) and issubclass(AuthError, ProtocolError)
    assert issubclass(ReplayError, AuthError) and issubclass(KeyFileError, ValueError)


def hkdf_sha256(ikm: bytes, salt: bytes, info: bytes, length: int = 32) -> bytes:
    """RFC 5869 written out with the standard library, to check the implementation against."""
    prk = hmac.new(salt, ikm, hashlib.sha256).digest()
    out, block = b"", b""
    for i in range(1, -(-length // 32) + 1):
        block = hmac.new(prk, block + info + bytes([i]), hashlib.sha256).digest()
        out += block
    return out[:length]


def test_seal_is_chacha20_poly1305_under_hkdf_keys():
    keys = session_keys(KEY, NC, NS)
    assert keys.c2s == hkdf_sha256(KEY, NC + NS, b"vacc/6 c2s") and keys.s2c == hkdf_sha256(KEY, NC + NS, b"vacc/6 s2c")
    assert keys.token == hkdf_sha256(KEY, NC + NS, b"vacc/6 token", 16) and keys.c2s != keys.s2c
    client, _ = pair()
    plain = plain_datagram()
    client.seal(plain)
    sealed = client.seal(plain)  # seq 1
    head = sealed[: HEADER_BYTES + SLOT_BYTES]
    assert head[-8:] == (1).to_bytes(8, "big")
    body = ChaCha20Poly1305(keys.c2s).decrypt(bytes(4) + head[-8:], sealed[len(head) :], head + bytes([C2S]))
    assert plain == sealed[:HEADER_BYTES] + body


def test_hello_opens_with_the_psk_and_its_answer_only_with_its_nonce():
    hello = fragment(codec.encode(CLOSE), 1, flags=FLAG_MAC, trailer=TRAILER_BYTES, version=KEYED_VERSION)[0]
    sealed = seal_hello(KEY, NC, hello)
    assert sealed == seal_hello(KEY, NC, hello)  # a re-sent hello is the same bytes
    assert sealed[3] & FLAG_HANDSHAKE and sealed[HEADER_BYTES : HEADER_BYTES + 16] == NC
    plain, nc = open_hello(KEY, sealed)
    assert nc == NC and plain[HEADER_BYTES:] == hello[HEADER_BYTES:]
    with pytest.raises(AuthError):
        open_hello(b"w" * 32, sealed)
    answer = session_keys(KEY, NC, NS).seal(hello)
    with pytest.raises(AuthError):
        open_hello(KEY, answer)  # an answer reflected to the server is no hello
    client = ClientKeys(KEY)
    client.begin()
    with pytest.raises(AuthError):
        client.open(answer)  # sealed for another hello's nonce
    client.nc = NC
    assert client.open(answer)[HEADER_BYTES:] == hello[HEADER_BYTES:]
    with pytest.raises(AuthError):
        client.open(sealed)  # its own hello reflected


def endpoints(key_a: bytes | None, key_b: bytes | None) -> tuple[Endpoint, Endpoint]:
    """A client endpoint (a) with an established session and a server endpoint (b)."""
    a, b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    a.bind(("127.0.0.1", 0))
    b.bind(("127.0.0.1", 0))
    server_channel = Channel(session_keys(key_b or KEY, NC, NS), client=False)
    client, server = Endpoint(a, key=key_a), Endpoint(b, key=key_b, sessions=lambda sid: (server_channel, a.getsockname()))
    if key_a is not None:
        client.keys.channel = Channel(session_keys(key_a, NC, NS), client=True)
    return client, server


@pytest.mark.parametrize("keys, reason", [((KEY, KEY), None), ((None, KEY), "AuthError"), ((KEY, None), "AuthError"), ((b"y" * 32, KEY), "ForeignSessionError")])
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


def test_many_sessions_never_share_keys():
    tokens = {session_keys(KEY, os.urandom(16), os.urandom(16)).token for _ in range(50)}
    assert len(tokens) == 50
