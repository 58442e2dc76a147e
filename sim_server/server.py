"""The simulator server: one world, one session at a time, lockstep over UDP.

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


class SimServer:
    """A UDP simulator server. Use as a context manager, then :meth:`serve`."""

    def __init__(self, config: ServerConfig):
        self.config = config
        sock = socket.socket(socket.AF_INET6 if ":" in config.host else socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind((config.host, config.port))
        self.endpoint = Endpoint(
            sock, max_datagram=config.max_datagram, faults=config.faults, key=config.key, max_message=MAX_REQUEST_BYTES,
            versions=m.SUPPORTED_VERSIONS, sessions=self._lookup, live_peer=self._live_peer,
        )  # fmt: skip
        self.address = sock.getsockname()[:2]
        self.world = World(config.world, salt=config.seed)
        self.session: _Session | None = None
        self.pending: OrderedDict[bytes, _Session] = OrderedDict()  # keyed handshakes by sid, oldest first
        self._hellos: OrderedDict[bytes, Any] = OrderedDict()  # keyed: client nonce -> the address it came from
        self.stats: Counter[str] = Counter()
        self._bad_replies = DecodeBudget(rate=BAD_MESSAGE_RATE, burst=BAD_MESSAGE_RATE)
        self._stopped = False  # set by stop(), even before serve() starts
        self._waiting = False  # serve() is blocked in a receive

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
                got = self.endpoint.receive(0.5 if deadline is None else min(0.5, deadline - now))
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
            s = self.session
            if s is not None and got.addr == s.addr and msg.get("session") == s.token:
                # INTERNAL is fatal: the session's world may be half-updated, so it
                # ends here, and the client's new hello is answered at once.
                self.session = None
                self.stats["sessions_ended_internal"] += 1
            self._send_error(got.addr, ErrorCode.INTERNAL, repr(exc), limit=limit, version=got.version)

    # -- keyed sessions -------------------------------------------------------

    def _lookup(self, sid: bytes) -> tuple[Channel, Any] | None:
        """The channel and address of the session or pending handshake ``sid`` names."""
        s = self.session
        if s is None or s.channel is None or s.channel.sid != sid:
            s = self.pending.get(sid)
        return None if s is None or s.channel is None else (s.channel, s.addr)

    def _live_peer(self) -> Any:
        return None if self.session is None else self.session.addr

    def _confirm(self, channel: Channel, addr: Any) -> bool:
        """A request opened under ``channel``: its handshake, if pending, takes the world."""
        s = self.session
        if s is not None and s.channel is channel:
            return True
        pending = self.pending.pop(channel.sid, None)
        if pending is None:
            return False
        if s is not None:
            # Another handshake finished first: this one opened nothing.
            self.stats["rejected.world_held"] += 1
            self._send_error(addr, ErrorCode.NO_SESSION, "another session took the world first", version=pending.version)
            return False
        pending.last_seen = time.monotonic()
        self.session = pending
        self.endpoint.max_datagram = pending.max_datagram
        self.stats["sessions_opened"] += 1
        return True

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
        for s in (self.session, *self.pending.values()):
            if s is not None and s.keys is not None and s.keys.nc == keys.nc:
                self.endpoint.send_datagrams(s.welcome, addr, sealer=s.keys)
                return True
        return False  # answered before with an error: answer again

    # -- requests -------------------------------------------------------------

    def _reply_limit(self, msg: dict[str, Any], addr: Any, size: int) -> int | None:
        """The most bytes a reply to this message may take: unbounded for an
        authenticated datagram or the session's own requests, else the request's
        size, so a spoofed source gains no amplification."""
        s = self.session
        if self.endpoint.authenticated or (s is not None and addr == s.addr and msg.get("session") == s.token):
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
        session = self.session
        if session is None or msg["session"] != session.token:
            if kind == "close":
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
            self.endpoint.send({"type": "heartbeat", "session": session.token, "seq": msg["seq"]}, addr, session.version)
        elif kind == "close":
            self.endpoint.send({"type": "close", "session": session.token}, addr, session.version)
            self.session = None
            self.stats["sessions_closed"] += 1

    def _hello(self, msg: dict[str, Any], addr: Any, limit: int | None, version: int) -> None:
        keys = self.endpoint.reply_sealer  # keyed: the fresh keys of this hello's answer
        if isinstance(keys, SessionKeys) and self._keyed_repeat(keys, addr):
            return
        session = self.session
        if keys is None and session is not None and session.addr == addr and session.nonce == msg["nonce"]:
            if limit is None or self.endpoint.wire_size(session.welcome) <= limit:
                self.endpoint.send_datagrams(session.welcome, addr)  # a repeated hello
            return
        if msg["version"] != version:
            # The header's version is one the server speaks; the hello must say the same.
            detail = f"server speaks versions {self._versions()}; hello says {msg['version']} in a version {version} datagram"
            self._send_error(addr, ErrorCode.BAD_VERSION, detail, limit=limit)
            return
        if session is not None:
            # Who holds the world is nobody else's business.
            self._send_error(addr, ErrorCode.BUSY, "the world is in use by another session; retry later", limit=limit, version=version)
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
        self.endpoint.max_datagram = max_datagram
        datagrams = self.endpoint.pack(m.for_version(welcome, version), version=version)
        if limit is not None and self.endpoint.wire_size(datagrams) > limit:
            self._send_error(addr, ErrorCode.BAD_MESSAGE, f"pad the hello to {HELLO_BYTES} bytes", limit=limit, version=version)
            return
        opened = _Session(token, addr, version, msg["nonce"], datagrams, fmt, (width, height), time.monotonic(), max_datagram=max_datagram)
        if keys is None:
            self.session = opened
            self.stats["sessions_opened"] += 1
        else:
            # Keyed: the world is taken by the first request that opens under these keys.
            opened.keys, opened.channel = keys, Channel(keys, client=False)
            self.pending[keys.sid] = opened
            if len(self.pending) > MAX_PENDING:
                self.pending.popitem(last=False)
            self.stats["handshakes"] += 1
        self.endpoint.send_datagrams(datagrams, addr)

    def _error(self, s: _Session, addr: Any, code: ErrorCode, detail: str, **where: int | None) -> None:
        """An error answering one of the session's own requests."""
        self._send_error(addr, code, detail, version=s.version, **where)

    def _reset(self, s: _Session, msg: dict[str, Any], addr: Any) -> None:
        episode = msg["episode"]
        if episode < 0:  # -1 stands for "none yet" and has no cached reply
            self._error(s, addr, ErrorCode.BAD_RESET, f"episode {episode} is negative: episodes count from 0", episode=episode)
            return
        if episode == s.episode:
            self.endpoint.send_datagrams(s.reset_reply, addr)  # a repeated reset
            return
        if episode < s.episode:
            self._error(s, addr, ErrorCode.BAD_RESET, f"episode {episode} is older than {s.episode}", episode=episode)
            return
        trace = None
        if msg["trajectory"] == "trace":
            if msg["trace_t"] is None or msg["trace_v"] is None:
                self._error(s, addr, ErrorCode.BAD_RESET, "trajectory 'trace' needs trace_t and trace_v", episode=episode)
                return
            numbers = all(type(x) in (int, float) for x in (*msg["trace_t"], *msg["trace_v"]))  # not bool, not str
            try:
                if not numbers:
                    raise TypeError
                trace = (np.asarray(msg["trace_t"], dtype=float), np.asarray(msg["trace_v"], dtype=float))
            except (TypeError, ValueError, OverflowError):
                self._error(s, addr, ErrorCode.BAD_RESET, "trace_t and trace_v must be arrays of numbers", episode=episode)
                return
        duration = msg["duration"]
        if duration is not None and not (math.isfinite(duration) and duration > 0):
            self._error(s, addr, ErrorCode.BAD_RESET, f"duration {duration} must be > 0 s", episode=episode)
            return
        try:
            state = self.world.reset(
                msg["scenario"], msg["seed"], msg["trajectory"], trace=trace, duration=duration,
                host_speed=msg["host_speed"], gap=msg["gap"], set_speed=msg["set_speed"],
                preroll=msg.get("preroll") or 0,  # absent before version 4
            )  # fmt: skip
        except SimError as exc:
            self._error(s, addr, ErrorCode.BAD_RESET, str(exc), episode=episode)
            return
        s.episode, s.frame, s.state = episode, state.frame, state
        s.step_reply = []
        s.wall_start = time.monotonic() - state.t  # a pre-roll starts at t < 0
        s.reset_reply = self.endpoint.send(self._obs(s, state), addr, s.version)

    def _step(self, s: _Session, msg: dict[str, Any], addr: Any) -> None:
        episode, frame = msg["episode"], msg["frame"]
        if s.state is None or episode != s.episode:
            self._error(s, addr, ErrorCode.NO_EPISODE, f"no episode {episode} (current {s.episode})", episode=episode, frame=frame)
            return
        if frame == s.frame - 1 and s.step_reply:
            self.stats["cached_replies"] += 1
            self.endpoint.send_datagrams(s.step_reply, addr)
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
        state = self.world.step(float(u))
        s.state, s.frame = state, state.frame
        obs = self._obs(s, state)
        if self.config.realtime:
            # Pace to the wall clock; a slow client only makes the world wait.
            delay = s.wall_start + state.t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        s.step_reply = self.endpoint.send(obs, addr, s.version)

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
        return in_format(s.renderer.render(self.world.scene()), s.image_format)

    def _expire(self, now: float) -> None:
        while self.pending:
            sid, p = next(iter(self.pending.items()))
            if now - p.last_seen <= HANDSHAKE_TIMEOUT:
                break
            del self.pending[sid]
            self.stats["handshakes_expired"] += 1
        s = self.session
        if s is not None and now - s.last_seen > self.config.session_timeout:
            print(f"vacc-server: session of {s.addr} idle for {now - s.last_seen:.1f} s, freed", file=sys.stderr)
            self.session = None
            self.stats["sessions_expired"] += 1
