"""Seeded fault injection on the sending side of a UDP socket.

Either side can wrap its sends to drop, duplicate, reorder or truncate datagrams at
given rates, so the lockstep rules can be tested on the real processes. The fault
stream has its own seed and never touches simulation randomness: with the same
world seed and actions, a run is bit-identical whatever the faults.
"""

from __future__ import annotations

import heapq
import socket
import time
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

__all__ = ["FaultConfig", "FaultySender"]


@dataclass(frozen=True)
class FaultConfig:
    """Rates of each fault, per datagram sent."""

    drop: float = 0.0  # probability a datagram is not sent
    dup: float = 0.0  # probability it is sent twice
    reorder: float = 0.0  # probability it is held back and sent after the next one
    truncate: float = 0.0  # probability it loses a random tail
    delay: float = 0.0  # probability it is held back for up to delay_s
    delay_s: float = 0.05  # [s] longest delay
    seed: int = 0  # seed of the fault stream

    def __post_init__(self) -> None:
        if not 0.0 <= self.delay_s <= 10.0:
            raise ValueError(f"fault delay_s={self.delay_s} is outside [0, 10] s")
        for f in fields(self):
            if f.name not in ("seed", "delay_s") and not 0.0 <= getattr(self, f.name) <= 1.0:
                raise ValueError(f"fault rate {f.name}={getattr(self, f.name)} is outside [0, 1]")

    @property
    def active(self) -> bool:
        return any((self.drop, self.dup, self.reorder, self.truncate, self.delay))

    @classmethod
    def parse(cls, spec: str) -> FaultConfig:
        """Parse ``"drop=0.1,dup=0.05,reorder=0.05,truncate=0,delay=0.1,delay_s=0.05,seed=3"``.

        Raises:
            ValueError: naming the bad item.
        """
        values: dict[str, float | int] = {}
        names = {f.name for f in fields(cls)}
        for item in filter(None, (part.strip() for part in spec.split(","))):
            key, sep, raw = item.partition("=")
            if not sep or key not in names:
                raise ValueError(f"bad fault item {item!r}: expected one of {sorted(names)} as NAME=VALUE")
            try:
                values[key] = int(raw) if key == "seed" else float(raw)
            except ValueError:
                raise ValueError(f"bad fault item {item!r}: {raw!r} is not a number") from None
        return cls(**values)  # type: ignore[arg-type]


class FaultySender:
    """Sends datagrams through ``sock``, injecting the faults of ``config``."""

    def __init__(self, sock: socket.socket, config: FaultConfig):
        self.sock = sock
        self.config = config
        self.rng = np.random.default_rng(config.seed)
        self._held: list[tuple[bytes, Any]] = []
        self._delayed: list[tuple[float, int, bytes, Any]] = []  # heap of (due [s], seq, data, addr)
        self._seq = 0
        self.counts = {"sent": 0, "dropped": 0, "duplicated": 0, "reordered": 0, "truncated": 0, "delayed": 0}

    def next_due(self) -> float | None:
        """Monotonic time [s] the next delayed datagram is due, if any."""
        return self._delayed[0][0] if self._delayed else None

    def flush(self) -> None:
        """Send the delayed datagrams whose time has come."""
        now = time.monotonic()
        while self._delayed and self._delayed[0][0] <= now:
            _, _, data, addr = heapq.heappop(self._delayed)
            self._send(data, addr)

    def sendto(self, data: bytes, addr: Any) -> None:
        c = self.config
        self.flush()
        roll = self.rng.random(5)
        if roll[4] < c.delay:
            self._seq += 1
            due = time.monotonic() + float(self.rng.uniform(0.0, c.delay_s))
            heapq.heappush(self._delayed, (due, self._seq, data, addr))
            self.counts["delayed"] += 1
        elif roll[0] < c.drop:
            self.counts["dropped"] += 1
        else:
            if roll[3] < c.truncate and len(data) > 1:
                data = data[: int(self.rng.integers(1, len(data)))]
                self.counts["truncated"] += 1
            if roll[2] < c.reorder:
                self._held.append((data, addr))
                self.counts["reordered"] += 1
                return
            self._send(data, addr)
            if roll[1] < c.dup:
                self._send(data, addr)
                self.counts["duplicated"] += 1
        # A held datagram goes out after the next one, so it arrives late, not never.
        held, self._held = self._held, []
        for item in held:
            self._send(*item)

    def _send(self, data: bytes, addr: Any) -> None:
        self.counts["sent"] += 1
        try:
            self.sock.sendto(data, addr)
        except OSError:
            pass  # a full buffer is just another loss
