"""Clean-room lockstep client for the vacc wire protocol, written from protocol/SPEC.md only.

Standard library, ``msgpack`` and ``cryptography``; nothing from the vacc package.
Section numbers (§) refer to protocol/SPEC.md, version 6.
"""

from __future__ import annotations

import os
import random
import socket
import struct
import time
from dataclasses import dataclass, field

import msgpack
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

MAGIC = b"VC"
UNKEYED_VERSION = 5
KEYED_VERSION = 6
FLAG_MAC, FLAG_PADDED, FLAG_HANDSHAKE = 0x01, 0x02, 0x04
HEADER = struct.Struct(">2sBBIHHI")  # §2: magic, version, flags, msg_id, index, count, total
HEADER_BYTES = 16
SEAL_BYTES = 32  # slot 16 + tag 16 (§2a)
HELLO_BYTES = 576
MAX_SERVER_MESSAGE = 4 * 1024 * 1024
C2S, S2C = b"\x01", b"\x02"
REPLAY_WINDOW = 4096

OBS_FIELDS = (
    "frame",
    "t",
    "v_host",
    "v_lead",
    "gap",
    "accel",
    "a_lead",
    "force",
    "collision",
    "terminated",
    "truncated",
    "reason",
    "set_speed",
)


class ProtocolError(RuntimeError):
    """The server answered with an error, or never answered."""


# ---------------------------------------------------------------- keys and seals (§2a)


def hkdf(psk: bytes, salt: bytes, label: str, n: int = 32) -> bytes:
    info = b"vacc/6 " + label.encode("ascii")
    return HKDF(algorithm=hashes.SHA256(), length=n, salt=salt, info=info).derive(psk)


@dataclass(frozen=True)
class SessionKeys:
    token: bytes
    c2s: bytes
    s2c: bytes
    answer: bytes

    @property
    def sid(self) -> bytes:
        return self.token[:8]


def session_keys(psk: bytes, nc: bytes, ns: bytes) -> SessionKeys:
    salt = nc + ns
    return SessionKeys(
        token=hkdf(psk, salt, "token", 16),
        c2s=hkdf(psk, salt, "c2s"),
        s2c=hkdf(psk, salt, "s2c"),
        answer=hkdf(psk, salt, "answer"),
    )


def seal(
    key: bytes, header: bytes, slot: bytes, body: bytes, direction: bytes, seq: int | None
) -> bytes:
    """header ‖ slot ‖ ciphertext ‖ tag; nonce 0⁴‖seq, or 12 zero bytes in the handshake."""
    nonce = bytes(12) if seq is None else bytes(4) + seq.to_bytes(8, "big")
    sealed = ChaCha20Poly1305(key).encrypt(nonce, body, header + slot + direction)
    return header + slot + sealed


def unseal(key: bytes, datagram: bytes, direction: bytes, seq: int | None) -> bytes:
    """Open a sealed datagram; raises cryptography's InvalidTag on a bad seal."""
    header, slot = datagram[:HEADER_BYTES], datagram[HEADER_BYTES : HEADER_BYTES + 16]
    nonce = bytes(12) if seq is None else bytes(4) + seq.to_bytes(8, "big")
    return ChaCha20Poly1305(key).decrypt(
        nonce, datagram[HEADER_BYTES + 16 :], header + slot + direction
    )


def read_key_file(path: str) -> bytes:
    with open(path, "rb") as f:
        psk = f.read().strip()
    if len(psk) < 16:
        raise ValueError(f"{path}: key shorter than 16 bytes")
    return psk


# ---------------------------------------------------------------- datagrams (§2)


def header(version: int, flags: int, msg_id: int, index: int, count: int, total: int) -> bytes:
    return HEADER.pack(MAGIC, version, flags, msg_id, index, count, total)


def fragments(payload: bytes, chunk: int) -> list[bytes]:
    if not payload:
        return [b""]
    return [payload[i : i + chunk] for i in range(0, len(payload), chunk)]


