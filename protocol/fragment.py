"""Datagram framing: a fixed header, fragmentation and reassembly.

Every datagram starts with a 16-byte big-endian header::

    magic   2s  b"VC"
    version u8  PROTOCOL_VERSION (a server also takes the older SUPPORTED_VERSIONS)
    flags   u8  FLAG_MAC | FLAG_PADDED | FLAG_HANDSHAKE; other bits reserved (0, ignored)
    msg_id  u32 sender's message counter; fragments of one message share it
    index   u16 this fragment's index, 0..count-1
    count   u16 fragments in the message, 1..MAX_FRAGMENTS
    total   u32 whole message length in bytes

followed by the fragment's bytes. All fragments but the last carry the same number
of bytes; the last carries the rest. A message that fits is one fragment. A
single-fragment datagram with ``FLAG_PADDED`` may carry bytes after its ``total``,
which are ignored (a client pads its ``hello`` so that no reply to an unauthenticated
datagram is larger than it). ``FLAG_MAC`` marks a datagram sealed by
:mod:`protocol.auth`; the reassembler sees it after the seal is checked and removed.
"""

from __future__ import annotations

import struct
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass, field

from protocol.codec import MAX_MESSAGE_BYTES
from protocol.errors import DecodeError, FragmentError, LimitError, VersionError
from protocol.messages import PROTOCOL_VERSION

__all__ = [
    "HEADER",
    "HEADER_BYTES",
    "MAGIC",
    "MIN_DATAGRAM",
    "MAX_DATAGRAM",
    "DEFAULT_DATAGRAM",
    "MAX_FRAGMENTS",
    "HELLO_BYTES",
    "FLAG_MAC",
    "FLAG_PADDED",
    "FLAG_HANDSHAKE",
    "fragment",
    "pad",
    "parse_header",
    "Reassembler",
]

MAGIC = b"VC"
HEADER = struct.Struct("!2sBBIHHI")
HEADER_BYTES = HEADER.size  # 16
MIN_DATAGRAM = 576  # [bytes] the IPv4 minimum reassembly size
MAX_DATAGRAM = 65507  # [bytes] the largest UDP payload over IPv4
DEFAULT_DATAGRAM = 65000  # [bytes] loopback default; use ~1400 across a real network
MAX_FRAGMENTS = 65535
HELLO_BYTES = MIN_DATAGRAM  # [bytes] a client pads its hello to this, so every answer fits in it
FLAG_MAC = 0x01  # the datagram is sealed with an AEAD (protocol.auth)
FLAG_PADDED = 0x02  # a single fragment followed by padding to ignore
FLAG_HANDSHAKE = 0x04  # a keyed hello or its answer: sealed with handshake keys (protocol.auth)


