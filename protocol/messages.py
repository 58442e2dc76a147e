"""Message schemas of the vacc wire protocol (versions 2 to 6).

Every message is a msgpack map with a ``"type"`` tag. This module is the single
source of truth for which fields each type carries and of which wire type; the
codec (:mod:`protocol.codec`) checks every decoded message against it, and
``protocol/SPEC.md`` documents it for implementers in other languages.

Field types use msgpack's vocabulary: ``int``, ``float`` (an int is accepted where a
float is expected), ``bool``, ``str``, ``bin``, ``nil`` and ``array``.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Any

from protocol.errors import SchemaError

__all__ = [
    "PROTOCOL_VERSION",
    "KEYED_VERSION",
    "SUPPORTED_VERSIONS",
    "FIELDS_SINCE",
    "OPTIONAL_FIELDS",
    "MESSAGE_TYPES",
    "ErrorCode",
    "FATAL_CODES",
    "SCHEMAS",
    "validate",
    "schema",
    "for_version",
    "make",
    "error",
]

# 2: reset gained host_speed, gap and set_speed; obs gained set_speed; lead
#    scenarios as trajectory names (protocol/scenarios.py).
# 3: welcome gained seed_salt.
# 4: reset gained preroll: the camera's frames before the controller engages.
# 5: welcome gained traffic and sun_elevation: the road a client drives on, for its run logs.
# 6: keyed sessions: a handshake of fresh nonces from both sides, per-session and
#    per-direction AEAD keys (protocol.auth). Messages are those of version 5.
PROTOCOL_VERSION = 5  # what unkeyed datagrams carry: unkeyed traffic is unchanged since 5
KEYED_VERSION = 6  # the newest version: every version-6 datagram is sealed, and a keyed side speaks only it
# An unkeyed server also speaks 2 to 4 (cheap: only the welcome and the reset differ), so older clients keep working.
SUPPORTED_VERSIONS = (2, 3, 4, 5)

# Image formats a client may ask for in the handshake.
IMAGE_FORMATS = ("none", "rgb", "gray")
MIN_IMAGE_SIDE = 8  # [px] smallest width or height the camera renders
MAX_IMAGE_SIDE = 1024  # [px] largest width or height a client may ask for
TOKEN_BYTES = 16  # session token length
NONCE_BYTES = 8  # handshake nonce length


class ErrorCode(IntEnum):
    """Error codes carried by ``error`` messages.

    Recoverable codes leave the session as it was. A fatal one means the request's
    session does not exist on the server after the reply: it never did
    (BAD_VERSION, NO_SESSION) or the server ended it (INTERNAL); the client starts
    a new handshake, which is answered at once unless another session holds the world.
    """

    BAD_MESSAGE = 1  # a bad hello, or a whole message that is not msgpack, breaks a limit or its schema
    BAD_VERSION = 2  # a datagram or hello of a version the server does not speak (fatal)
    NO_SESSION = 3  # unknown or expired session token (fatal)
    BUSY = 4  # the server's one world is in use by another session
    BAD_FRAME = 5  # step for a frame that is neither current nor the last answered
    BAD_ACTION = 6  # action not finite or outside [-1, 1]
    BAD_RESET = 7  # unknown scenario or trajectory, bad trace, initial condition or set speed
    EPISODE_OVER = 8  # step after the episode terminated or was truncated
    NO_EPISODE = 9  # step before any reset, or for another episode
    INTERNAL = 10  # a bug on the server (fatal)
    SEAT_LOST = 11  # a platoon gave up on a seat: every seat's session is ended (fatal)


FATAL_CODES = frozenset({ErrorCode.BAD_VERSION, ErrorCode.NO_SESSION, ErrorCode.INTERNAL, ErrorCode.SEAT_LOST})

_INT = ("int",)
_FLOAT = ("float",)
_BOOL = ("bool",)
_STR = ("str",)
_BIN = ("bin",)
_OPT_FLOAT = ("float", "nil")
_OPT_INT = ("int", "nil")
_ARRAY = ("array",)
_OPT_ARRAY = ("array", "nil")
_OPT_BIN = ("bin", "nil")

# type tag -> {field: allowed wire types}. Every field is required but OPTIONAL_FIELDS; nil is a value.
SCHEMAS: dict[str, dict[str, tuple[str, ...]]] = {
    # client -> server: open a session
    "hello": {
        "version": _INT,
        "nonce": _BIN,  # NONCE_BYTES random bytes; a repeated hello is answered again
        "client": _STR,  # free-form client name, for logs
        "image_format": _STR,  # one of IMAGE_FORMATS
        "image_width": _INT,  # [px]
        "image_height": _INT,  # [px]
        "max_datagram": _INT,  # [bytes] largest datagram the client accepts
        "seat": _INT,  # optional: the platoon seat asked for, 0 nearest the lead; -1 or absent: the first free one
    },
    # server -> client: session opened
    "welcome": {
        "version": _INT,
        "nonce": _BIN,  # echo of the hello's nonce
        "session": _BIN,  # TOKEN_BYTES token to carry in every later request
        "server": _STR,
        "physics_dt": _FLOAT,  # [s]
        "control_period": _FLOAT,  # [s] simulated time per step
        "image_format": _STR,
        "image_width": _INT,
        "image_height": _INT,
        "max_datagram": _INT,  # [bytes] what the server will send
        "session_timeout": _FLOAT,  # [s] idle time after which the session is freed
        "seed_salt": _INT,  # the server's --seed as mixed into every episode seed (version 3)
        "traffic": _INT,  # cars in each adjacent lane, twice as many oncoming: the server's --traffic (version 5)
        "sun_elevation": _ARRAY,  # [rad] [low, high]: the range of each episode's sun height, the server's --sun-elevation (version 5)
        # a platoon server's only (optional: a single-car server sends none of them)
        "seat": _INT,  # the seat this session drives, 0 nearest the lead
        "seats": _INT,  # the platoon's followers
        "seat_timeout": _FLOAT,  # [s] how long the platoon waits for a seat's action before it gives up
        "join_timeout": _FLOAT,  # [s] how long it waits for every seat's reset
    },
    # client -> server: start episode `episode` (answered with obs frame 0, or -preroll)
    "reset": {
        "session": _BIN,
        "episode": _INT,  # client's episode counter, strictly increasing
        "scenario": _STR,  # "ice" | "ev"
        "seed": _INT,  # world seed: initial conditions, traffic, scenery, random trajectory
        "trajectory": _STR,  # protocol.scenarios.TRAJECTORIES (tests, "random", lead scenarios) | "trace"
        "trace_t": _OPT_ARRAY,  # [s] lead speed trace times when trajectory == "trace"
        "trace_v": _OPT_ARRAY,  # [m/s] lead speed trace values
        "duration": _OPT_FLOAT,  # [s] truncate the episode earlier than the trajectory
        "host_speed": _OPT_FLOAT,  # [m/s] host's initial speed; nil: drawn from the seed
        "gap": _OPT_FLOAT,  # [m] initial gap; nil: drawn from the seed
        "set_speed": _OPT_FLOAT,  # [m/s] cruise set speed; nil: DEFAULT_SET_SPEED (33.5)
        "preroll": _OPT_INT,  # control steps driven before engagement (answered with obs frame -preroll); nil: 0 (version 4)
    },
    # client -> server: apply `action` at frame `frame` (answered with obs frame+1)
    "step": {
        "session": _BIN,
        "episode": _INT,
        "frame": _INT,
        "action": _FLOAT,  # normalised force u in [-1, 1]
    },
    # server -> client: the state of frame `frame`
    "obs": {
        "episode": _INT,
        "frame": _INT,
        "t": _FLOAT,  # [s] simulated time of this frame
        "v_host": _FLOAT,  # [m/s]
        "v_lead": _FLOAT,  # [m/s]
        "gap": _FLOAT,  # [m] bumper to bumper; reward and logging only
        "accel": _FLOAT,  # [m/s^2] host acceleration over the last control period
        "a_lead": _FLOAT,  # [m/s^2] lead acceleration over the last control period
        "force": _FLOAT,  # the u that produced this frame (0 at frame 0)
        "collision": _BOOL,
        "terminated": _BOOL,  # collision or gap > limit
        "truncated": _BOOL,  # end of trajectory or duration
        "reason": _STR,  # "", "collision", "gap", "end"
        "set_speed": _FLOAT,  # [m/s] cruise set speed (a driver input: a policy may use it)
        "image": _OPT_BIN,  # row-major uint8 pixels, or nil for image_format "none"
        "image_shape": _OPT_ARRAY,  # [height, width, channels] or nil
    },
    # client -> server: end the session; answered with a close echo
    "close": {"session": _BIN},
    # either way
    "error": {
        "code": _INT,  # ErrorCode
        "name": _STR,  # ErrorCode name, for humans
        "detail": _STR,
        "fatal": _BOOL,
        "episode": _OPT_INT,
        "frame": _OPT_INT,
    },
    # client -> server keeps an idle session alive; the server echoes it
    "heartbeat": {"session": _BIN, "seq": _INT},
}

MESSAGE_TYPES = frozenset(SCHEMAS)

# Fields a message may leave out: a platoon's seats. A peer that knows nothing of
# platoons never sends or receives them, so they need no new version.
OPTIONAL_FIELDS: frozenset[tuple[str, str]] = frozenset(
    {("hello", "seat"), ("welcome", "seat"), ("welcome", "seats"), ("welcome", "seat_timeout"), ("welcome", "join_timeout")}
)

# (type, field) -> the version that added it; older versions' messages lack it.
FIELDS_SINCE: dict[tuple[str, str], int] = {("welcome", "seed_salt"): 3, ("reset", "preroll"): 4, ("welcome", "traffic"): 5, ("welcome", "sun_elevation"): 5}


def schema(kind: str, version: int = PROTOCOL_VERSION) -> dict[str, tuple[str, ...]] | None:
    """The fields of message type ``kind`` in protocol ``version``, or None for an unknown type."""
    fields = SCHEMAS.get(kind)
    if fields is None or version >= PROTOCOL_VERSION:
        return fields
    return {k: v for k, v in fields.items() if FIELDS_SINCE.get((kind, k), 0) <= version}


def for_version(msg: dict[str, Any], version: int) -> dict[str, Any]:
    """``msg`` without the fields that ``version`` does not have (to answer an older peer)."""
    if version >= PROTOCOL_VERSION:
        return msg
    kind = msg["type"]
    return {k: v for k, v in msg.items() if FIELDS_SINCE.get((kind, k), 0) <= version}


def _wire_type(value: Any) -> str:
    # bool before int: bool is a subclass of int in Python.
    if value is None:
        return "nil"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "str"
    if isinstance(value, (bytes, bytearray, memoryview)):
        return "bin"
    if isinstance(value, (list, tuple)):
        return "array"
    return type(value).__name__


def validate(msg: Any, version: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """Check a decoded value against :data:`SCHEMAS`.

    Args:
        msg: the value msgpack produced.
        version: the protocol version it was sent in (its datagram header's).

    Returns:
        The same map, typed as a message.

    Raises:
        SchemaError: if it is not a map, has an unknown type tag, misses a field,
            has an unknown field, or a field of the wrong wire type.
    """
    if not isinstance(msg, dict):
        raise SchemaError(f"message is a {_wire_type(msg)}, not a map")
    kind = msg.get("type")
    fields = schema(kind, version) if isinstance(kind, str) else None
    if fields is None:
        raise SchemaError(f"unknown message type {kind!r}")
    extra = sorted(set(map(str, msg)) - set(fields) - {"type"})
    missing = sorted(k for k in fields if k not in msg and (kind, k) not in OPTIONAL_FIELDS)
    if extra or missing:
        raise SchemaError(f"{kind}: unknown fields {extra}, missing fields {missing}")
    for name, allowed in fields.items():
        if name not in msg:
            continue  # optional
        got = _wire_type(msg[name])
        if got not in allowed and not (got == "int" and "float" in allowed):
            raise SchemaError(f"{kind}.{name}: expected {'|'.join(allowed)}, got {got}")
    return msg


def make(kind: str, **fields: Any) -> dict[str, Any]:
    """Build a message and check it, for senders that want the check.

    Raises:
        SchemaError: as :func:`validate`.
    """
    return validate({"type": kind, **fields})


def error(
    code: ErrorCode,
    detail: str,
    *,
    episode: int | None = None,
    frame: int | None = None,
) -> dict[str, Any]:
    """Build an ``error`` message for ``code``."""
    return {
        "type": "error",
        "code": int(code),
        "name": code.name,
        "detail": detail,
        "fatal": code in FATAL_CODES,
        "episode": episode,
        "frame": frame,
    }
