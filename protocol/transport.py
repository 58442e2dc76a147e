"""Whole messages over one UDP socket: encode, fragment, seal, send; receive, open, reassemble, decode.

What a receiver spends on an untrusted datagram is bounded before it spends it: a
sealed datagram is opened first (with a key: :mod:`protocol.auth`); fragments wait in a
:class:`~protocol.fragment.Reassembler` bounded per peer and per direction; a
whole message's structure is scanned (:func:`protocol.codec.scan`) and its object
count charged to a decode budget before msgpack allocates anything: the live
session's address has a budget of its own, every other source shares one.
"""

from __future__ import annotations

import ipaddress
import socket
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Collection, Hashable
from dataclasses import dataclass
from typing import Any

from protocol.auth import TRAILER_BYTES, Channel, ClientKeys, ServerKeys
from protocol.codec import MAX_MESSAGE_BYTES, MAX_OBJECTS, MAX_REQUEST_BYTES, decode, encode
from protocol.errors import AuthError, LimitError, ProtocolError
from protocol.faults import FaultConfig, FaultySender
from protocol.fragment import (
    DEFAULT_DATAGRAM,
    FLAG_HANDSHAKE,
    FLAG_MAC,
    HEADER_BYTES,
    MAX_DATAGRAM,
    Reassembler,
    fragment,
    pad,
)
from protocol.messages import KEYED_VERSION, PROTOCOL_VERSION

__all__ = ["Endpoint", "Received", "DecodeBudget", "SOCKET_BUFFER_BYTES", "is_loopback"]

SOCKET_BUFFER_BYTES = 4 * 1024 * 1024  # [bytes] room for a few full-size images in flight
DECODE_RATE = 4 * MAX_OBJECTS  # [objects/s] one budget (~60 ms of CPU a second)
DECODE_BURST = 2 * MAX_OBJECTS  # [objects] its bucket: two of the largest messages at once
MAX_BUDGET_PEERS = 1024  # peers whose budgets are remembered
OTHERS = "others"  # the one budget every source but the live session's address shares
# [bytes/s] what every source but the live session's address may make a server read
# past the socket, together: four of the largest requests a second (bursts of two).
OTHERS_BYTE_RATE = 4 * MAX_REQUEST_BYTES
OTHERS_BYTE_BURST = 2 * MAX_REQUEST_BYTES

Address = Any  # (host, port) as the socket module gives it


def is_loopback(host: str) -> bool:
    """Whether every address ``host`` resolves to is a loopback one (127.0.0.0/8, ::1).

    A name is resolved, not read: "127.example.com" may point anywhere. A name that does
    not resolve is not loopback.
    """
    try:
        infos = socket.getaddrinfo(host, None, proto=socket.IPPROTO_UDP)
    except (socket.gaierror, UnicodeError, ValueError):
        return False
    return bool(infos) and all(ipaddress.ip_address(str(info[4][0]).split("%")[0]).is_loopback for info in infos)


@dataclass
class Received:
    """One received datagram's outcome: a whole message, a rejection, or neither yet.

    ``size`` is what the sender spent on it [bytes]: the datagram, or for a
    fragmented message its whole length with a header; a reply to an
    unauthenticated peer must not be larger. ``version`` is the protocol version
    of its header. ``bad_message`` marks an error in a whole message's content
    (not msgpack, over a limit inside it, wrong fields or types): the sender
    meant a message and may be told what was wrong with it.
    """

    addr: Address
    msg: dict[str, Any] | None = None
    error: ProtocolError | None = None
    size: int = 0
    version: int = PROTOCOL_VERSION
    bad_message: bool = False
    sealer: Any = None  # with a key: what seals the answer (a session's channel, or a hello's fresh keys)


class DecodeBudget:
    """A token bucket of msgpack objects per peer, so one source cannot keep the
    decoder busy with messages that are each within the limits."""

    def __init__(self, rate: float = DECODE_RATE, burst: float = DECODE_BURST, max_peers: int = MAX_BUDGET_PEERS):
        self.rate, self.burst, self.max_peers = rate, burst, max_peers
        self._peers: OrderedDict[Hashable, tuple[float, float]] = OrderedDict()

    def charge(self, peer: Hashable, objects: int, now: float) -> None:
        """Take ``objects`` from ``peer``'s bucket.

        Raises:
            LimitError: if the bucket holds fewer (nothing is taken).
        """
        tokens, last = self._peers.pop(peer, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate)
        if objects > tokens:
            self._peers[peer] = (tokens, now)
            raise LimitError(f"peer {peer} is over its decode budget of {self.rate:.0f} objects/s")
        self._peers[peer] = (tokens - objects, now)
        if len(self._peers) > self.max_peers:
            self._peers.popitem(last=False)