def fragment(
    payload: bytes, msg_id: int, max_datagram: int = DEFAULT_DATAGRAM, *, flags: int = 0, trailer: int = 0, version: int = PROTOCOL_VERSION
) -> list[bytes]:
    """Split one encoded message into datagrams.

    Args:
        payload: the encoded message.
        msg_id: the sender's message counter (wraps at 2**32).
        max_datagram: largest datagram to produce [bytes], header and trailer included.
        flags: header flags of every fragment.
        trailer: bytes to leave room for after each fragment (a MAC seal).
        version: the protocol version in the header (a server answers an older
            client in its own version).

    Raises:
        LimitError: if the message is too long for the fragment count or size limit.
    """
    if not MIN_DATAGRAM <= max_datagram <= MAX_DATAGRAM:
        raise LimitError(f"max_datagram {max_datagram} outside [{MIN_DATAGRAM}, {MAX_DATAGRAM}]")
    total = len(payload)
    if total > MAX_MESSAGE_BYTES:
        raise LimitError(f"message of {total} bytes exceeds {MAX_MESSAGE_BYTES}")
    msg_id &= 0xFFFFFFFF
    chunk = max_datagram - HEADER_BYTES - trailer
    if total <= chunk:
        return [HEADER.pack(MAGIC, version, flags, msg_id, 0, 1, total) + payload]
    count = -(-total // chunk)
    if count > MAX_FRAGMENTS:
        raise LimitError(f"message needs {count} fragments, more than {MAX_FRAGMENTS}")
    view = memoryview(payload)
    return [
        HEADER.pack(MAGIC, version, flags, msg_id, i, count, total)
        + view[i * chunk : (i + 1) * chunk]
        for i in range(count)
    ]


def pad(datagram: bytes, size: int) -> bytes:
    """A single-fragment datagram padded with zeros to ``size`` bytes (``FLAG_PADDED``).

    Raises:
        FragmentError: if the datagram is one fragment of several.
    """
    if HEADER.unpack_from(datagram)[5] != 1:
        raise FragmentError("only a single-fragment datagram can be padded")
    if len(datagram) >= size:
        return datagram
    return datagram[:3] + bytes([datagram[3] | FLAG_PADDED]) + datagram[4:] + bytes(size - len(datagram))


def parse_header(datagram: bytes, max_total: int = MAX_MESSAGE_BYTES, versions: tuple[int, ...] = (PROTOCOL_VERSION,)) -> tuple[int, int, int, int]:
    """Check a datagram's header.

    Args:
        datagram: the datagram, header included (a seal already removed).
        max_total: [bytes] largest whole message this receiver accepts.
        versions: the protocol versions this receiver speaks.

    Returns:
        ``(msg_id, index, count, total)``.

    Raises:
        DecodeError: if the datagram is shorter than a header or the magic is wrong.
        VersionError: if the header carries another protocol version.
        FragmentError: if index, count and total are inconsistent.
        LimitError: if total exceeds the message limit.
    """
    if len(datagram) < HEADER_BYTES:
        raise DecodeError(f"datagram of {len(datagram)} bytes is shorter than the header")
    magic, version, flags, msg_id, index, count, total = HEADER.unpack_from(datagram)
    if magic != MAGIC:
        raise DecodeError(f"bad magic {magic!r}")
    if version not in versions:
        raise VersionError(f"protocol version {version}, this side speaks {'/'.join(map(str, versions))}")
    if count == 0 or index >= count:
        raise FragmentError(f"fragment index {index} of count {count}")
    if total > max_total:
        raise LimitError(f"declared message length {total} exceeds {max_total}")
    body = len(datagram) - HEADER_BYTES
    if flags & FLAG_PADDED and count != 1:
        raise FragmentError(f"padded fragment {index} of a {count}-fragment message")
    if count == 1 and body != total and not (flags & FLAG_PADDED and body > total):
        raise FragmentError(f"single fragment carries {body} bytes, header says {total}")
    if count > 1:
        # A non-last fragment fixes the chunk size L: (count-1)*L < total <= count*L.
        fits = 0 < body <= total
        if index < count - 1:
            fits = fits and body * (count - 1) < total <= body * count
        if not fits:
            raise FragmentError(f"fragment {index}/{count} of {body} bytes does not fit total {total}")
    return msg_id, index, count, total


@dataclass
class _Partial:
    count: int
    total: int
    version: int
    started: float  # [s] monotonic time of the first fragment
    parts: dict[int, bytes] = field(default_factory=dict)
    size: int = 0  # [bytes] held so far


class Reassembler:
    """Puts fragments back together, within bounds on count, bytes and age.

    Keys are ``(peer, msg_id)``, so two peers never mix their fragments. A repeated
    fragment with identical length is ignored (a retransmission); a repeated one of
    another length, or one whose count/total disagree with its message, drops the
    whole assembly and raises :class:`FragmentError`. One peer over its own caps
    evicts its own oldest message, never another peer's.

    Args:
        max_pending: most unfinished messages held at once; the oldest is evicted.
        max_bytes: most bytes held in unfinished messages; the oldest are evicted.
        timeout: [s] an unfinished message older than this is dropped.
        max_message: [bytes] largest whole message accepted (per direction: a server
            takes requests of at most ``codec.MAX_REQUEST_BYTES``).
        max_pending_per_peer: most unfinished messages of one peer.
        max_bytes_per_peer: most unfinished bytes of one peer (default: one largest
            message).
        versions: the protocol versions accepted (a server speaks older ones too).
    """

    def __init__(
        self,
        max_pending: int = 32,
        max_bytes: int = 16 * 1024 * 1024,
        timeout: float = 2.0,
        *,
        max_message: int = MAX_MESSAGE_BYTES,
        max_pending_per_peer: int = 4,
        max_bytes_per_peer: int | None = None,
        versions: tuple[int, ...] = (PROTOCOL_VERSION,),
    ):
        self.versions = versions
        self.max_pending = max_pending
        self.max_bytes = max_bytes
        self.timeout = timeout
        self.max_message = max_message
        self.max_pending_per_peer = max_pending_per_peer
        self.max_bytes_per_peer = max_message if max_bytes_per_peer is None else max_bytes_per_peer
        self._pending: OrderedDict[tuple[Hashable, int], _Partial] = OrderedDict()
        self._bytes = 0
        self._peer_bytes: dict[Hashable, int] = {}
        self._peer_count: dict[Hashable, int] = {}
        self.evicted = 0  # unfinished messages dropped for limits or age

    @property
    def pending(self) -> int:
        """Unfinished messages held."""
        return len(self._pending)

    @property
    def pending_bytes(self) -> int:
        """Bytes held in unfinished messages."""
        return self._bytes

    def feed(self, datagram: bytes, peer: Hashable, now: float) -> bytes | None:
        """Take one datagram.

        Args:
            datagram: the raw datagram, header included (a seal already removed).
            peer: who sent it (the socket address).
            now: [s] a monotonic clock reading, for expiry.

        Returns:
            The whole message once its last fragment arrives, else None.

        Raises:
            DecodeError, VersionError, FragmentError, LimitError: as
            :func:`parse_header`, or on a fragment inconsistent with its message.
        """
        msg_id, index, count, total = parse_header(datagram, self.max_message, self.versions)
        version = datagram[2]
        if count == 1:
            return datagram[HEADER_BYTES : HEADER_BYTES + total]
        self._expire(now)
        key = (peer, msg_id)
        part = self._pending.get(key)
        if part is None:
            part = _Partial(count, total, version, now)
            self._pending[key] = part
            self._peer_count[peer] = self._peer_count.get(peer, 0) + 1
        elif part.count != count or part.total != total or part.version != version:
            self._drop(key)
            raise FragmentError(f"fragment {index} of message {msg_id} changes its count, length or version")
        body = datagram[HEADER_BYTES:]
        held = part.parts.get(index)
        if held is not None:
            if len(held) != len(body):
                self._drop(key)
                raise FragmentError(f"fragment {index} of message {msg_id} repeated with another length")
            return None
        part.parts[index] = body
        part.size += len(body)
        self._bytes += len(body)
        self._peer_bytes[peer] = self._peer_bytes.get(peer, 0) + len(body)
        if part.size > part.total:
            self._drop(key)
            raise FragmentError(f"message {msg_id}: fragments hold more than its {total} bytes")
        if len(part.parts) == count:
            self._drop(key)
            return self._join(part, msg_id)
        self._enforce_limits(keep=key)
        return None

    def _join(self, part: _Partial, msg_id: int) -> bytes:
        chunk = len(part.parts[0])
        last = part.total - chunk * (part.count - 1)
        for i in range(part.count - 1):
            if len(part.parts[i]) != chunk:
                raise FragmentError(f"message {msg_id}: fragment {i} has {len(part.parts[i])} bytes, not {chunk}")
        if len(part.parts[part.count - 1]) != last:
            raise FragmentError(f"message {msg_id}: last fragment does not complete {part.total} bytes")
        return b"".join(part.parts[i] for i in range(part.count))

    def _drop(self, key: tuple[Hashable, int]) -> None:
        part = self._pending.pop(key, None)
        if part is None:
            return
        peer = key[0]
        self._bytes -= part.size
        left = self._peer_bytes.get(peer, 0) - part.size
        count = self._peer_count.get(peer, 0) - 1
        if count <= 0:
            self._peer_bytes.pop(peer, None)
            self._peer_count.pop(peer, None)
        else:
            self._peer_bytes[peer], self._peer_count[peer] = left, count

    def _expire(self, now: float) -> None:
        while self._pending:
            key, part = next(iter(self._pending.items()))
            if now - part.started <= self.timeout:
                break
            self._drop(key)
            self.evicted += 1

    def _enforce_limits(self, keep: tuple[Hashable, int]) -> None:
        peer = keep[0]
        while self._peer_count.get(peer, 0) > self.max_pending_per_peer or self._peer_bytes.get(peer, 0) > self.max_bytes_per_peer:
            # A peer over its own caps loses one of its own messages: the one with
            # the fewest fragments (a late duplicate of a finished message has one),
            # the oldest among those; never the one this fragment belongs to.
            mine = (k for k in self._pending if k[0] == peer and k != keep)
            victim = min(mine, key=lambda k: len(self._pending[k].parts), default=None)
            self._drop(victim or keep)
            self.evicted += 1
            if victim is None:
                raise LimitError(f"unfinished message exceeds {self.max_bytes_per_peer} bytes for one peer")
        while len(self._pending) > self.max_pending or self._bytes > self.max_bytes:
            key = next(iter(self._pending))
            if key == keep and len(self._pending) == 1:
                # One message alone over the byte cap can never complete.
                self._drop(key)
                self.evicted += 1
                raise LimitError(f"unfinished message exceeds {self.max_bytes} bytes")
            if key == keep:
                self._pending.move_to_end(key)
                continue
            self._drop(key)
            self.evicted += 1
