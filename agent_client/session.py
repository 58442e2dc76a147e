"""A lockstep client session with the simulator server, as a context manager.

    with Session(("127.0.0.1", 47800)) as sim:
        obs = sim.reset(scenario="ice", seed=1, trajectory="test-1")
        while not (obs["terminated"] or obs["truncated"]):
            obs = sim.step(controller(obs))

Every request is re-sent after a timeout that doubles up to a cap; the session gives
up after ``give_up`` seconds without the expected reply, naming the server address
and the last frame. Replies are matched by episode and frame, so stale, duplicated
or reordered datagrams are ignored.

The socket is connected to the server, so the kernel drops datagrams from anyone
else; with a pre-shared ``key`` the handshake derives this session's own keys, one
per direction, and every datagram both ways is sealed and checked
(:mod:`protocol.auth`), so a forged, replayed, reflected or other session's reply
is dropped and counted in ``session.endpoint.rejected``.
"""

from __future__ import annotations

import logging
import math
import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_client.errors import FatalSessionError, ServerTimeout, SessionError
from protocol import messages as m
from protocol.errors import VersionError
from protocol.faults import FaultConfig
from protocol.fragment import DEFAULT_DATAGRAM, HELLO_BYTES
from protocol.transport import Endpoint, is_loopback

__all__ = ["Session", "RETRY_INITIAL", "RETRY_FIRST_RESET", "RETRY_MAX", "GIVE_UP"]

log = logging.getLogger("vacc.client")

RETRY_INITIAL = 0.02  # [s] first re-send timeout before any round trip is measured
# [s] the same for resets, which keep their own estimate: a reset builds the world and
# renders frame 0, and a session's first one builds the camera too (30-60 ms measured)
RETRY_FIRST_RESET = 0.25
RETRY_MIN = 0.002  # [s] floor of the adaptive re-send timeout
RETRY_MAX = 0.5  # [s] re-send interval cap (doubling backoff)
GIVE_UP = 5.0  # [s] without the expected reply, the session is declared lost


@dataclass
class _RoundTrip:
    """A round-trip estimate of one kind of request (RFC 6298, Karn's rule)."""

    initial: float  # [s] re-send timeout before any sample
    srtt: float | None = None  # [s] smoothed round trip of unrepeated requests
    rttvar: float = 0.0  # [s] its mean deviation
    backoff: float = 0.0  # [s] re-send timeout kept from a request that needed re-sends

    def timeout(self, retry_max: float) -> float:
        wait = self.initial if self.srtt is None else min(retry_max, max(RETRY_MIN, self.srtt + 4.0 * self.rttvar))
        # Karn: a backed-off timeout stays until a clean sample, so a server that
        # is slow on purpose (real-time pacing) is not flooded with re-sends.
        return max(wait, self.backoff)

    def sample(self, rtt: float) -> None:
        self.backoff = 0.0
        if self.srtt is None:
            self.srtt, self.rttvar = rtt, rtt / 2
        else:  # RFC 6298 gains
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - rtt)
            self.srtt = 0.875 * self.srtt + 0.125 * rtt


def resolve(addr: tuple[str, int]) -> tuple[str, int]:
    """The numeric address replies come from, so they can be compared exactly."""
    host, port = addr
    info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    return str(info[0][4][0]), int(info[0][4][1])


