"""Datagram framing: a fixed header, fragmentation and reassembly.

Every datagram starts with a 16-byte big-endian header::

    magic   2s  b"VC"
    version u8  PROTOCOL_VERSION
    flags   u8  0 (reserved)
    msg_id  u32 sender's message counter; fragments of one message share it
    index   u16 this fragment's index, 0..count-1
    count   u16 fragments in the message, 1..MAX_FRAGMENTS
    total   u32 whole message length in bytes

followed by the fragment's bytes. All fragments but the last carry the same number
of bytes; the last carries the rest. A message that fits is one fragment.
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
    "fragment",
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


def fragment(payload: bytes, msg_id: int, max_datagram: int = DEFAULT_DATAGRAM) -> list[bytes]:
    """Split one encoded message into datagrams.

    Args:
        payload: the encoded message.
        msg_id: the sender's message counter (wraps at 2**32).
        max_datagram: largest datagram to produce [bytes], header included.

    Raises:
        LimitError: if the message is too long for the fragment count or size limit.
    """
    if not MIN_DATAGRAM <= max_datagram <= MAX_DATAGRAM:
        raise LimitError(f"max_datagram {max_datagram} outside [{MIN_DATAGRAM}, {MAX_DATAGRAM}]")
    total = len(payload)
    if total > MAX_MESSAGE_BYTES:
        raise LimitError(f"message of {total} bytes exceeds {MAX_MESSAGE_BYTES}")
    msg_id &= 0xFFFFFFFF
    chunk = max_datagram - HEADER_BYTES
    if total <= chunk:
        return [HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, 0, 1, total) + payload]
    count = -(-total // chunk)
    if count > MAX_FRAGMENTS:
        raise LimitError(f"message needs {count} fragments, more than {MAX_FRAGMENTS}")
    view = memoryview(payload)
    return [
        HEADER.pack(MAGIC, PROTOCOL_VERSION, 0, msg_id, i, count, total)
        + view[i * chunk : (i + 1) * chunk]
        for i in range(count)
    ]


def parse_header(datagram: bytes) -> tuple[int, int, int, int]:
    """Check a datagram's header.

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
    magic, version, _flags, msg_id, index, count, total = HEADER.unpack_from(datagram)
    if magic != MAGIC:
        raise DecodeError(f"bad magic {magic!r}")
    if version != PROTOCOL_VERSION:
        raise VersionError(f"protocol version {version}, this side speaks {PROTOCOL_VERSION}")
    if count == 0 or index >= count:
        raise FragmentError(f"fragment index {index} of count {count}")
    if total > MAX_MESSAGE_BYTES:
        raise LimitError(f"declared message length {total} exceeds {MAX_MESSAGE_BYTES}")
    body = len(datagram) - HEADER_BYTES
    if count == 1 and body != total:
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
    started: float  # [s] monotonic time of the first fragment
    parts: dict[int, bytes] = field(default_factory=dict)
    size: int = 0  # [bytes] held so far


class Reassembler:
    """Puts fragments back together, within bounds on count, bytes and age.

    Keys are ``(peer, msg_id)``, so two peers never mix their fragments. A repeated
    fragment with identical length is ignored (a retransmission); a repeated one of
    another length, or one whose count/total disagree with its message, drops the
    whole assembly and raises :class:`FragmentError`.

    Args:
        max_pending: most unfinished messages held at once; the oldest is evicted.
        max_bytes: most bytes held in unfinished messages; the oldest are evicted.
        timeout: [s] an unfinished message older than this is dropped.
    """

    def __init__(self, max_pending: int = 32, max_bytes: int = 16 * 1024 * 1024, timeout: float = 2.0):
        self.max_pending = max_pending
        self.max_bytes = max_bytes
        self.timeout = timeout
        self._pending: OrderedDict[tuple[Hashable, int], _Partial] = OrderedDict()
        self._bytes = 0
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
            datagram: the raw datagram, header included.
            peer: who sent it (the socket address).
            now: [s] a monotonic clock reading, for expiry.

        Returns:
            The whole message once its last fragment arrives, else None.

        Raises:
            DecodeError, VersionError, FragmentError, LimitError: as
            :func:`parse_header`, or on a fragment inconsistent with its message.
        """
        msg_id, index, count, total = parse_header(datagram)
        if count == 1:
            return datagram[HEADER_BYTES:]
        self._expire(now)
        key = (peer, msg_id)
        part = self._pending.get(key)
        if part is None:
            part = _Partial(count, total, now)
            self._pending[key] = part
        elif part.count != count or part.total != total:
            self._drop(key)
            raise FragmentError(f"fragment {index} of message {msg_id} changes its count or length")
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
        if part is not None:
            self._bytes -= part.size

    def _expire(self, now: float) -> None:
        while self._pending:
            key, part = next(iter(self._pending.items()))
            if now - part.started <= self.timeout:
                break
            self._drop(key)
            self.evicted += 1

    def _enforce_limits(self, keep: tuple[Hashable, int]) -> None:
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