def hello_message(
    version: int, nonce: bytes, client: str = "spec", max_datagram: int = 65000
) -> dict:
    return {
        "type": "hello",
        "version": version,
        "nonce": nonce,
        "client": client,
        "image_format": "none",
        "image_width": 0,
        "image_height": 0,
        "max_datagram": max_datagram,
    }


def encode_hello(msg: bytes, msg_id: int, psk: bytes | None, nc: bytes | None) -> bytes:
    """A hello padded to 576 bytes: after the message, or inside the seal with a key."""
    if psk is None:
        hdr = header(UNKEYED_VERSION, FLAG_PADDED, msg_id, 0, 1, len(msg))
        return hdr + msg + bytes(HELLO_BYTES - HEADER_BYTES - len(msg))
    hdr = header(KEYED_VERSION, FLAG_MAC | FLAG_PADDED | FLAG_HANDSHAKE, msg_id, 0, 1, len(msg))
    body = msg + bytes(HELLO_BYTES - HEADER_BYTES - SEAL_BYTES - len(msg))
    return seal(hkdf(psk, nc, "hello"), hdr, nc, body, C2S, None)


def encode_message(
    payload: bytes,
    version: int,
    msg_id: int,
    max_datagram: int,
    keys: SessionKeys | None = None,
    seq: int = 0,
    key: bytes | None = None,
    direction: bytes = C2S,
) -> tuple[list[bytes], int]:
    """Fragment (and with keys, seal) one session message; returns datagrams and next seq.

    ``key``/``direction`` override the C→S key (to seal server messages for test vectors).
    """
    overhead = HEADER_BYTES + (SEAL_BYTES if keys else 0)
    parts = fragments(payload, max_datagram - overhead)
    out = []
    for i, part in enumerate(parts):
        hdr = header(version, FLAG_MAC if keys else 0, msg_id, i, len(parts), len(payload))
        if keys is None:
            out.append(hdr + part)
            continue
        slot = keys.sid + seq.to_bytes(8, "big")
        out.append(seal(key or keys.c2s, hdr, slot, part, direction, seq))
        seq += 1
    return out, seq


class ReplayWindow:
    """RFC 6479-style window: accept unseen numbers less than 4096 below the highest."""

    def __init__(self) -> None:
        self.highest = -1
        self.seen: set[int] = set()

    def check(self, seq: int) -> bool:
        if seq in self.seen or seq <= self.highest - REPLAY_WINDOW:
            return False
        self.seen.add(seq)
        if seq > self.highest:
            self.highest = seq
            self.seen = {s for s in self.seen if s > seq - REPLAY_WINDOW}
        return True


class Reassembler:
    """Fragments keyed by msg_id (one peer); drops inconsistent or stale messages."""

    def __init__(self, timeout: float = 2.0) -> None:
        self.timeout = timeout
        self.partial: dict[int, tuple[float, int, int, dict[int, bytes]]] = {}

    def add(self, msg_id: int, index: int, count: int, total: int, body: bytes) -> bytes | None:
        now = time.monotonic()
        self.partial = {k: v for k, v in self.partial.items() if now - v[0] < self.timeout}
        if count == 1:
            return body[:total] if len(body) >= total else None
        started, cnt, tot, parts = self.partial.setdefault(msg_id, (now, count, total, {}))
        if (cnt, tot) != (count, total) or len(parts.get(index, body)) != len(body):
            del self.partial[msg_id]
            return None
        parts[index] = body
        if len(parts) < count:
            return None
        del self.partial[msg_id]
        whole = b"".join(parts[i] for i in range(count))
        return whole if len(whole) == total else None


# ---------------------------------------------------------------- re-send timing (§5)