class Session:
    """One client's session with one server.

    Args:
        server: (host, port) of the server.
        image_format: "none", "rgb" or "gray": what the observation carries.
        image_size: (width, height) [px] of the image to ask for.
        give_up: [s] bound on waiting for any one reply.
        retry_initial: [s] first re-send timeout.
        retry_first_reset: [s] first re-send timeout of resets.
        retry_max: [s] re-send timeout cap.
        faults: fault injection on the client's sends (tests, benchmarks).
        client_name: shown in the server's logs.
        key: shared key (``protocol.auth.load_key``); the server must hold the same.
        seat: a platoon server's seat to take (0 nearest the lead); None: the first free
            one. A platoon's replies wait for every seat, so a seated session waits the
            server's ``seat_timeout`` (steps) or ``join_timeout`` (resets) longer than
            ``give_up``: the server's give-up, which names the seat it waited for, comes first.
    """

    def __init__(
        self,
        server: tuple[str, int],
        *,
        image_format: str = "none",
        image_size: tuple[int, int] = (400, 400),
        give_up: float = GIVE_UP,
        retry_initial: float = RETRY_INITIAL,
        retry_first_reset: float = RETRY_FIRST_RESET,
        retry_max: float = RETRY_MAX,
        faults: FaultConfig | None = None,
        max_datagram: int = DEFAULT_DATAGRAM,
        client_name: str = "vacc-client",
        key: bytes | None = None,
        seat: int | None = None,
    ):
        self.server = resolve(server)
        self.seat = seat
        self.image_format = image_format
        self.image_size = image_size
        self.give_up = give_up
        self.retry_max = retry_max
        self.client_name = client_name
        self.max_datagram = max_datagram
        family = socket.AF_INET6 if ":" in self.server[0] else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        loopback = is_loopback(self.server[0])
        # Bind loopback for a loopback server, so nothing listens on the network.
        sock.bind((self.server[0] if loopback else "", 0))
        sock.connect(self.server)  # the kernel then drops datagrams from anyone else
        self.endpoint = Endpoint(sock, max_datagram=max_datagram, faults=faults, key=key, peer=self.server)
        self.token: bytes | None = None
        self.welcome: dict[str, Any] | None = None
        self.episode = -1
        self.frame = -1
        self.resends = 0  # requests re-sent after a timeout
        self._rtt = {"reset": _RoundTrip(retry_first_reset), "other": _RoundTrip(retry_initial)}
        self._closed = False
        self._heartbeat_seq = 0
        self._last_send = time.monotonic()  # [s] when a request last went out
        self._stop = threading.Event()
        self._keepalive: threading.Thread | None = None

    # -- lifecycle ------------------------------------------------------------

    def __enter__(self) -> Session:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> dict[str, Any]:
        """Handshake; returns the server's welcome.

        Raises:
            FatalSessionError: the server refused (version, busy past give-up time).
            ServerTimeout: no answer.
        """
        nonce = os.urandom(m.NONCE_BYTES)
        hello = {
            "type": "hello",
            "version": self.endpoint.version,
            "nonce": nonce,
            "client": self.client_name,
            "image_format": self.image_format,
            "image_width": int(self.image_size[0]),
            "image_height": int(self.image_size[1]),
            "max_datagram": self.max_datagram,
        }
        if self.seat is not None:
            hello["seat"] = int(self.seat)
        deadline = time.monotonic() + self.give_up
        busy: SessionError | None = None
        while True:
            try:
                welcome = self._request(hello, lambda r: r["type"] == "welcome" and r["nonce"] == nonce, "hello", deadline, pad_to=HELLO_BYTES)
                break
            except ServerTimeout:
                if busy is None:
                    raise
                exc = busy
            except SessionError as refused:
                exc = refused
            # BUSY: the world may be held by a vanished client; wait for its timeout.
            if exc.code != m.ErrorCode.BUSY or time.monotonic() >= deadline:
                raise FatalSessionError(f"server {self._where()} refused the session: {exc}", exc.code) from None
            busy = exc
            time.sleep(0.1)
        if self.endpoint.authenticated:
            self.endpoint.establish(welcome["session"])  # the keys of the answer that carried it
        self.welcome = welcome
        self.token = welcome["session"]
        self.seat = welcome.get("seat", self.seat)
        self._keepalive = threading.Thread(target=self._keep_alive, name="vacc-keepalive", daemon=True)
        self._keepalive.start()
        return welcome

    def _keep_alive(self) -> None:
        # A client busy elsewhere (evaluating, saving a checkpoint) must not lose its
        # session: while no request goes out, send a heartbeat every quarter of the
        # server's timeout. Its echo (seq 0) is ignored as a stale reply.
        assert self.welcome is not None and self.token is not None
        period = max(0.05, float(self.welcome["session_timeout"]) / 4)
        datagram = self.endpoint.pack({"type": "heartbeat", "session": self.token, "seq": 0})[0]
        while not self._stop.wait(period):
            if time.monotonic() - self._last_send >= period:
                try:  # straight to the socket: fault injection is not thread-safe
                    self.endpoint.sock.sendto(self.endpoint.seal(datagram), self.server)
                except ConnectionError:
                    continue  # an ICMP error from an earlier send; the server may be back
                except OSError:
                    return  # the socket is closed

    def close(self) -> None:
        """Tell the server goodbye (best effort) and release the socket; safe twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._keepalive is not None:
            self._keepalive.join()
        try:
            if self.token is not None:
                msg = {"type": "close", "session": self.token}
                self._request(msg, lambda r: r["type"] == "close", "close", time.monotonic() + min(self.give_up, 0.5))
        except (FatalSessionError, SessionError):
            pass  # the server may already be gone; closing must not fail
        finally:
            self.endpoint.close()

    # -- lockstep -------------------------------------------------------------

    def reset(
        self,
        scenario: str = "ice",
        seed: int = 0,
        trajectory: str = "test-1",
        *,
        trace: tuple[np.ndarray, np.ndarray] | None = None,
        duration: float | None = None,
        host_speed: float | None = None,
        gap: float | None = None,
        set_speed: float | None = None,
        preroll: int = 0,
    ) -> dict[str, Any]:
        """Start a new episode; returns the observation of frame 0 (``-preroll``).

        Args:
            scenario: "ice" or "ev".
            seed: episode seed.
            trajectory: a name of :data:`protocol.scenarios.TRAJECTORIES`.
            trace: (times [s], speeds [m/s]) of a lead trace; replaces ``trajectory``.
            duration: truncate the episode after this many seconds.
            host_speed: host's initial speed [m/s]; None: the server draws it.
            gap: initial gap [m]; None: the server draws it.
            set_speed: cruise set speed [m/s]; None: the server's default (33.5).
            preroll: control steps the camera runs before the controller engages
                (frames -preroll..-1, the host coasting at its initial speed and the
                server ignoring the action); frame 0 is the episode's start either way.

        Raises:
            SessionError: the server refused the reset (unknown scenario, bad trace,
                initial condition or set speed out of range).
            FatalSessionError, ServerTimeout: the session is lost.
        """
        self._check_open()
        self.episode += 1
        episode = self.episode
        msg = {
            "type": "reset",
            "session": self.token,
            "episode": episode,
            "scenario": scenario,
            "seed": int(seed),
            "trajectory": "trace" if trace is not None else trajectory,
            "trace_t": None if trace is None else [float(x) for x in trace[0]],
            "trace_v": None if trace is None else [float(x) for x in trace[1]],
            "duration": None if duration is None else float(duration),
            "host_speed": None if host_speed is None else float(host_speed),
            "gap": None if gap is None else float(gap),
            "set_speed": None if set_speed is None else float(set_speed),
            "preroll": int(preroll),
        }
        first = -int(preroll)
        obs = self._request(
            msg,
            lambda r: r["type"] == "obs" and r["episode"] == episode and r["frame"] == first,
            f"reset of episode {episode}",
            error_match=lambda e: e["episode"] in (episode, None),
            rtt=self._rtt["reset"],
            extra=self._waits("join_timeout"),
        )
        self.frame = first
        return obs

    def step(self, action: float) -> dict[str, Any]:
        """Apply ``action`` (force u in [-1, 1]) at the current frame; returns the next one.

        Raises:
            SessionError: the server refused the step (bad action, episode over).
            FatalSessionError, ServerTimeout: the session is lost.
        """
        self._check_open()
        episode, frame, u = self.episode, self.frame, float(action)
        msg = {"type": "step", "session": self.token, "episode": episode, "frame": frame, "action": u}
        # A bad action refused for this frame may be answered again (its request was re-sent)
        # after the caller moved on: that refusal is not the answer to a valid action.
        valid = math.isfinite(u) and -1.0 <= u <= 1.0
        obs = self._request(
            msg,
            lambda r: r["type"] == "obs" and r["episode"] == episode and r["frame"] == frame + 1,
            f"step of frame {frame}",
            error_match=lambda e: e["frame"] in (frame, None) and e["episode"] in (episode, None) and not (valid and e["code"] == m.ErrorCode.BAD_ACTION),
            extra=self._waits("seat_timeout"),
            # a platoon server sends the frame acted on again while it awaits this step: it was lost
            nudge=(lambda r: r["type"] == "obs" and r["episode"] == episode and r["frame"] == frame) if "seats" in (self.welcome or {}) else None,
        )
        self.frame = frame + 1
        return obs

    def heartbeat(self) -> None:
        """Keep an idle session alive (e.g. while a human pauses)."""
        self._check_open()
        self._heartbeat_seq += 1
        seq = self._heartbeat_seq
        msg = {"type": "heartbeat", "session": self.token, "seq": seq}
        self._request(msg, lambda r: r["type"] == "heartbeat" and r["seq"] == seq, "heartbeat")

    @staticmethod
    def image(obs: dict[str, Any]) -> np.ndarray | None:
        """The observation's camera frame as a uint8 array (H, W, C) or (H, W), or None."""
        if obs["image"] is None:
            return None
        h, w, c = obs["image_shape"]
        pixels = np.frombuffer(obs["image"], dtype=np.uint8)
        if pixels.size != h * w * c:
            raise FatalSessionError(f"image of {pixels.size} bytes does not match shape {obs['image_shape']}")
        return pixels.reshape((h, w) if c == 1 else (h, w, c))

    # -- plumbing -------------------------------------------------------------

    def _where(self) -> str:
        return f"{self.server[0]}:{self.server[1]}"

    def _waits(self, name: str) -> float:
        """[s] how long a platoon server may hold a reply for the other seats (0 for one car)."""
        return float((self.welcome or {}).get(name, 0.0))

    def _check_open(self) -> None:
        if self._closed or self.token is None:
            raise FatalSessionError(f"session with {self._where()} is not open")

    def _request(
        self,
        msg: dict[str, Any],
        accept: Callable[[dict[str, Any]], bool],
        what: str,
        deadline: float | None = None,
        error_match: Callable[[dict[str, Any]], bool] = lambda e: True,
        pad_to: int = 0,
        rtt: _RoundTrip | None = None,
        extra: float = 0.0,
        nudge: Callable[[dict[str, Any]], bool] | None = None,
    ) -> dict[str, Any]:
        endpoint, server = self.endpoint, self.server
        datagrams = endpoint.pack(msg, pad_to=pad_to)
        endpoint.send_datagrams(datagrams, server)
        now = self._last_send = time.monotonic()
        deadline = deadline if deadline is not None else now + self.give_up + extra
        sent_at = now
        # Re-send timeout from measured round trips (TCP-style, Karn's rule: only
        # requests answered without a re-send update the estimate).
        rtt = rtt or self._rtt["other"]
        wait = rtt.timeout(self.retry_max)
        resent = False
        resend_at = now + wait
        while True:
            got = endpoint.receive(max(0.0, min(resend_at, deadline) - now))
            now = time.monotonic()
            if got is not None and got.msg is not None and got.addr == server:
                reply = got.msg
                if accept(reply):
                    if not resent:
                        rtt.sample(now - sent_at)
                    return reply
                if nudge is not None and nudge(reply):
                    endpoint.send_datagrams(datagrams, server)  # the server asks again: re-send at once
                    self._last_send = now
                    self.resends += 1
                    resent = True
                    continue
                if reply["type"] == "error" and error_match(reply):
                    text = f"server {self._where()}: {reply['name']}: {reply['detail']}"
                    if reply["fatal"]:
                        self.token = None  # the server holds no session for it any more
                        raise FatalSessionError(text, reply["code"])
                    raise SessionError(text, reply["code"])
                continue  # stale or duplicate reply
            if got is not None and isinstance(got.error, VersionError) and got.addr == server and msg["type"] == "hello":
                # A server of another version answers in its own, which this side cannot read.
                raise FatalSessionError(f"server {self._where()} speaks another protocol version: {got.error}", m.ErrorCode.BAD_VERSION)
            if now >= deadline:
                hint = "; check that both sides use the same --key-file" if endpoint.authenticated and self.token is None else ""
                if self.token is None:  # no session yet: there is no episode or frame to speak of
                    raise ServerTimeout(f"no reply from server {self._where()} to {what} within {self.give_up:g} s: "
                                        f"the server was never reached (is one running there?){hint}")  # fmt: skip
                raise ServerTimeout(
                    f"no reply from server {self._where()} to {what} (episode {self.episode}, "
                    f"last frame {self.frame}) within {self.give_up + extra:g} s{hint}"
                )
            if now >= resend_at:
                log.debug("no reply from %s to %s within %.3f s: re-sent (frame %d)", self._where(), what, wait, self.frame)
                endpoint.send_datagrams(datagrams, server)
                self._last_send = now
                self.resends += 1
                resent = True
                wait = min(wait * 2, self.retry_max)
                rtt.backoff = wait
                resend_at = now + wait
