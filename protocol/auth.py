"""Keyed sessions: a handshake of fresh nonces, per-session keys for each direction, replay windows.

With a pre-shared key (PSK) every datagram both ways is sealed with ChaCha20-Poly1305
(RFC 8439) under keys derived with HKDF-SHA256 (RFC 5869). The key schedule follows
the PSK-only key exchange of TLS 1.3 and DTLS 1.3 (RFC 8446 §7.1, RFC 9147: session
keys from the PSK and both sides' fresh randoms); the transport follows WireGuard
(one key per direction, a 64-bit counter as the AEAD nonce, a sliding replay
window as in RFC 6479)::

    hello  (C->S)  slot = Nc (16 random bytes)   key = HKDF(PSK, salt=Nc,      "vacc/6 hello")
    answer (S->C)  slot = Ns (16 random bytes)   key = HKDF(PSK, salt=Nc || Ns, "vacc/6 answer")
    session        token = HKDF(PSK, salt=Nc || Ns, "vacc/6 token", 16), sid = token[:8]
                   c2s = HKDF(..., "vacc/6 c2s"), s2c = HKDF(..., "vacc/6 s2c")

A sealed datagram is ``header (16) | slot (16) | ciphertext | tag (16)``: the slot
is the sender's nonce in a handshake datagram (flag HANDSHAKE) and ``sid | seq``
otherwise. The AEAD's associated data is ``header | slot | direction`` (1 C->S,
2 S->C), its nonce ``00000000 | seq`` (12 zero bytes in a handshake). A datagram of
another session, of the other direction (a reflection) or sealed with another key
fails before anything else looks at it; one that opens is then checked against its
session's replay window. Nothing here is simulation randomness.
"""

from __future__ import annotations

import itertools
import os
import struct
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from protocol.errors import AuthError, ForeignSessionError, KeyFileError, ReplayError
from protocol.fragment import FLAG_HANDSHAKE, FLAG_MAC, HEADER_BYTES
from protocol.messages import KEYED_VERSION

__all__ = [
    "TAG_BYTES",
    "SLOT_BYTES",
    "TRAILER_BYTES",
    "NONCE_BYTES",
    "SID_BYTES",
    "MIN_KEY_BYTES",
    "REPLAY_WINDOW",
    "C2S",
    "S2C",
    "load_key",
    "ReplayWindow",
    "SessionKeys",
    "session_keys",
    "hello_key",
    "seal_hello",
    "open_hello",
    "Channel",
    "ClientKeys",
    "ServerKeys",
]

TAG_BYTES = 16  # Poly1305 tag
SLOT_BYTES = 16  # a handshake nonce, or sid (8) | seq (8)
TRAILER_BYTES = SLOT_BYTES + TAG_BYTES  # 32: what a seal adds to every datagram
NONCE_BYTES = 16  # Nc and Ns: fresh randoms of each side
SID_BYTES = 8  # session id on every session datagram: the token's first 8 bytes
TOKEN_BYTES = 16
MIN_KEY_BYTES = 16
MAX_KEY_BYTES = 4096
REPLAY_WINDOW = 4096  # sequence numbers remembered per session and direction
C2S, S2C = 1, 2  # direction bytes in the associated data
_SEQ = struct.Struct("!Q")
_ZERO_NONCE = bytes(12)
_LABEL = b"vacc/6 "


def load_key(path: str | Path) -> bytes:
    """Read a pre-shared key file: its bytes, surrounding whitespace stripped.

    Make one with ``head -c 32 /dev/urandom > vacc.key`` (or ``openssl rand -hex 32``)
    and copy it to both sides.

    Raises:
        KeyFileError: if the file cannot be read or holds fewer than
            :data:`MIN_KEY_BYTES` bytes.
    """
    try:
        with open(path, "rb") as f:
            key = f.read(MAX_KEY_BYTES + 1).strip()
    except OSError as exc:
        raise KeyFileError(f"key file {path}: {exc.strerror or exc}") from None
    if len(key) < MIN_KEY_BYTES:
        raise KeyFileError(f"key file {path}: {len(key)} bytes, need at least {MIN_KEY_BYTES}")
    if len(key) > MAX_KEY_BYTES:
        raise KeyFileError(f"key file {path}: longer than {MAX_KEY_BYTES} bytes")
    return key


