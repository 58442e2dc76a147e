"""The simulator server: one world, one session at a time, lockstep over UDP.

A platoon server (``followers`` > 0) holds one session per follower, its *seat*, and
steps them together (:mod:`sim_server.seats`); everything below holds per seat.

The server owns time. It advances exactly one control period per ``step`` it
receives and answers with the observation of the new frame. A repeated request
(the client re-sends after a timeout) is answered from a cache, never simulated
twice, so lost, duplicated or reordered datagrams cannot change a run.

With a pre-shared key (``--key-file``) every datagram is sealed and opened before it
is even reassembled (:mod:`protocol.auth`): a hello opens a *pending* handshake with
keys of its own, which becomes the session holding the world only when its first
request opens under those keys, so a replayed hello holds nothing. Datagrams that
fail are counted and never answered. Without a key, a datagram outside the current
session is never answered with more bytes than it carried.

A session ends on ``close``, on its timeout, and when one of its own requests
(its token, from its address) is answered with a fatal error; nothing else,
so no datagram without the token can end it. A client at version 2 is answered
in version 2.
"""

from __future__ import annotations

import math
import os
import socket
import sys
import time
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocol import messages as m
from protocol.auth import Channel, SessionKeys
from protocol.codec import MAX_REQUEST_BYTES, MAX_STR_LEN
from protocol.errors import ProtocolError, VersionError
from protocol.faults import FaultConfig
from protocol.fragment import DEFAULT_DATAGRAM, HELLO_BYTES, MAX_DATAGRAM, MIN_DATAGRAM
from protocol.messages import ErrorCode
from protocol.transport import DecodeBudget, Endpoint, Received
from sim_server.errors import SimError
from sim_server.seats import JOIN_TIMEOUT, SEAT_TIMEOUT, PlatoonLockstep, SeatReset, where
from sim_server.world import World, WorldConfig, WorldState


class _Stopped(Exception):
    """Raised by :meth:`SimServer.stop` into a blocked receive (a retried syscall never returns early)."""


__all__ = ["ServerConfig", "SimServer", "BAD_MESSAGE_RATE"]

# Answers to malformed messages, per source: never larger than the message, and
# at most this many a second (bursts as large), so a flood costs few sends.
BAD_MESSAGE_RATE = 50.0  # [replies/s]
# Keyed handshakes that have not sent their first request yet hold no world; at most
# this many wait, each at most this long (a replayed hello costs one entry, briefly).
HANDSHAKE_TIMEOUT = 2.0  # [s]
MAX_PENDING = 64
MAX_LOST = 64  # platoon seats remembered after a give-up, to tell each why when it asks
HELLO_MEMORY = 4096  # client nonces remembered with their address: a hello seen from another address is a replay

@dataclass(frozen=True)
class ServerConfig:
    """Settings of a simulator server."""

    host: str = "127.0.0.1"
    port: int = 47800  # 0 picks a free port
    seed: int = 0  # salts every episode seed
    realtime: bool = False  # pace replies to the wall clock (a human at the wheel)
    session_timeout: float = 10.0  # [s] idle time before a session is freed
    world: WorldConfig = field(default_factory=WorldConfig)
    faults: FaultConfig | None = None  # inject faults on the server's sends
    max_datagram: int = DEFAULT_DATAGRAM  # [bytes] cap on what the server sends
    parent_pid: int | None = None  # exit when this process is no longer our parent
    key: bytes | None = field(default=None, repr=False)  # shared key: seal and check every datagram
    followers: int = 0  # 0: one car; 1..16: a platoon, one seat (session) per follower
    seat_timeout: float = SEAT_TIMEOUT  # [s] a platoon's wait for a seat's action
    join_timeout: float = JOIN_TIMEOUT  # [s] a platoon's wait for every seat's reset