class RetransmitTimer:
    """RFC 6298 estimator with Karn's rule, 2 ms floor, back-off doubling up to 0.5 s."""

    def __init__(self, initial: float) -> None:
        self.initial = initial
        self.srtt: float | None = None
        self.rttvar = 0.0
        self.backed_off: float | None = None

    def first_timeout(self) -> float:
        if self.backed_off is not None:
            return self.backed_off
        if self.srtt is None:
            return self.initial
        return max(0.002, self.srtt + 4 * self.rttvar)

    def answered(self, rtt: float, resent: bool, timeout: float) -> None:
        if resent:
            self.backed_off = timeout  # kept until a request is answered without a re-send
            return
        self.backed_off = None
        if self.srtt is None:
            self.srtt, self.rttvar = rtt, rtt / 2
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - rtt)
            self.srtt = 0.875 * self.srtt + 0.125 * rtt


# ---------------------------------------------------------------- the client


@dataclass
class Faults:
    """Optional client-side send faults, to exercise the server's idempotence too."""

    drop: float = 0.0
    dup: float = 0.0
    seed: int = 0
    rng: random.Random = field(init=False)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)


class SpecClient:
    """One session over one UDP socket: hello, reset, step, close (§7)."""

    def __init__(
        self,
        server: tuple[str, int],
        psk: bytes | None = None,
        give_up: float = 5.0,
        max_datagram: int = 65000,
        faults: Faults | None = None,
        client_name: str = "spec-cleanroom",
    ) -> None:
        self.server = server
        self.psk = psk
        self.give_up = give_up
        self.max_datagram = max_datagram
        self.faults = faults or Faults()
        self.client_name = client_name
        family = socket.AF_INET6 if ":" in server[0] else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sock.bind(("::1" if family == socket.AF_INET6 else "127.0.0.1", 0))
        self.version = KEYED_VERSION if psk else UNKEYED_VERSION
        self.next_msg_id = 1
        self.token: bytes | None = None
        self.keys: SessionKeys | None = None
        self.send_seq = 0
        self.window = ReplayWindow()
        self.reasm = Reassembler()
        self.step_timer = RetransmitTimer(0.020)
        self.reset_timer = RetransmitTimer(0.250)
        self.welcome: dict | None = None
        self.episode = -1
        self.frame: int | None = None
        self.resends = 0
        self.busy_answers = 0

    # -- sending

    def _msg_id(self) -> int:
        msg_id = self.next_msg_id
        self.next_msg_id = (self.next_msg_id + 1) & 0xFFFFFFFF
        return msg_id

    def _datagrams(self, msg: dict, msg_id: int) -> list[bytes]:
        """Encode a session message; sealed ones take a fresh seq per transmission."""
        payload = msgpack.packb(msg, use_bin_type=True)
        out, self.send_seq = encode_message(
            payload, self.version, msg_id, self.max_datagram, self.keys, self.send_seq
        )
        return out

    def _send_raw(self, datagram: bytes) -> None:
        if self.faults.rng.random() < self.faults.drop:
            return
        self.sock.sendto(datagram, self.server)
        if self.faults.rng.random() < self.faults.dup:
            self.sock.sendto(datagram, self.server)

    # -- receiving

    def _open(self, datagram: bytes) -> tuple[int, int, int, int, bytes] | None:
        """Check form and seal; return (msg_id, index, count, total, body) or None."""
        if len(datagram) < HEADER_BYTES:
            return None
        magic, version, flags, msg_id, index, count, total = HEADER.unpack_from(datagram)
        if magic != MAGIC or version != self.version or not 0 <= index < count:
            return None
        if total > MAX_SERVER_MESSAGE:
            return None
        if self.psk is None:
            body = datagram[HEADER_BYTES:]
        else:
            body = self._open_sealed(datagram, flags)
            if body is None:
                return None
        if flags & FLAG_PADDED and count == 1:
            body = body[:total]
        return msg_id, index, count, total, body

    def _open_sealed(self, datagram: bytes, flags: int) -> bytes | None:
        if len(datagram) < HEADER_BYTES + SEAL_BYTES or not flags & FLAG_MAC:
            return None
        slot = datagram[HEADER_BYTES : HEADER_BYTES + 16]
        try:
            if flags & FLAG_HANDSHAKE:
                if self.keys is not None or self._hello_nc is None:
                    return None
                keys = session_keys(self.psk, self._hello_nc, slot)
                body = unseal(keys.answer, datagram, S2C, None)
                self._pending_keys = keys
                return body
            if self.keys is None or slot[:8] != self.keys.sid:
                return None
            seq = int.from_bytes(slot[8:], "big")
            body = unseal(self.keys.s2c, datagram, S2C, seq)
        except Exception:  # InvalidTag: never answered, just dropped
            return None
        return body if self.window.check(seq) else None

    def _receive(self, deadline: float) -> dict | None:
        """Next whole message from the server before the deadline, else None."""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.sock.settimeout(left)
            try:
                datagram, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                return None
            if addr[:2] != self.server[:2]:
                continue
            opened = self._open(datagram)
            if opened is None:
                continue
            whole = self.reasm.add(*opened)
            if whole is None:
                continue
            try:
                msg = msgpack.unpackb(whole, raw=False)
            except Exception:
                continue
            if isinstance(msg, dict) and isinstance(msg.get("type"), str):
                return msg

    # -- request/reply with re-sends (§5)

    def _exchange(self, make, accept, timer: RetransmitTimer | None, what: str) -> dict:
        """Send make(msg_id) until accept(reply) is true; re-send on timeout with back-off."""
        msg_id = self._msg_id()
        timeout = timer.first_timeout() if timer else 0.020
        start = time.monotonic()
        sent_at, resent = start, False
        for d in make(msg_id):
            self._send_raw(d)
        while True:
            now = time.monotonic()
            if now - start > self.give_up:
                raise ProtocolError(
                    f"no reply from {self.server[0]}:{self.server[1]} to {what}, "
                    f"episode {self.episode}, frame {self.frame}"
                )
            reply = self._receive(min(sent_at + timeout, start + self.give_up))
            if reply is not None and accept(reply):
                if timer:
                    timer.answered(time.monotonic() - sent_at, resent, timeout)
                return reply
            if time.monotonic() >= sent_at + timeout:
                timeout = min(0.5, timeout * 2)
                resent, sent_at = True, time.monotonic()
                self.resends += 1
                for d in make(msg_id):
                    self._send_raw(d)

    # -- handshake

    def open(self) -> dict:
        """hello → welcome (keyed: derive the session's keys); BUSY: wait 0.1 s and retry."""
        nonce = os.urandom(8)
        deadline = time.monotonic() + self.give_up
        while True:
            self._hello_nc = os.urandom(16) if self.psk else None
            self._pending_keys = None
            msg = msgpack.packb(
                hello_message(self.version, nonce, self.client_name, self.max_datagram),
                use_bin_type=True,
            )

            def make(msg_id, msg=msg):
                return [encode_hello(msg, msg_id, self.psk, self._hello_nc)]

            def accept(reply):
                return reply["type"] == "error" or (
                    reply["type"] == "welcome" and reply.get("nonce") == nonce
                )

            reply = self._exchange(make, accept, self.step_timer, "hello")
            if reply["type"] == "welcome":
                return self._welcomed(reply)
            if reply.get("code") != 4 or time.monotonic() > deadline:
                raise ProtocolError(f"hello refused: {reply}")
            self.busy_answers += 1
            time.sleep(0.1)

    def _welcomed(self, welcome: dict) -> dict:
        if self.psk is not None:
            keys = self._pending_keys
            if keys is None or welcome["session"] != keys.token:
                raise ProtocolError("welcome's session is not the derived token")
            self.keys, self.send_seq, self.window = keys, 0, ReplayWindow()
        self.token = welcome["session"]
        self.welcome = welcome
        return welcome

    # -- episode

    def _check_error(self, reply: dict) -> dict:
        if reply["type"] == "error":
            raise ProtocolError(f"{reply.get('name')} ({reply.get('code')}): {reply.get('detail')}")
        return reply

    def reset(
        self,
        episode: int,
        seed: int,
        trajectory: str = "test-1",
        scenario: str = "ice",
        duration: float | None = None,
        host_speed: float | None = None,
        gap: float | None = None,
        set_speed: float | None = None,
        preroll: int | None = None,
    ) -> dict:
        msg = {
            "type": "reset",
            "session": self.token,
            "episode": episode,
            "scenario": scenario,
            "seed": seed,
            "trajectory": trajectory,
            "trace_t": None,
            "trace_v": None,
            "duration": duration,
            "host_speed": host_speed,
            "gap": gap,
            "set_speed": set_speed,
            "preroll": preroll,
        }
        first = -(preroll or 0)

        def accept(r):
            if r["type"] == "obs":
                return r.get("episode") == episode and r.get("frame") == first
            return (
                r["type"] == "error"
                and r.get("episode") in (episode, None)
                and r.get("frame") is None
            )

        self.episode, self.frame = episode, None
        reply = self._check_error(
            self._exchange(lambda mid: self._datagrams(msg, mid), accept, self.reset_timer, "reset")
        )
        self.frame = reply["frame"]
        return reply

    def step(self, action: float) -> dict:
        frame, episode = self.frame, self.episode
        msg = {
            "type": "step",
            "session": self.token,
            "episode": episode,
            "frame": frame,
            "action": float(action),
        }

        def accept(r):
            if r["type"] == "obs":
                return r.get("episode") == episode and r.get("frame") == frame + 1
            return r["type"] == "error" and (
                (r.get("episode"), r.get("frame")) in ((episode, frame), (None, None))
            )

        reply = self._check_error(
            self._exchange(lambda mid: self._datagrams(msg, mid), accept, self.step_timer, "step")
        )
        self.frame = reply["frame"]
        return reply

    def close(self, wait: float = 1.0) -> None:
        """Send close and wait (bounded) for its echo; the socket is closed either way."""
        if self.sock.fileno() < 0:
            return
        try:
            if self.token is not None:
                msg = {"type": "close", "session": self.token}
                give_up, self.give_up = self.give_up, wait
                try:
                    self._exchange(
                        lambda mid: self._datagrams(msg, mid),
                        lambda r: r["type"] == "close",
                        self.step_timer,
                        "close",
                    )
                except ProtocolError:
                    pass
                finally:
                    self.give_up = give_up
        finally:
            self.sock.close()