def _hkdf(psk: bytes, salt: bytes, label: str, length: int = 32) -> bytes:
    """HKDF-SHA256 (extract with ``salt``, expand with ``"vacc/6 " + label``)."""
    return HKDF(algorithm=hashes.SHA256(), length=length, salt=salt, info=_LABEL + label.encode()).derive(psk)


class ReplayWindow:
    """One direction of one session: the highest sequence number seen, and which of the
    ``size`` numbers below it were seen. A new window has seen nothing (highest -1)."""

    def __init__(self, size: int = REPLAY_WINDOW):
        self.size = size
        self._mask = (1 << size) - 1
        self.top = -1
        self._bits = 0

    def check(self, seq: int) -> None:
        """Record ``seq``.

        Raises:
            ReplayError: if it was seen before or is ``size`` or more below the highest.
        """
        if seq > self.top:
            shift = seq - self.top
            self._bits = ((self._bits << shift) | 1) & self._mask if shift < self.size else 1
            self.top = seq
            return
        back = self.top - seq
        if back >= self.size:
            raise ReplayError(f"sequence number {seq} is older than the window ({self.top} - {self.size})")
        if self._bits >> back & 1:
            raise ReplayError(f"sequence number {seq} was already received")
        self._bits |= 1 << back


@dataclass(frozen=True)
class SessionKeys:
    """What both sides derive from the PSK and the two nonces (never sent)."""

    nc: bytes  # the client's nonce, from its hello
    ns: bytes  # the server's nonce, from its answer
    token: bytes  # the session token of the welcome; its first SID_BYTES are the sid
    c2s: bytes  # [32 bytes] key of client-to-server datagrams
    s2c: bytes  # [32 bytes] key of server-to-client datagrams
    answer: bytes  # [32 bytes] key of the server's one answer to the hello

    @property
    def sid(self) -> bytes:
        return self.token[:SID_BYTES]

    def seal(self, datagram: bytes) -> bytes:
        """Seal the server's answer to the hello (a welcome or an error): slot Ns, nonce 0."""
        return _seal(ChaCha20Poly1305(self.answer), _handshake(datagram), self.ns, S2C, _ZERO_NONCE)


def hello_key(psk: bytes, nc: bytes) -> bytes:
    """The key a hello with client nonce ``nc`` is sealed with."""
    return _hkdf(psk, nc, "hello")


def session_keys(psk: bytes, nc: bytes, ns: bytes) -> SessionKeys:
    """Every key of the session that the nonces ``nc`` (client) and ``ns`` (server) open."""
    salt = nc + ns
    return SessionKeys(nc, ns, _hkdf(psk, salt, "token", TOKEN_BYTES), _hkdf(psk, salt, "c2s"), _hkdf(psk, salt, "s2c"), _hkdf(psk, salt, "answer"))


def _handshake(datagram: bytes) -> bytes:
    return datagram[:3] + bytes([datagram[3] | FLAG_MAC | FLAG_HANDSHAKE]) + datagram[4:]


def _seal(aead: ChaCha20Poly1305, datagram: bytes | memoryview, slot: bytes, direction: int, nonce: bytes) -> bytes:
    header = bytes(datagram[:HEADER_BYTES])
    return header + slot + aead.encrypt(nonce, bytes(datagram[HEADER_BYTES:]), header + slot + bytes([direction]))