class Endpoint:
    """A UDP socket that speaks whole messages.

    Args:
        sock: a bound (server) or unbound (client) UDP socket; the endpoint owns it.
        max_datagram: largest datagram sent [bytes], seal included.
        faults: optional fault injection on sends.
        reassembler: where fragments wait; a default bounded one if None.
        key: shared key: seal every datagram sent, accept only sealed ones.
        max_message: [bytes] largest whole message accepted (a server takes
            requests of at most ``codec.MAX_REQUEST_BYTES``).
        peer: accept datagrams from this address only (a client's server).
        versions: protocol versions accepted without a key (a server's
            ``SUPPORTED_VERSIONS``); with one, only ``KEYED_VERSION``.
        sessions: with a key, the server's side: the channel and address of a
            session by its sid (None: this is a client).
        live_peers: the addresses of the sessions that hold the world (a platoon's
            seats): their messages are charged to decode budgets of their own.
    """

    def __init__(
        self,
        sock: socket.socket,
        *,
        max_datagram: int = DEFAULT_DATAGRAM,
        faults: FaultConfig | None = None,
        reassembler: Reassembler | None = None,
        key: bytes | None = None,
        max_message: int = MAX_MESSAGE_BYTES,
        peer: Address | None = None,
        versions: tuple[int, ...] = (PROTOCOL_VERSION,),
        sessions: Callable[[bytes], tuple[Channel, Any] | None] | None = None,
        live_peers: Callable[[], Collection[Address]] = lambda: (),
    ):
        self.sock = sock
        for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, SOCKET_BUFFER_BYTES)
            except OSError:
                pass  # the OS keeps its own cap; a smaller buffer only means more loss
        self.max_datagram = max_datagram
        if key is not None:
            versions = (KEYED_VERSION,)
        self.version = versions[-1]  # what this side's own messages carry
        self.reassembler = reassembler or Reassembler(max_message=max_message, versions=versions)
        self.keys: ClientKeys | ServerKeys | None = None
        if key is not None:
            self.keys = ClientKeys(key) if sessions is None else ServerKeys(key, sessions)
        self.reply_sealer: Any = None  # a server's: what seals answers to the datagram just received
        self.peer = peer
        self.live_peers = live_peers
        self.budget = DecodeBudget()
        self.others = DecodeBudget(rate=OTHERS_BYTE_RATE, burst=OTHERS_BYTE_BURST, max_peers=1)
        self._sender = FaultySender(sock, faults) if faults and faults.active else None
        self._msg_id = 0
        self.rejected: Counter[str] = Counter()  # reason -> datagrams dropped

    @property
    def authenticated(self) -> bool:
        """True when every datagram is sealed (keyed sessions)."""
        return self.keys is not None

    def establish(self, token: bytes) -> None:
        """A keyed client: seal with the session whose welcome carried ``token``."""
        assert isinstance(self.keys, ClientKeys)
        self.keys.establish(token)

    def close(self) -> None:
        """Close the socket; safe to call twice."""
        self.sock.close()

    def pack(self, msg: dict[str, Any], *, pad_to: int = 0, version: int | None = None, max_datagram: int | None = None) -> list[bytes]:
        """Encode and fragment a message into datagrams, ready to (re)send.

        The datagrams are sealed (with a key) only when sent, so that every
        transmission carries a fresh sequence number. ``pad_to`` pads a
        single-fragment message to that many bytes on the wire. Message ids
        count from 1; a re-send reuses its datagrams, so its id too. A keyed
        client's hello starts a new handshake (a fresh nonce). ``max_datagram``
        overrides :attr:`max_datagram` (a platoon server's seats each chose theirs).
        """
        self._msg_id = (self._msg_id + 1) & 0xFFFFFFFF
        version = self.version if version is None else version
        max_datagram = self.max_datagram if max_datagram is None else max_datagram
        if self.keys is None:
            datagrams = fragment(encode(msg), self._msg_id, max_datagram, version=version)
        else:
            flags = FLAG_MAC
            if isinstance(self.keys, ClientKeys) and msg["type"] == "hello":
                self.keys.begin()
                flags |= FLAG_HANDSHAKE
            datagrams = fragment(encode(msg), self._msg_id, max_datagram, flags=flags, trailer=TRAILER_BYTES, version=version)
        if pad_to and len(datagrams) == 1:
            datagrams = [pad(datagrams[0], pad_to - (TRAILER_BYTES if self.keys else 0))]
        return datagrams

    def wire_size(self, datagrams: list[bytes]) -> int:
        """Bytes these datagrams take on the wire, seals included."""
        return sum(len(d) for d in datagrams) + (TRAILER_BYTES * len(datagrams) if self.keys else 0)

    def seal(self, datagram: bytes, sealer: Any = None) -> bytes:
        """The datagram as it goes on the wire: sealed with a fresh sequence number (with a key).

        ``sealer`` is a server's choice (a session's channel, a hello's keys);
        by default a server seals in the channel of the datagram just received.
        """
        if self.keys is None:
            return datagram
        sealer = sealer or (self.keys if isinstance(self.keys, ClientKeys) else self.reply_sealer)
        if sealer is None:
            raise AuthError("nothing to seal an answer with: the request was not sealed")
        return sealer.seal(datagram)

    def send_datagrams(self, datagrams: list[bytes], addr: Address, sealer: Any = None) -> None:
        """Send packed datagrams (a fresh reply or a cached one), sealing each (see :meth:`seal`)."""
        if self.keys is not None:
            try:
                datagrams = [self.seal(d, sealer) for d in datagrams]
            except AuthError:
                self.rejected["unsealable_answer"] += 1  # never answer what did not open
                return
        if self._sender is not None:
            for d in datagrams:
                self._sender.sendto(d, addr)
            return
        for d in datagrams:
            try:
                self.sock.sendto(d, addr)
            except OSError:
                pass  # a full send buffer is a loss; the peer's retry covers it

    def send(self, msg: dict[str, Any], addr: Address, version: int | None = None) -> list[bytes]:
        """Send one message; returns its datagrams for a reply cache."""
        datagrams = self.pack(msg, version=version)
        self.send_datagrams(datagrams, addr)
        return datagrams

    def receive(self, timeout: float | None) -> Received | None:
        """Wait up to ``timeout`` seconds for one datagram.

        Returns:
            None on timeout; else a :class:`Received` with a whole message, a
            rejection (counted in :attr:`rejected` by reason), or neither while a
            fragmented message is incomplete or the datagram came from a foreign
            address.
        """
        sender = self._sender
        if sender is not None:
            sender.flush()
            due = sender.next_due()
            if due is not None:
                # Wake up in time to release a delayed datagram.
                wait = max(0.0, due - time.monotonic())
                timeout = wait if timeout is None else min(timeout, wait)
        self.sock.settimeout(timeout)
        try:
            datagram, addr = self.sock.recvfrom(MAX_DATAGRAM + 1)
        except (TimeoutError, BlockingIOError):
            return None
        except ConnectionError:
            # Linux reports an ICMP port-unreachable from an earlier send here.
            return Received(addr=None)
        if self.peer is not None and addr[:2] != self.peer[:2]:  # IPv6 adds flow info and scope
            self.rejected["foreign_peer"] += 1
            return Received(addr=None)
        size = len(datagram)
        whole = over_budget = False
        sealer = self.reply_sealer = None
        live = self.peer is not None or addr in self.live_peers()
        if not live:
            # A server: strangers share one byte budget, checked before any work on their
            # datagrams, so that many of them together cannot starve the live session.
            try:
                self.others.charge(OTHERS, size, time.monotonic())
            except LimitError:
                self.rejected["others_over_budget"] += 1
                return Received(addr=None)

        def charge(objects: int) -> None:
            nonlocal over_budget
            over_budget = True  # until the budget has paid for it
            # The live session is never starved by other sources: they share one budget.
            self.budget.charge(addr if live and self.peer is None else OTHERS, objects, now)
            over_budget = False

        try:
            if isinstance(self.keys, ServerKeys):
                datagram, sealer = self.keys.open(datagram, addr)
                self.reply_sealer = sealer
            elif self.keys is not None:
                datagram = self.keys.open(datagram)
            elif len(datagram) > 3 and datagram[3] & FLAG_MAC:
                raise AuthError("datagram carries a MAC but this side has no key")
            now = time.monotonic()
            payload = self.reassembler.feed(datagram, addr, now)
            if payload is None:
                return Received(addr, size=size)
            whole, version = True, datagram[2]
            size = max(size, len(payload) + HEADER_BYTES)
            msg = decode(payload, check=charge, version=version)
            return Received(addr, msg=msg, size=size, version=version, sealer=sealer)
        except ProtocolError as exc:
            self.rejected[type(exc).__name__] += 1
            return Received(addr, error=exc, size=size, bad_message=whole and not over_budget, sealer=sealer)
