"""The sealed test vectors of protocol/SPEC.md §6a, byte for byte (issue #55, item 3).

Two checks: the implementation reproduces every vector exactly, and each vector
opens with a key schedule written out here from the SPEC's words alone (standard
library HKDF, the ``cryptography`` AEAD), so a third-party client can check itself
against the same bytes. ``python tests/protocol/test_spec_vectors.py`` prints the
vectors in the SPEC's form.
"""

from __future__ import annotations

import hashlib
import hmac
import re
from pathlib import Path

from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

from protocol import codec
from protocol.auth import TRAILER_BYTES, Channel, seal_hello, session_keys
from protocol.fragment import FLAG_HANDSHAKE, FLAG_MAC, HELLO_BYTES, fragment, pad
from protocol.messages import KEYED_VERSION

SPEC = Path(__file__).resolve().parents[2] / "protocol" / "SPEC.md"
PSK = b"0123456789abcdef0123456789abcdef"
NC = bytes(range(0x00, 0x10))
NS = bytes(range(0x10, 0x20))
HELLO_NONCE = bytes(range(0xA0, 0xA8))


def messages(token: bytes) -> dict[str, dict]:
    return {
        "hello": {"type": "hello", "version": 6, "nonce": HELLO_NONCE, "client": "spec", "image_format": "none", "image_width": 0, "image_height": 0, "max_datagram": 65000},
        "welcome": {"type": "welcome", "version": 6, "nonce": HELLO_NONCE, "session": token, "server": "vacc-sim/0.1", "physics_dt": 0.02, "control_period": 0.1,
                    "image_format": "none", "image_width": 0, "image_height": 0, "max_datagram": 65000, "session_timeout": 10.0, "seed_salt": 0, "traffic": 3, "sun_elevation": [0.35, 1.2]},
        "step": {"type": "step", "session": token, "episode": 0, "frame": 7, "action": -0.3},
        "obs": {"type": "obs", "episode": 0, "frame": 8, "t": 0.8, "v_host": 29.5, "v_lead": 30.0, "gap": 52.25, "accel": -1.65, "a_lead": 0.0, "force": -0.3,
                "collision": False, "terminated": False, "truncated": False, "reason": "", "set_speed": 33.5, "image": None, "image_shape": None},
    }  # fmt: skip


# A run without re-sends: hello (msg_id 1), reset (2, seq 0), steps of frames 0..7 (3..10, seqs 1..8);
# welcome (1), obs of frame 0 (2, seq 0), obs of frames 1..8 (3..10, seqs 1..8).
MSG_IDS = {"hello": 1, "welcome": 1, "step": 10, "obs": 10}
SEQS = {"step": 8, "obs": 8}


def plain(kind: str, msg: dict) -> bytes:
    flags = FLAG_MAC | (FLAG_HANDSHAKE if kind in ("hello", "welcome") else 0)
    return fragment(codec.encode(msg), MSG_IDS[kind], flags=flags, trailer=TRAILER_BYTES, version=KEYED_VERSION)[0]


def build_vectors() -> dict[str, bytes]:
    """The four sealed datagrams, made with the implementation."""
    keys = session_keys(PSK, NC, NS)
    msgs = messages(keys.token)
    hello = seal_hello(PSK, NC, pad(plain("hello", msgs["hello"]), HELLO_BYTES - TRAILER_BYTES))
    welcome = keys.seal(plain("welcome", msgs["welcome"]))
    client, server = Channel(keys, client=True), Channel(keys, client=False)
    for _ in range(SEQS["step"]):
        client.seal(b"")  # spend the numbers of the earlier requests
    for _ in range(SEQS["obs"]):
        server.seal(b"")
    return {"hello": hello, "welcome": welcome, "step": client.seal(plain("step", msgs["step"])), "obs": server.seal(plain("obs", msgs["obs"]))}


def spec_vectors() -> dict[str, bytes]:
    text = SPEC.read_text()
    blocks = re.findall(r"```hex (\w+)\n(.*?)```", text, re.S)
    return {name: bytes.fromhex(" ".join(line.split("|")[0] for line in body.splitlines())) for name, body in blocks}


def test_the_implementation_reproduces_the_specs_vectors():
    stated, made = spec_vectors(), build_vectors()
    assert set(stated) == {"hello", "welcome", "step", "obs"}
    for name in made:
        assert stated[name] == made[name], f"{name}: SPEC §6a and the implementation differ"


def hkdf(salt: bytes, label: str, length: int = 32) -> bytes:
    """HKDF-SHA256 (RFC 5869) of the PSK, as SPEC §2a states it."""
    prk = hmac.new(salt, PSK, hashlib.sha256).digest()
    return hmac.new(prk, b"vacc/6 " + label.encode() + b"\x01", hashlib.sha256).digest()[:length]


def test_the_vectors_open_with_the_specs_key_schedule_alone():
    v = spec_vectors()
    token = hkdf(NC + NS, "token", 16)

    def opens(datagram: bytes, key: bytes, direction: int, nonce: bytes) -> bytes:
        head = datagram[:32]
        return ChaCha20Poly1305(key).decrypt(nonce, datagram[32:], head + bytes([direction]))

    hello = opens(v["hello"], hkdf(NC, "hello"), 1, bytes(12))
    assert len(v["hello"]) == 576 and v["hello"][16:32] == NC
    assert codec.msgpack.unpackb(hello[: int.from_bytes(v["hello"][12:16], "big")])["client"] == "spec"
    welcome = codec.decode(opens(v["welcome"], hkdf(NC + NS, "answer"), 2, bytes(12)), version=6)
    assert welcome["session"] == token and v["welcome"][16:32] == NS
    step = codec.decode(opens(v["step"], hkdf(NC + NS, "c2s"), 1, bytes(4) + v["step"][24:32]), version=6)
    assert step["action"] == -0.3 and v["step"][16:24] == token[:8]
    obs = codec.decode(opens(v["obs"], hkdf(NC + NS, "s2c"), 2, bytes(4) + v["obs"][24:32]), version=6)
    assert obs["frame"] == 8 and v["obs"][16:24] == token[:8]


def hex_lines(data: bytes) -> str:
    return "\n".join(" ".join(f"{b:02x}" for b in data[i : i + 16]) for i in range(0, len(data), 16))


if __name__ == "__main__":
    keys = session_keys(PSK, NC, NS)
    for name, label in (("token", keys.token), ("c2s", keys.c2s), ("s2c", keys.s2c), ("answer", keys.answer)):
        print(f"{name}: {label.hex(' ')}")
    for name, data in build_vectors().items():
        print(f"\n{name} ({len(data)} bytes)\n```hex {name}\n{hex_lines(data)}\n```")