def _open(aead: ChaCha20Poly1305, datagram: bytes, direction: int, nonce: bytes) -> bytes:
    """The datagram as it was before sealing (header | body).

    Raises:
        AuthError: if the tag does not verify (another key, direction, header or slot).
    """
    head = datagram[: HEADER_BYTES + SLOT_BYTES]
    try:
        body = aead.decrypt(nonce, datagram[HEADER_BYTES + SLOT_BYTES :], head + bytes([direction]))
    except InvalidTag:
        raise AuthError("datagram does not open with this key and direction") from None
    return datagram[:HEADER_BYTES] + body


def _check_form(datagram: bytes) -> None:
    if len(datagram) < HEADER_BYTES + TRAILER_BYTES or not datagram[3] & FLAG_MAC:
        raise AuthError("datagram carries no seal")
    if datagram[2] != KEYED_VERSION:
        raise AuthError(f"sealed datagram of version {datagram[2]}: keyed sessions speak version {KEYED_VERSION}")


def seal_hello(psk: bytes, nc: bytes, datagram: bytes) -> bytes:
    """Seal a client's hello (header flags get MAC and HANDSHAKE): slot ``nc``, nonce 0.

    A re-sent hello keeps its nonce, so it is the same bytes."""
    return _seal(ChaCha20Poly1305(hello_key(psk, nc)), _handshake(datagram), nc, C2S, _ZERO_NONCE)


def open_hello(psk: bytes, datagram: bytes) -> tuple[bytes, bytes]:
    """Open a sealed hello: ``(datagram without its seal, the client's nonce)``.

    Raises:
        AuthError: if it is no hello sealed with this key.
    """
    _check_form(datagram)
    nc = datagram[HEADER_BYTES : HEADER_BYTES + NONCE_BYTES]
    return _open(ChaCha20Poly1305(hello_key(psk, nc)), datagram, C2S, _ZERO_NONCE), nc


class Channel:
    """One side's seals of one session: its sending key and counter, the peer's key and window.

    Args:
        keys: the session's keys.
        client: True on the client's side (it sends C->S), False on the server's.
    """

    def __init__(self, keys: SessionKeys, *, client: bool):
        self.keys = keys
        self.sid = keys.sid
        self._send = ChaCha20Poly1305(keys.c2s if client else keys.s2c)
        self._recv = ChaCha20Poly1305(keys.s2c if client else keys.c2s)
        self._send_dir, self._recv_dir = (C2S, S2C) if client else (S2C, C2S)
        self._seq = itertools.count()  # next() is atomic: a keep-alive thread may seal too
        self.window = ReplayWindow()

    def seal(self, datagram: bytes) -> bytes:
        """Seal with the next sequence number: every transmission gets a fresh one."""
        seq = next(self._seq)
        packed = _SEQ.pack(seq)
        return _seal(self._send, datagram, self.sid + packed, self._send_dir, bytes(4) + packed)

    def open(self, datagram: bytes) -> bytes:
        """Open one of the peer's datagrams of this session (its form already checked).

        Raises:
            ForeignSessionError: if it belongs to another session.
            AuthError: if it does not verify (wrong key, reflected, altered).
            ReplayError: if its sequence number was seen or is too old.
        """
        if datagram[3] & FLAG_HANDSHAKE or datagram[HEADER_BYTES : HEADER_BYTES + SID_BYTES] != self.sid:
            raise ForeignSessionError("datagram of another session")
        packed = datagram[HEADER_BYTES + SID_BYTES : HEADER_BYTES + SLOT_BYTES]
        plain = _open(self._recv, datagram, self._recv_dir, bytes(4) + packed)
        self.window.check(_SEQ.unpack(packed)[0])
        return plain