@dataclass
class _Session:
    token: bytes
    addr: Any
    version: int  # the client's protocol version: every reply is in it
    nonce: bytes
    welcome: list[bytes]  # cached welcome datagrams
    image_format: str
    image_size: tuple[int, int]  # (width, height) [px]
    last_seen: float  # [s] monotonic
    episode: int = -1
    frame: int = 0
    state: WorldState | None = None
    reset_reply: list[bytes] = field(default_factory=list)
    step_reply: list[bytes] = field(default_factory=list)  # reply to step(frame - 1)
    wall_start: float = 0.0  # [s] realtime pacing origin
    renderer: Any = None
    max_datagram: int = DEFAULT_DATAGRAM  # [bytes] what the server sends this client
    keys: SessionKeys | None = None  # keyed: what both sides derived from the nonces
    channel: Channel | None = None  # keyed: the server's seals of this session
    seat: int = 0  # a platoon's seat (0 nearest the lead); 0 for one car
    asked: SeatReset | None = None  # platoon: this seat's reset, waiting for the other seats
    action: float | None = None  # platoon: this seat's action for the platoon's current frame
    start: int = 0  # platoon: this seat's first frame (-its pre-roll)
    pending_episode: int = -1  # platoon: the episode started, answered when the platoon reaches `start`
    lost: str = ""  # platoon: why the platoon gave up, told to every later request