def drive_episode(
    client: SpecClient,
    actions: list[float],
    seed: int,
    trajectory: str,
    duration: float | None,
    scenario: str = "ice",
) -> list[dict]:
    """Reset episode 0 and step the given actions in order; one record per frame."""
    obs = client.reset(0, seed, trajectory, scenario, duration=duration)
    rows = [{k: obs[k] for k in OBS_FIELDS}]
    for u in actions:
        if obs["terminated"] or obs["truncated"]:
            break
        obs = client.step(u)
        rows.append({k: obs[k] for k in OBS_FIELDS})
    return rows


# ---------------------------------------------------------------- SPEC §6 / §6a vectors


def _hex_tokens(line: str) -> list[int]:
    out = []
    for tok in line.split():
        if len(tok) != 2 or any(c not in "0123456789abcdef" for c in tok):
            break
        out.append(int(tok, 16))
    return out


def spec_vectors(spec_text: str) -> dict[str, bytes]:
    """The §6a ```hex NAME blocks and §6's two annotated dumps (keys 'v2-step', 'v2-obs')."""
    out: dict[str, bytes] = {}
    blocks = spec_text.split("```")
    for block in blocks[1::2]:
        first, _, rest = block.partition("\n")
        if first.startswith("hex "):
            out[first[4:].strip()] = bytes(_hex_tokens(rest.replace("\n", " ")))
        elif rest.startswith("56 43 02"):
            data = bytes(b for line in rest.splitlines() for b in _hex_tokens(line))
            out["v2-step" if "v2-step" not in out else "v2-obs"] = data
    return out