class ClientKeys:
    """A client's side: the hello's nonce, the answers it opened, and its session's channel."""

    def __init__(self, psk: bytes):
        if len(psk) < MIN_KEY_BYTES:
            raise KeyFileError(f"key of {len(psk)} bytes, need at least {MIN_KEY_BYTES}")
        self.psk = psk
        self.nc: bytes | None = None
        self.channel: Channel | None = None
        self._answers: OrderedDict[bytes, SessionKeys] = OrderedDict()  # sid -> keys, of the current hello

    def begin(self) -> None:
        """A new handshake: a fresh nonce; the old session's keys are forgotten."""
        self.nc = os.urandom(NONCE_BYTES)  # a key-exchange random, not simulation randomness
        self.channel = None
        self._answers.clear()

    def establish(self, token: bytes) -> None:
        """Use the keys of the answer that carried the welcome with ``token``.

        Raises:
            AuthError: if no answer to the current hello derived that token.
        """
        keys = self._answers.get(bytes(token[:SID_BYTES]))
        if keys is None or keys.token != token:
            raise AuthError("the welcome's token is not one this hello's keys derive")
        self.channel = Channel(keys, client=True)

    def seal(self, datagram: bytes) -> bytes:
        """Seal a hello (handshake flag set by the packer) or a session datagram.

        Raises:
            AuthError: a session datagram before any welcome.
        """
        if datagram[3] & FLAG_HANDSHAKE:
            assert self.nc is not None, "a hello is packed after begin()"
            return seal_hello(self.psk, self.nc, datagram)
        if self.channel is None:
            raise AuthError("no keyed session yet: send a hello first")
        return self.channel.seal(datagram)

    def open(self, datagram: bytes) -> bytes:
        """Open an answer to the current hello, or a datagram of the current session.

        Raises:
            AuthError, ForeignSessionError, ReplayError: as :meth:`Channel.open`.
        """
        _check_form(datagram)
        if datagram[3] & FLAG_HANDSHAKE:
            if self.nc is None:
                raise AuthError("a handshake answer, but no hello was sent")
            ns = bytes(datagram[HEADER_BYTES : HEADER_BYTES + NONCE_BYTES])
            keys = session_keys(self.psk, self.nc, ns)
            plain = _open(ChaCha20Poly1305(keys.answer), datagram, S2C, _ZERO_NONCE)
            self._answers[keys.sid] = keys
            while len(self._answers) > 4:  # BUSY answers while it waits: keep the last few
                self._answers.popitem(last=False)
            return plain
        if self.channel is None:
            raise ForeignSessionError("a session datagram, but no session is established")
        return self.channel.open(datagram)


class ServerKeys:
    """A server's side: opens hellos, and session datagrams with the channel their sid names.

    Args:
        psk: the pre-shared key.
        lookup: the channel and address of a session (open or handshaking) by sid, or None.
    """

    def __init__(self, psk: bytes, lookup: Callable[[bytes], tuple[Channel, Any] | None]):
        if len(psk) < MIN_KEY_BYTES:
            raise KeyFileError(f"key of {len(psk)} bytes, need at least {MIN_KEY_BYTES}")
        self.psk = psk
        self.lookup = lookup

    def open(self, datagram: bytes, addr: Any) -> tuple[bytes, Any]:
        """Open a datagram: ``(datagram without its seal, what seals the answer)``.

        A hello's answer is sealed with fresh session keys (a new server nonce);
        a session datagram's with its session's channel.

        Raises:
            AuthError, ForeignSessionError, ReplayError: if it does not open.
        """
        _check_form(datagram)
        if datagram[3] & FLAG_HANDSHAKE:
            plain, nc = open_hello(self.psk, datagram)
            return plain, session_keys(self.psk, nc, os.urandom(NONCE_BYTES))
        found = self.lookup(bytes(datagram[HEADER_BYTES : HEADER_BYTES + SID_BYTES]))
        if found is None:
            raise ForeignSessionError("datagram of no session this server holds")
        channel, owner = found
        if owner[:2] != addr[:2]:
            raise ForeignSessionError("datagram of a session bound to another address")
        return channel.open(datagram), channel