class SimServer:
    """A UDP simulator server. Use as a context manager, then :meth:`serve`."""

    def __init__(self, config: ServerConfig):
        self.config = config
        sock = socket.socket(socket.AF_INET6 if ":" in config.host else socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind((config.host, config.port))
        self.endpoint = Endpoint(
            sock, max_datagram=config.max_datagram, faults=config.faults, key=config.key, max_message=MAX_REQUEST_BYTES,
            versions=m.SUPPORTED_VERSIONS, sessions=self._lookup, live_peers=self._live_peers,
        )  # fmt: skip
        self.address = sock.getsockname()[:2]
        self.world = World(config.world, salt=config.seed)
        self.platoon = None if not config.followers else PlatoonLockstep(
            config.followers, config.world, config.seed, config.seat_timeout, config.join_timeout)  # fmt: skip
        self.seats: list[_Session | None] = [None] * max(1, config.followers)
        self.lost: OrderedDict[bytes, _Session] = OrderedDict()  # platoon: sessions of a given-up platoon, by token
        self.pending: OrderedDict[bytes, _Session] = OrderedDict()  # keyed handshakes by sid, oldest first
        self._hellos: OrderedDict[bytes, Any] = OrderedDict()  # keyed: client nonce -> the address it came from
        self.stats: Counter[str] = Counter()
        self._bad_replies = DecodeBudget(rate=BAD_MESSAGE_RATE, burst=BAD_MESSAGE_RATE)
        self._stopped = False  # set by stop(), even before serve() starts
        self._waiting = False  # serve() is blocked in a receive

    @property
    def session(self) -> _Session | None:
        """The session holding the world (a platoon's: seat 0's)."""
        return self.seats[0]

    def __enter__(self) -> SimServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the socket; safe to call twice."""
        self.endpoint.close()

    def stop(self) -> None:
        """Ask :meth:`serve` to return after the current datagram, or at once while it waits
        for one, so a reaper's SIGTERM waits for no receive timeout. Call it from the serving
        thread: a signal handler (it may raise into the wait) or the loop itself."""
        self._stopped = True
        if self._waiting:
            raise _Stopped

    def stats_line(self) -> str:
        """Counters of served and rejected datagrams, for the log at close."""
        counts = self.stats + Counter({f"rejected.{k}": v for k, v in self.endpoint.rejected.items()})
        counts["reassembly_evicted"] = self.endpoint.reassembler.evicted
        return " ".join(f"{k}={v}" for k, v in sorted(counts.items())) or "idle"

    def serve(self, max_seconds: float | None = None) -> None:
        """Answer requests until :meth:`stop` or ``max_seconds`` have passed."""
        deadline = None if max_seconds is None else time.monotonic() + max_seconds
        while not self._stopped:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            self._expire(now)
            if self.config.parent_pid is not None and os.getppid() != self.config.parent_pid:
                # The client that spawned us died (even by kill -9): don't linger.
                print("vacc-server: parent process gone, exiting", file=sys.stderr)
                break
            self._waiting = True
            try:
                wait = 0.5 if deadline is None else min(0.5, deadline - now)
                if self.platoon is not None and self.platoon.nudge_at is not None:
                    wait = max(0.0, min(wait, self.platoon.nudge_at - now))
                got = self.endpoint.receive(wait)
            except _Stopped:
                break
            finally:
                self._waiting = False
            if got is not None:
                self.handle(got)

    def handle(self, got: Received) -> None:
        """Answer one received datagram (a message, a rejection, or a fragment)."""
        if got.addr is None:
            return
        if got.error is not None:
            self._reject(got)
            return
        msg = got.msg
        if msg is None:
            return
        if isinstance(got.sealer, Channel) and not self._confirm(got.sealer, got.addr):
            return
        self.stats[f"rx.{msg['type']}"] += 1
        limit = self._reply_limit(msg, got.addr, got.size)
        try:
            self._dispatch(msg, got.addr, limit, got.version)
        except Exception as exc:  # noqa: BLE001 - a bug must not kill the service
            self.stats["internal_errors"] += 1
            print(f"vacc-server: internal error on {msg['type']}: {exc!r}", file=sys.stderr)
            s = self._held(msg.get("session"))
            if s is not None and got.addr == s.addr:
                # INTERNAL is fatal: the session's world may be half-updated, so it
                # ends here (a platoon's every seat), and the client's new hello is answered at once.
                if self.platoon is not None:
                    self._give_up(f"internal error on seat {s.seat}'s {msg['type']}", notify=s)
                self.seats[s.seat] = None
                self.stats["sessions_ended_internal"] += 1
            self._send_error(got.addr, ErrorCode.INTERNAL, repr(exc), limit=limit, version=got.version)

    # -- keyed sessions -------------------------------------------------------

    def _held(self, token: Any) -> _Session | None:
        """The session (seat) holding the world with this token, if any."""
        for s in self.seats:
            if s is not None and s.token == token:
                return s
        return None

    def _lookup(self, sid: bytes) -> tuple[Channel, Any] | None:
        """The channel and address of the session, pending handshake or lost seat ``sid`` names."""
        for s in (*self.seats, *self.lost.values()):
            if s is not None and s.channel is not None and s.channel.sid == sid:
                return s.channel, s.addr
        s = self.pending.get(sid)
        return None if s is None or s.channel is None else (s.channel, s.addr)

    def _live_peers(self) -> list[Any]:
        return [s.addr for s in self.seats if s is not None]

    def _confirm(self, channel: Channel, addr: Any) -> bool:
        """A request opened under ``channel``: its handshake, if pending, takes the world (its seat)."""
        if any(s is not None and s.channel is channel for s in (*self.seats, *self.lost.values())):
            return True
        pending = self.pending.pop(channel.sid, None)
        if pending is None:
            return False
        if self.seats[pending.seat] is not None:
            # Another handshake finished first: this one opened nothing.
            self.stats["rejected.world_held"] += 1
            taken = "another session took the world first" if self.platoon is None else f"another session took seat {pending.seat} first"
            self._send_error(addr, ErrorCode.NO_SESSION, taken, version=pending.version)
            return False
        pending.last_seen = time.monotonic()
        self._seat(pending)
        return True

    def _seat(self, s: _Session) -> None:
        """``s`` takes its seat (the world, for one car)."""
        self.seats[s.seat] = s
        if self.platoon is None:
            self.endpoint.max_datagram = s.max_datagram
        else:
            self.platoon.joined(s.last_seen)
        self.stats["sessions_opened"] += 1

    def _keyed_repeat(self, keys: SessionKeys, addr: Any) -> bool:
        """Whether a keyed hello was seen before: answered again if from its own address
        (a re-send), dropped and counted if from another (a replay)."""
        seen = self._hellos.get(keys.nc)
        if seen is None:
            self._hellos[keys.nc] = addr
            if len(self._hellos) > HELLO_MEMORY:
                self._hellos.popitem(last=False)
            return False
        if seen != addr:
            self.stats["rejected.hello_replay"] += 1
            return True
        for s in (*self.seats, *self.pending.values()):
            if s is not None and s.keys is not None and s.keys.nc == keys.nc:
                self.endpoint.send_datagrams(s.welcome, addr, sealer=s.keys)
                return True
        return False  # answered before with an error: answer again

    # -- requests -------------------------------------------------------------

    def _reply_limit(self, msg: dict[str, Any], addr: Any, size: int) -> int | None:
        """The most bytes a reply to this message may take: unbounded for an
        authenticated datagram or the session's own requests, else the request's
        size, so a spoofed source gains no amplification."""
        s = self._held(msg.get("session"))
        if self.endpoint.authenticated or (s is not None and addr == s.addr):
            return None
        return size

    def _reject(self, got: Received) -> None:
        self.stats["rejected"] += 1
        exc, addr = got.error, got.addr
        limit = None if self.endpoint.authenticated else got.size  # with a key, only a sealed datagram gets here
        if isinstance(exc, VersionError):
            # The peer can fix its version; the header of the answer says the server's.
            self._send_error(addr, ErrorCode.BAD_VERSION, f"server speaks versions {self._versions()}", limit=limit)
        elif got.bad_message and exc is not None:
            # A whole message, refused for its content: say why, so a client written
            # from the spec does not wait for its timeout. Never to an over-budget source.
            try:
                self._bad_replies.charge(addr, 1, time.monotonic())
            except ProtocolError:
                self.stats["tx.bad_message_rate_limited"] += 1
                return
            self._send_error(addr, ErrorCode.BAD_MESSAGE, str(exc), limit=limit, version=got.version)

    def _versions(self) -> str:
        return "/".join(map(str, self.endpoint.reassembler.versions))

    def _send(self, msg: dict[str, Any], addr: Any, limit: int | None, version: int | None = None) -> list[bytes]:
        """Send a reply no larger than ``limit`` bytes on the wire (else withhold it)."""
        datagrams = self.endpoint.pack(msg, version=version)
        if limit is not None and self.endpoint.wire_size(datagrams) > limit:
            self.stats["tx.withheld_larger_than_request"] += 1
            return []
        self.endpoint.send_datagrams(datagrams, addr)
        return datagrams

    def _send_error(
        self, addr: Any, code: ErrorCode, detail: str, *, limit: int | None = None, version: int | None = None, **where: int | None
    ) -> None:
        msg = m.error(code, detail[: MAX_STR_LEN // 4], **where)  # a str of at most 4 bytes a character fits the codec's limit
        if limit is not None and self.endpoint.wire_size(self.endpoint.pack(msg, version=version)) > limit:
            msg = m.error(code, "", **where)  # the code alone may still fit
        if self._send(msg, addr, limit, version):
            self.stats[f"tx.error.{code.name}"] += 1

    def _dispatch(self, msg: dict[str, Any], addr: Any, limit: int | None, version: int) -> None:
        kind = msg["type"]
        if kind == "hello":
            self._hello(msg, addr, limit, version)
            return
        if kind in ("welcome", "obs", "error"):
            # Never answered: an error for an error could ping-pong between two servers.
            self.stats["rejected.wrong_direction"] += 1
            return
        session = self._held(msg["session"])
        if session is None:
            lost = self.lost.get(msg["session"])
            if lost is not None and addr == lost.addr:
                # a seat of a platoon that gave up: told why until it closes
                if kind == "close":
                    del self.lost[msg["session"]]
                    self._send_to(lost, {"type": "close", "session": lost.token})
                else:
                    self._send_to(lost, m.error(ErrorCode.SEAT_LOST, lost.lost))
            elif kind == "close":
                self._send({"type": "close", "session": msg["session"]}, addr, limit, version)
            else:
                self.stats["rejected.no_session"] += 1
                self._send_error(addr, ErrorCode.NO_SESSION, "unknown or expired session token", limit=limit, version=version)
            return
        if addr != session.addr:
            # A valid token from another address is a hijack attempt: not served.
            self.stats["rejected.wrong_address"] += 1
            return
        session.last_seen = time.monotonic()
        if kind == "step":
            self._step(session, msg, addr)
        elif kind == "reset":
            self._reset(session, msg, addr)
        elif kind == "heartbeat":
            self._send_to(session, {"type": "heartbeat", "session": session.token, "seq": msg["seq"]})
        elif kind == "close":
            self._send_to(session, {"type": "close", "session": session.token})
            self.seats[session.seat] = None
            self.stats["sessions_closed"] += 1
            if self.platoon is not None:
                self._left(session, "closed its session")

    def _hello(self, msg: dict[str, Any], addr: Any, limit: int | None, version: int) -> None:
        keys = self.endpoint.reply_sealer  # keyed: the fresh keys of this hello's answer
        if isinstance(keys, SessionKeys) and self._keyed_repeat(keys, addr):
            return
        again = next((s for s in self.seats if s is not None and s.addr == addr and s.nonce == msg["nonce"]), None)
        if keys is None and again is not None:
            if limit is None or self.endpoint.wire_size(again.welcome) <= limit:
                self.endpoint.send_datagrams(again.welcome, addr)  # a repeated hello
            return
        if msg["version"] != version:
            # The header's version is one the server speaks; the hello must say the same.
            detail = f"server speaks versions {self._versions()}; hello says {msg['version']} in a version {version} datagram"
            self._send_error(addr, ErrorCode.BAD_VERSION, detail, limit=limit)
            return
        seat, refusal = self._free_seat(msg.get("seat", -1))
        if refusal is not None:
            self._send_error(addr, *refusal, limit=limit, version=version)
            return
        fmt, width, height = msg["image_format"], msg["image_width"], msg["image_height"]
        lo, hi = m.MIN_IMAGE_SIDE, m.MAX_IMAGE_SIDE
        problem = None
        if fmt not in m.IMAGE_FORMATS:
            problem = f"image_format {fmt!r} is not one of {m.IMAGE_FORMATS}"
        elif fmt != "none" and not (lo <= width <= hi and lo <= height <= hi):
            problem = f"image size {width}x{height} outside {lo}..{hi} px"
        elif not MIN_DATAGRAM <= msg["max_datagram"] <= MAX_DATAGRAM:
            problem = f"max_datagram {msg['max_datagram']} outside {MIN_DATAGRAM}..{MAX_DATAGRAM}"
        elif len(msg["nonce"]) != m.NONCE_BYTES:
            problem = f"nonce must be {m.NONCE_BYTES} bytes"
        if problem:
            self._send_error(addr, ErrorCode.BAD_MESSAGE, problem, limit=limit, version=version)
            return
        token = os.urandom(m.TOKEN_BYTES) if keys is None else keys.token  # a capability, not simulation randomness
        max_datagram = min(msg["max_datagram"], self.config.max_datagram)
        cfg = self.config.world
        welcome = {
            "type": "welcome",
            "version": version,
            "nonce": msg["nonce"],
            "session": token,
            "server": "vacc-sim/0.1",
            "physics_dt": cfg.physics_dt,
            "control_period": cfg.control_period,
            "image_format": fmt,
            "image_width": width if fmt != "none" else 0,
            "image_height": height if fmt != "none" else 0,
            "max_datagram": max_datagram,
            "session_timeout": self.config.session_timeout,
            "seed_salt": self.world.salt,
            "traffic": cfg.traffic_per_lane,
            "sun_elevation": list(cfg.sun_elevation),
        }
        if self.platoon is not None:
            welcome |= {"seat": seat, "seats": len(self.seats), "seat_timeout": self.platoon.seat_timeout, "join_timeout": self.platoon.join_timeout}
        else:
            self.endpoint.max_datagram = max_datagram
        datagrams = self.endpoint.pack(m.for_version(welcome, version), version=version, max_datagram=max_datagram)
        if limit is not None and self.endpoint.wire_size(datagrams) > limit:
            self._send_error(addr, ErrorCode.BAD_MESSAGE, f"pad the hello to {HELLO_BYTES} bytes", limit=limit, version=version)
            return
        opened = _Session(token, addr, version, msg["nonce"], datagrams, fmt, (width, height), time.monotonic(), max_datagram=max_datagram,
                          seat=seat)  # fmt: skip
        if keys is None:
            self._seat(opened)
        else:
            # Keyed: the world is taken by the first request that opens under these keys.
            opened.keys, opened.channel = keys, Channel(keys, client=False)
            self.pending[keys.sid] = opened
            if len(self.pending) > MAX_PENDING:
                self.pending.popitem(last=False)
            self.stats["handshakes"] += 1
        self.endpoint.send_datagrams(datagrams, addr)

    def _free_seat(self, wanted: int) -> tuple[int, tuple[ErrorCode, str] | None]:
        """The seat a hello asking for ``wanted`` (-1: any) takes, or the error that refuses it:
        BUSY while it (or every seat) is taken, BAD_MESSAGE for a seat there is not."""
        n = len(self.seats)
        claimed = {p.seat for p in self.pending.values()}
        if self.platoon is None:
            if wanted not in (-1, 0):
                return 0, (ErrorCode.BAD_MESSAGE, f"this server drives one car: there is no seat {wanted} (start it with --followers for a platoon)")
            # Who holds the world is nobody else's business.
            return 0, (ErrorCode.BUSY, "the world is in use by another session; retry later") if self.seats[0] is not None else None
        if wanted == -1:
            free = [i for i in range(n) if self.seats[i] is None and i not in claimed]
            return (free[0], None) if free else (0, (ErrorCode.BUSY, f"every one of the {n} seats is taken; retry later"))
        if not 0 <= wanted < n:
            return 0, (ErrorCode.BAD_MESSAGE, f"seat {wanted} outside 0..{n - 1} (-1: any free seat)")
        if self.seats[wanted] is not None or wanted in claimed:
            return wanted, (ErrorCode.BUSY, f"seat {wanted} is taken; retry later")
        return wanted, None

    def _send_to(self, s: _Session, msg: dict[str, Any]) -> list[bytes]:
        """Send a message to session ``s``, at its version and datagram size, sealed in its channel."""
        datagrams = self.endpoint.pack(m.for_version(msg, s.version), version=s.version, max_datagram=s.max_datagram)
        self.endpoint.send_datagrams(datagrams, s.addr, sealer=s.channel)
        return datagrams

    def _error(self, s: _Session, addr: Any, code: ErrorCode, detail: str, **where: int | None) -> None:
        """An error answering one of the session's own requests."""
        self._send_error(addr, code, detail, version=s.version, **where)

    def _reset(self, s: _Session, msg: dict[str, Any], addr: Any) -> None:
        episode = msg["episode"]
        if episode < 0:  # -1 stands for "none yet" and has no cached reply
            self._error(s, addr, ErrorCode.BAD_RESET, f"episode {episode} is negative: episodes count from 0", episode=episode)
            return
        if episode == s.episode:
            self.endpoint.send_datagrams(s.reset_reply, addr, sealer=s.channel)  # a repeated reset
            return
        if episode < s.episode:
            self._error(s, addr, ErrorCode.BAD_RESET, f"episode {episode} is older than {s.episode}", episode=episode)
            return
        args = self._reset_args(s, msg, addr)
        if args is None:
            return
        if self.platoon is not None:
            self._seat_reset(s, episode, args)
            return
        try:
            state = self.world.reset(**args)
        except SimError as exc:
            self._error(s, addr, ErrorCode.BAD_RESET, str(exc), episode=episode)
            return
        s.episode, s.frame, s.state = episode, state.frame, state
        s.step_reply = []
        s.wall_start = time.monotonic() - state.t  # a pre-roll starts at t < 0
        s.reset_reply = self.endpoint.send(self._obs(s, state), addr, s.version)

    def _reset_args(self, s: _Session, msg: dict[str, Any], addr: Any) -> dict[str, Any] | None:
        """A reset's arguments for :meth:`World.reset`, or None once a BAD_RESET is sent."""
        episode = msg["episode"]
        trace = None
        if msg["trajectory"] == "trace":
            if msg["trace_t"] is None or msg["trace_v"] is None:
                self._error(s, addr, ErrorCode.BAD_RESET, "trajectory 'trace' needs trace_t and trace_v", episode=episode)
                return None
            numbers = all(type(x) in (int, float) for x in (*msg["trace_t"], *msg["trace_v"]))  # not bool, not str
            try:
                if not numbers:
                    raise TypeError
                trace = (np.asarray(msg["trace_t"], dtype=float), np.asarray(msg["trace_v"], dtype=float))
            except (TypeError, ValueError, OverflowError):
                self._error(s, addr, ErrorCode.BAD_RESET, "trace_t and trace_v must be arrays of numbers", episode=episode)
                return None
        duration = msg["duration"]
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            self._error(s, addr, ErrorCode.BAD_RESET, f"duration {duration} must be > 0 s", episode=episode)
            return None
        return {"scenario": msg["scenario"], "seed": msg["seed"], "trajectory": msg["trajectory"], "trace": trace, "duration": duration,
                "host_speed": msg["host_speed"], "gap": msg["gap"], "set_speed": msg["set_speed"],
                "preroll": msg.get("preroll") or 0}  # absent before version 4  # fmt: skip

    def _step(self, s: _Session, msg: dict[str, Any], addr: Any) -> None:
        episode, frame = msg["episode"], msg["frame"]
        if s.state is None or episode != s.episode:
            self._error(s, addr, ErrorCode.NO_EPISODE, f"no episode {episode} (current {s.episode})", episode=episode, frame=frame)
            return
        if frame == s.frame - 1 and s.step_reply:
            self.stats["cached_replies"] += 1
            self.endpoint.send_datagrams(s.step_reply, addr, sealer=s.channel)
            return
        if frame != s.frame:
            self._error(s, addr, ErrorCode.BAD_FRAME, f"step for frame {frame}, server is at frame {s.frame}", episode=episode, frame=frame)
            return
        u = msg["action"]
        if not (math.isfinite(u) and -1.0 <= u <= 1.0):
            self._error(s, addr, ErrorCode.BAD_ACTION, f"action {u!r} is not a finite number in [-1, 1]", episode=episode, frame=frame)
            return
        if s.state.terminated or s.state.truncated:
            self._error(s, addr, ErrorCode.EPISODE_OVER, f"episode {episode} ended at frame {s.frame} ({s.state.reason})", episode=episode, frame=frame)
            return
        if self.platoon is not None:
            if self.platoon.frame is None:
                self._error(s, addr, ErrorCode.EPISODE_OVER, self.platoon.abandoned, episode=episode, frame=frame)
            elif s.action is None:  # else a repeat while the other seats' actions are awaited
                self.platoon.ask_step(s, float(u), time.monotonic())
                self._advance()
            return
        state = self.world.step(float(u))
        s.state, s.frame = state, state.frame
        obs = self._obs(s, state)
        if self.config.realtime:
            # Pace to the wall clock; a slow client only makes the world wait.
            delay = s.wall_start + state.t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        s.step_reply = self.endpoint.send(obs, addr, s.version)

    # -- a platoon's seats (sim_server.seats) --------------------------------

    def _seat_reset(self, s: _Session, episode: int, args: dict[str, Any]) -> None:
        platoon = self.platoon
        assert platoon is not None
        if (s.asked is not None and s.asked.episode == episode) or s.pending_episode == episode:
            return  # a repeat while the other seats are awaited
        if platoon.running:
            # the episode is abandoned; seats that already acted on this frame are told so at once
            platoon.abandoned = f"seat {s.seat} asked for a new episode at frame {platoon.frame}"
            for x in self.seats:
                if x is not None and x.action is not None:
                    x.action = None
                    self._send_to(x, m.error(ErrorCode.EPISODE_OVER, platoon.abandoned, episode=x.episode, frame=x.frame))
            platoon.clear()
        lead = {k: args[k] for k in ("seed", "trajectory", "trace", "duration", "host_speed", "set_speed")}
        platoon.ask_reset(s, SeatReset(episode, args["scenario"], args["gap"], args["preroll"], lead), time.monotonic())
        self._advance()

    def _advance(self) -> None:
        """Pass whichever barrier is complete: start the episode, or step the frame."""
        platoon, seats = self.platoon, self.seats
        assert platoon is not None
        if not platoon.running and platoon.reset_ready(seats):
            held = [x for x in seats if x is not None]
            try:
                platoon.reset(held)
            except SimError as exc:
                for x in held:
                    self._send_to(x, m.error(ErrorCode.BAD_RESET, f"platoon reset: {exc}", episode=x.asked.episode if x.asked else None))
                    x.asked = None
                return
            for x in held:
                x.pending_episode, x.asked, x.step_reply = x.asked.episode if x.asked else -1, None, []
            self._engage()
        elif platoon.running and platoon.step_ready(seats):
            held = [x for x in seats if x is not None]
            engaged = [x.start < platoon.frame + 1 for x in held]  # type: ignore[operator]
            platoon.step(held)
            for x, was in zip(held, engaged, strict=True):
                if was:
                    x.state = platoon.seat_obs(x.seat)
                    x.frame = x.state.frame
                    x.step_reply = self._send_to(x, self._obs(x, x.state))
            self._engage()

    def _engage(self) -> None:
        """Answer the resets of the seats whose first frame the platoon has reached."""
        platoon = self.platoon
        assert platoon is not None and platoon.frame is not None
        for x in self.seats:
            if x is None or x.pending_episode < 0:
                continue
            if x.start == platoon.frame:
                x.episode, x.pending_episode = x.pending_episode, -1
                x.state = platoon.seat_obs(x.seat)
                x.frame = x.state.frame
                x.reset_reply = self._send_to(x, self._obs(x, x.state))
            elif platoon.world.over:
                episode, x.pending_episode = x.pending_episode, -1
                why = f"the platoon's episode ended at frame {platoon.frame} before this seat's first frame {x.start}"
                self._send_to(x, m.error(ErrorCode.BAD_RESET, why, episode=episode))

    def _left(self, s: _Session, why: str) -> None:
        """Seat ``s`` is gone: a running episode, or seats awaiting a reset, cannot go on."""
        platoon = self.platoon
        assert platoon is not None
        if platoon.running or any(x is not None and x.asked is not None for x in self.seats):
            self._give_up(f"seat {s.seat} (client {where(s.addr)}) {why}")
        elif all(x is None for x in self.seats):
            platoon.clear()

    def _give_up(self, detail: str, notify: _Session | None = None) -> None:
        """End every seat's session, telling each why (SEAT_LOST), as long as it asks."""
        assert self.platoon is not None
        print(f"vacc-server: platoon gave up: {detail}", file=sys.stderr)
        self.stats["platoon_gave_up"] += 1
        for x in (*self.seats, notify):
            if x is None or x.token in self.lost:
                continue
            x.lost = f"platoon gave up: {detail}"
            self.lost[x.token] = x
            while len(self.lost) > MAX_LOST:
                self.lost.popitem(last=False)
            self._send_to(x, m.error(ErrorCode.SEAT_LOST, x.lost))
        self.seats = [None] * len(self.seats)
        self.platoon.clear()

    def _obs(self, s: _Session, state: WorldState) -> dict[str, Any]:
        image, shape = None, None
        if s.image_format != "none":
            pixels = self._render(s)
            image, shape = pixels.tobytes(), list(pixels.shape if pixels.ndim == 3 else (*pixels.shape, 1))
        return {
            "type": "obs",
            "episode": s.episode,
            "frame": state.frame,
            "t": state.t,
            "v_host": state.v_host,
            "v_lead": state.v_lead,
            "gap": state.gap,
            "accel": state.accel,
            "a_lead": state.a_lead,
            "force": state.force,
            "collision": state.collision,
            "terminated": state.terminated,
            "truncated": state.truncated,
            "reason": state.reason,
            "set_speed": state.set_speed,
            "image": image,
            "image_shape": shape,
        }

    def _render(self, s: _Session) -> np.ndarray:
        # only image sessions pay for the renderer's import
        from sim_server.render import CameraConfig, Renderer, in_format

        if s.renderer is None:
            s.renderer = Renderer(CameraConfig(width=s.image_size[0], height=s.image_size[1]))
        world = self.world if self.platoon is None else self.platoon.world.worlds[s.seat]
        return in_format(s.renderer.render(world.scene()), s.image_format)

    def _expire(self, now: float) -> None:
        while self.pending:
            sid, p = next(iter(self.pending.items()))
            if now - p.last_seen <= HANDSHAKE_TIMEOUT:
                break
            del self.pending[sid]
            self.stats["handshakes_expired"] += 1
        for s in self.seats:
            if s is not None and now - s.last_seen > self.config.session_timeout:
                print(f"vacc-server: session of {s.addr} idle for {now - s.last_seen:.1f} s, freed", file=sys.stderr)
                self.seats[s.seat] = None
                self.stats["sessions_expired"] += 1
                if self.platoon is not None:
                    self._left(s, f"went silent for {now - s.last_seen:.1f} s")
        if self.platoon is not None and (why := self.platoon.overdue(self.seats, now)) is not None:
            self._give_up(why)
        elif self.platoon is not None:
            for x in self.platoon.nudges(self.seats, now):
                again = x.step_reply if x.frame == self.platoon.frame and x.step_reply else x.reset_reply
                self.endpoint.send_datagrams(again, x.addr, sealer=x.channel)
                self.stats["nudges"] += 1

