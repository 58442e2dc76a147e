"""Datagram authentication with a shared key: a MAC and a replay window.

With a key, every datagram in both directions is sealed::

    header (16, flags has FLAG_MAC) | body | seq u64 | tag (16)

``tag`` is the first :data:`TAG_BYTES` bytes of HMAC-SHA256(key, header | body | seq),
so the header (message id, fragment index and count, length) and the sequence
number are covered too. ``seq`` counts the sender's datagrams, every transmission
a fresh one (a re-sent request is sealed again), starting from the sender's wall
clock in nanoseconds so that a restarted sender continues above its old numbers.

The receiver checks the tag before anything else (before reassembly and
decoding), then the sequence number against a window of the last
:data:`REPLAY_WINDOW` numbers per peer address: a number seen before, or older
than the window, is a replay. A datagram that fails either check is dropped,
counted and never answered.
"""

from __future__ import annotations

import hashlib
import hmac
import itertools
import struct
import time
from collections import OrderedDict
from collections.abc import Hashable
from pathlib import Path

from protocol.errors import AuthError, KeyFileError, ReplayError
from protocol.fragment import FLAG_MAC, HEADER_BYTES

__all__ = [
    "TAG_BYTES",
    "SEQ_BYTES",
    "TRAILER_BYTES",
    "MIN_KEY_BYTES",
    "REPLAY_WINDOW",
    "load_key",
    "Sealer",
    "ReplayWindow",
]

TAG_BYTES = 16  # truncated HMAC-SHA256: 128-bit forgery resistance
SEQ_BYTES = 8
TRAILER_BYTES = SEQ_BYTES + TAG_BYTES  # added to every sealed datagram
MIN_KEY_BYTES = 16
MAX_KEY_BYTES = 4096
REPLAY_WINDOW = 4096  # sequence numbers remembered per peer
MAX_PEERS = 1024  # peers whose windows are remembered (least recently used go first)
_SEQ = struct.Struct("!Q")


def load_key(path: str | Path) -> bytes:
    """Read a shared key file: its bytes, surrounding whitespace stripped.

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


class ReplayWindow:
    """Sequence numbers seen per peer: the highest, and a bitmap of the last ``size``."""

    def __init__(self, size: int = REPLAY_WINDOW, max_peers: int = MAX_PEERS):
        self.size = size
        self.max_peers = max_peers
        self._mask = (1 << size) - 1
        self._peers: OrderedDict[Hashable, tuple[int, int]] = OrderedDict()

    def check(self, peer: Hashable, seq: int) -> None:
        """Record ``seq`` from ``peer``.

        Raises:
            ReplayError: if it was seen before or is older than the window.
        """
        state = self._peers.get(peer)
        if state is None:
            self._peers[peer] = (seq, 1)
            if len(self._peers) > self.max_peers:
                self._peers.popitem(last=False)
            return
        top, bits = state
        if seq > top:
            shift = seq - top
            bits = ((bits << shift) | 1) & self._mask if shift < self.size else 1
            top = seq
        else:
            back = top - seq
            if back >= self.size:
                raise ReplayError(f"sequence number {seq} is older than the window ({top} - {self.size})")
            if bits >> back & 1:
                raise ReplayError(f"sequence number {seq} was already received")
            bits |= 1 << back
        self._peers[peer] = (top, bits)
        self._peers.move_to_end(peer)


class Sealer:
    """Seals outgoing datagrams and opens incoming ones with one shared key.

    Args:
        key: the shared key (:func:`load_key`).
        window: the replay window of incoming sequence numbers.
    """

    def __init__(self, key: bytes, window: ReplayWindow | None = None):
        if len(key) < MIN_KEY_BYTES:
            raise KeyFileError(f"key of {len(key)} bytes, need at least {MIN_KEY_BYTES}")
        self._keyed = hmac.new(key, digestmod=hashlib.sha256)  # copied per datagram: the key is set up once
        self._seq = itertools.count(time.time_ns())  # next() is atomic: safe from two threads
        self.window = window or ReplayWindow()

    def _tag(self, data: bytes | memoryview) -> bytes:
        mac = self._keyed.copy()
        mac.update(data)
        return mac.digest()[:TAG_BYTES]

    def seal(self, datagram: bytes) -> bytes:
        """Append a fresh sequence number and the MAC (the header must carry FLAG_MAC)."""
        data = datagram + _SEQ.pack(next(self._seq) & 0xFFFFFFFFFFFFFFFF)
        return data + self._tag(data)

    def open(self, datagram: bytes, peer: Hashable) -> bytes:
        """Check a sealed datagram and return it without its seal.

        Raises:
            AuthError: if it carries no MAC or a wrong one.
            ReplayError: if its sequence number was seen before or is too old.
        """
        if len(datagram) < HEADER_BYTES + TRAILER_BYTES or not datagram[3] & FLAG_MAC:
            raise AuthError("datagram carries no MAC")
        data = memoryview(datagram)[:-TAG_BYTES]
        if not hmac.compare_digest(self._tag(data), datagram[-TAG_BYTES:]):
            raise AuthError("datagram MAC does not match the key")
        self.window.check(peer, _SEQ.unpack_from(datagram, len(datagram) - TRAILER_BYTES)[0])
        return datagram[:-TRAILER_BYTES]
