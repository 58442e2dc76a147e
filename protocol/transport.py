"""Whole messages over one UDP socket: encode, fragment, send; receive, reassemble, decode."""

from __future__ import annotations

import socket
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

from protocol.codec import decode, encode
from protocol.errors import ProtocolError
from protocol.faults import FaultConfig, FaultySender
from protocol.fragment import DEFAULT_DATAGRAM, MAX_DATAGRAM, Reassembler, fragment

__all__ = ["Endpoint", "Received", "SOCKET_BUFFER_BYTES"]

SOCKET_BUFFER_BYTES = 4 * 1024 * 1024  # [bytes] room for a few full-size images in flight

Address = Any  # (host, port) as the socket module gives it


@dataclass
class Received:
    """One received datagram's outcome: a whole message, a rejection, or neither yet."""

    addr: Address
    msg: dict[str, Any] | None = None
    error: ProtocolError | None = None


class Endpoint:
    """A UDP socket that speaks whole messages.

    Args:
        sock: a bound (server) or unbound (client) UDP socket; the endpoint owns it.
        max_datagram: largest datagram sent [bytes].
        faults: optional fault injection on sends.
        reassembler: where fragments wait; a default bounded one if None.
    """

    def __init__(
        self,
        sock: socket.socket,
        *,
        max_datagram: int = DEFAULT_DATAGRAM,
        faults: FaultConfig | None = None,
        reassembler: Reassembler | None = None,
    ):
        self.sock = sock
        for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, opt, SOCKET_BUFFER_BYTES)
            except OSError:
                pass  # the OS keeps its own cap; a smaller buffer only means more loss
        self.max_datagram = max_datagram
        self.reassembler = reassembler or Reassembler()
        self._sender = FaultySender(sock, faults) if faults and faults.active else None
        self._msg_id = 0
        self.rejected: Counter[str] = Counter()  # reason -> datagrams dropped

    def close(self) -> None:
        """Close the socket; safe to call twice."""
        self.sock.close()

    def pack(self, msg: dict[str, Any]) -> list[bytes]:
        """Encode and fragment a message into datagrams, ready to (re)send."""
        self._msg_id = (self._msg_id + 1) & 0xFFFFFFFF
        return fragment(encode(msg), self._msg_id, self.max_datagram)

    def send_datagrams(self, datagrams: list[bytes], addr: Address) -> None:
        """Send pre-packed datagrams (a fresh reply or a cached one)."""
        if self._sender is not None:
            for d in datagrams:
                self._sender.sendto(d, addr)
            return
        for d in datagrams:
            try:
                self.sock.sendto(d, addr)
            except OSError:
                pass  # a full send buffer is a loss; the peer's retry covers it

    def send(self, msg: dict[str, Any], addr: Address) -> list[bytes]:
        """Send one message; returns its datagrams for a reply cache."""
        datagrams = self.pack(msg)
        self.send_datagrams(datagrams, addr)
        return datagrams

    def receive(self, timeout: float | None) -> Received | None:
        """Wait up to ``timeout`` seconds for one datagram.

        Returns:
            None on timeout; else a :class:`Received` with a whole message, a
            rejection (counted in :attr:`rejected` by reason), or neither while a
            fragmented message is incomplete.
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
        try:
            payload = self.reassembler.feed(datagram, addr, time.monotonic())
            if payload is None:
                return Received(addr)
            return Received(addr, msg=decode(payload))
        except ProtocolError as exc:
            self.rejected[type(exc).__name__] += 1
            return Received(addr, error=exc)