def check_spec_vectors(spec_text: str) -> list[str]:
    """Reproduce §6 and §6a byte for byte; returns what was checked (raises on mismatch)."""
    vec = spec_vectors(spec_text)
    psk = b"0123456789abcdef0123456789abcdef"
    nc, ns, nonce = bytes(range(16)), bytes(range(16, 32)), bytes(range(0xA0, 0xA8))
    keys = session_keys(psk, nc, ns)
    expect = {
        "token": "93afe125b1114305cd36e8a5b421c5b0",
        "c2s": "36dc29827ed43e3c3428f9125db96c7280fe3404acb6eb05ee3684f6b292f80a",
        "s2c": "a88e109426f846ded98b03f8d662084a2e43dd5f4826410ae5b06fffb992a53b",
        "answer": "6d632d0f8fce76b3141f15c36f46a23ac4eeff499f05115ae55ad904054450dd",
    }
    for name, hexval in expect.items():
        assert getattr(keys, name).hex() == hexval, name
    done = ["keys"]
    token16 = bytes(range(16))
    step = {"type": "step", "session": token16, "episode": 0, "frame": 7, "action": -0.3}
    got, _ = encode_message(msgpack.packb(step, use_bin_type=True), 2, 42, 65000)
    assert got == [vec["v2-step"]], "§6 step"
    done.append("§6 step (v2, unkeyed)")
    obs_payload = vec["v2-obs"][HEADER_BYTES:]
    assert len(obs_payload) == HEADER.unpack_from(vec["v2-obs"])[6] == 211
    hello = msgpack.packb(hello_message(6, nonce, "spec", 65000), use_bin_type=True)
    assert encode_hello(hello, 1, psk, nc) == vec["hello"], "§6a hello"
    done.append("§6a hello")
    done.append(_check_welcome(vec["welcome"], keys, nonce))
    step["session"] = keys.token
    got, _ = encode_message(msgpack.packb(step, use_bin_type=True), 6, 10, 65000, keys, 8)
    assert got == [vec["step"]], "§6a step"
    done.append("§6a step")
    obs = msgpack.unpackb(obs_payload, raw=False)
    got, _ = encode_message(obs_payload, 6, 10, 65000, keys, 8, key=keys.s2c, direction=S2C)
    assert got == [vec["obs"]], "§6a obs"
    assert unseal(keys.s2c, vec["obs"], S2C, 8) == obs_payload
    assert obs["frame"] == 8 and obs["set_speed"] == 33.5
    done.append("§6a obs")
    return done


def _check_welcome(datagram: bytes, keys: SessionKeys, nonce: bytes) -> str:
    """Open the §6a welcome with the answer key (slot Ns) and check the listed defaults."""
    hdr = HEADER.unpack_from(datagram)
    assert hdr[1:3] == (6, FLAG_MAC | FLAG_HANDSHAKE) and hdr[3] == 1
    assert datagram[16:32] == bytes(range(16, 32))
    body = unseal(keys.answer, datagram, S2C, None)
    assert len(body) == hdr[6]
    msg = msgpack.unpackb(body, raw=False)
    want = {
        "type": "welcome",
        "version": 6,
        "nonce": nonce,
        "session": keys.token,
        "physics_dt": 0.02,
        "control_period": 0.1,
        "image_format": "none",
        "image_width": 0,
        "image_height": 0,
        "max_datagram": 65000,
        "session_timeout": 10.0,
        "seed_salt": 0,
        "traffic": 3,
        "sun_elevation": [0.35, 1.2],
        "server": "vacc-sim/0.1",
    }
    assert msg == want, msg
    resealed = seal(keys.answer, datagram[:16], datagram[16:32], body, S2C, None)
    assert resealed == datagram
    return "§6a welcome (opened, fields, resealed)"
