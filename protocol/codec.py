"""msgpack codec with strict limits for untrusted bytes.

A message is one msgpack map (see :mod:`protocol.messages`). Before anything is
allocated, :func:`scan` walks the bytes' structure: a map of at most
:data:`MAX_MAP_LEN` string keys whose values are scalars or flat arrays of scalars
(nesting depth at most :data:`MAX_DEPTH`), at most :data:`MAX_OBJECTS` objects in
all. An array longer than :data:`SHORT_ARRAY` must hold floats of one width, so
its check is one C-speed stride over the type bytes rather than a Python loop: a
hostile message costs a few microseconds to refuse whatever its size. Only then
does msgpack decode it, with every length bounded, and the schema is checked.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

import msgpack

from protocol.errors import DecodeError, LimitError, ProtocolError, SchemaError
from protocol.messages import PROTOCOL_VERSION, validate

__all__ = [
    "MAX_MESSAGE_BYTES",
    "MAX_REQUEST_BYTES",
    "MAX_ARRAY_LEN",
    "MAX_MAP_LEN",
    "MAX_STR_LEN",
    "MAX_DEPTH",
    "MAX_OBJECTS",
    "SHORT_ARRAY",
    "encode",
    "decode",
    "scan",
]

MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # [bytes] largest whole message (a 1024x1024x3 image fits)
MAX_ARRAY_LEN = 1 << 17  # longest array: a 36 h trace at 1 Hz, or image_shape
MAX_MAP_LEN = 32  # largest map: the biggest schema has 16 fields
MAX_STR_LEN = 4096  # [bytes] longest string (error details, names)
MAX_DEPTH = 2  # a map (1) of flat arrays (2); nothing nests deeper
MAX_OBJECTS = 2 * MAX_ARRAY_LEN + 2 * MAX_MAP_LEN + 1  # a reset with two full traces
SHORT_ARRAY = 16  # arrays up to this long may mix scalar types (image_shape)
# Client messages carry no image: the largest is a reset with two full float-64
# traces (9 bytes a sample) plus its strings. The server reassembles no more.
MAX_REQUEST_BYTES = 2 * 9 * MAX_ARRAY_LEN + 4 * MAX_STR_LEN  # [bytes] 2 375 680

_FLOAT_WIDTH = {0xCA: 5, 0xCB: 9}  # float 32, float 64: type byte -> element size [bytes]
_LEN = {1: struct.Struct("!B"), 2: struct.Struct("!H"), 4: struct.Struct("!I")}
_CONTAINER, _BAD = 0, 99  # markers in _SIZE


def _size_table() -> tuple[list[int], list[int]]:
    """Per type byte: a scalar's whole size (> 0), minus the width of a str/bin
    length prefix (< 0), :data:`_CONTAINER` or :data:`_BAD`; and the same for keys."""
    size = [_BAD] * 256
    for b in range(256):
        if b <= 0x7F or b >= 0xE0:
            size[b] = 1  # fixint
        elif 0xA0 <= b <= 0xBF:
            size[b] = 1 + (b & 0x1F)  # fixstr
        elif 0x80 <= b <= 0x9F or b in (0xDC, 0xDD, 0xDE, 0xDF):
            size[b] = _CONTAINER
    fixed = {0xC0: 1, 0xC2: 1, 0xC3: 1, 0xCA: 5, 0xCB: 9, 0xCC: 2, 0xCD: 3, 0xCE: 5, 0xCF: 9, 0xD0: 2, 0xD1: 3, 0xD2: 5, 0xD3: 9}
    for b, n in fixed.items():
        size[b] = n
    for b, w in {0xC4: 1, 0xC5: 2, 0xC6: 4, 0xD9: 1, 0xDA: 2, 0xDB: 4}.items():
        size[b] = -w
    key = [size[b] if (0xA0 <= b <= 0xBF or b in (0xD9, 0xDA, 0xDB)) else _BAD for b in range(256)]
    return size, key


_SIZE, _KEY_SIZE = _size_table()
_STR_TYPES = frozenset({0xD9, 0xDA, 0xDB})
_MAP_TYPES = frozenset([*range(0x80, 0x90), 0xDE, 0xDF])


def _read_len(data: bytes, pos: int, width: int) -> int:
    if pos + width > len(data):
        raise DecodeError(f"truncated length at byte {pos}")
    return _LEN[width].unpack_from(data, pos)[0]


def _sized_end(data: bytes, pos: int, width: int) -> int:
    """End of the str or bin with a ``width``-byte length prefix at ``pos``."""
    n = _read_len(data, pos + 1, width)
    limit = MAX_STR_LEN if data[pos] in _STR_TYPES else MAX_MESSAGE_BYTES
    if n > limit:
        raise LimitError(f"string or bin of {n} bytes at byte {pos} exceeds {limit}")
    return pos + 1 + width + n


def _bad(data: bytes, pos: int) -> ProtocolError:
    b = data[pos]
    if _SIZE[b] == _CONTAINER:
        return LimitError(f"nesting deeper than {MAX_DEPTH} at byte {pos}")
    if b == 0xC1:
        return DecodeError(f"reserved msgpack byte 0xc1 at byte {pos}")
    return DecodeError(f"msgpack ext type at byte {pos} is not allowed")


def _container_len(data: bytes, pos: int) -> tuple[bool, int, int]:
    """``(is_map, length, header bytes)`` of the map or array at ``pos``."""
    b = data[pos]
    if b <= 0x9F:
        return b <= 0x8F, b & 0x0F, 1
    width = 2 if b in (0xDC, 0xDE) else 4
    return b in (0xDE, 0xDF), _read_len(data, pos + 1, width), 1 + width


def _array_end(data: bytes, pos: int, n: int) -> int:
    """Where an array of ``n`` scalars starting at ``pos`` ends."""
    if n <= SHORT_ARRAY:
        for _ in range(n):
            s = _SIZE[data[pos]]
            if s > 0 and s != _BAD:
                pos += s
            elif s < 0:
                pos = _sized_end(data, pos, -s)
            else:
                raise _bad(data, pos)
        return pos
    kind = data[pos]
    width = _FLOAT_WIDTH.get(kind)
    if width is None:
        raise LimitError(f"array of {n} elements at byte {pos}: longer than {SHORT_ARRAY} needs floats of one width")
    end = pos + n * width
    types = data[pos:end:width]  # one C-speed stride over the type bytes
    if types.count(kind) != len(types):
        raise LimitError(f"array of {n} elements at byte {pos}: longer than {SHORT_ARRAY} needs floats of one width")
    if end > len(data):
        raise DecodeError(f"array of {n} floats at byte {pos} runs past the message end")
    return end


def _not_a_map(data: bytes) -> None:
    """Raise for a message that is not a map: SchemaError if it is one well-formed
    scalar or flat array, else DecodeError."""
    s = _SIZE[data[0]]
    if s == _CONTAINER:
        _, n, head = _container_len(data, 0)
        if n > MAX_ARRAY_LEN:
            raise LimitError(f"array of {n} elements exceeds {MAX_ARRAY_LEN}")
        end = _array_end(data, head, n)
    elif s == _BAD:
        raise _bad(data, 0)
    else:
        end = s if s > 0 else _sized_end(data, 0, -s)
    if end != len(data):
        raise DecodeError("message is not one msgpack value")
    raise SchemaError("message is not a map")


def scan(data: bytes | bytearray | memoryview) -> int:
    """Check a message's structure without decoding it.

    Returns:
        The number of msgpack objects it holds (map, keys, values, array elements).

    Raises:
        LimitError: if it is too long, nests too deep, holds too many objects, or a
            length inside it exceeds a limit.
        DecodeError: if it is not msgpack with string keys and no trailing bytes.
        SchemaError: if it is not a map.
    """
    if not isinstance(data, bytes):
        data = bytes(data)
    if len(data) > MAX_MESSAGE_BYTES:
        raise LimitError(f"message of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}")
    pos = 0
    try:
        if data[0] not in _MAP_TYPES:
            _not_a_map(data)
        _, entries, pos = _container_len(data, 0)
        if entries > MAX_MAP_LEN:
            raise LimitError(f"map of {entries} entries exceeds {MAX_MAP_LEN}")
        objects = 1 + 2 * entries
        for _ in range(entries):
            s = _KEY_SIZE[data[pos]]
            if s == _BAD:
                raise DecodeError(f"map key at byte {pos} is not a string")
            pos = pos + s if s > 0 else _sized_end(data, pos, -s)
            s = _SIZE[data[pos]]
            if s > 0 and s != _BAD:
                pos += s
            elif s < 0:
                pos = _sized_end(data, pos, -s)
            elif s == _BAD:
                raise _bad(data, pos)
            else:
                is_map, n, head = _container_len(data, pos)
                if is_map:
                    raise LimitError(f"nesting deeper than {MAX_DEPTH} at byte {pos}")
                if n > MAX_ARRAY_LEN:
                    raise LimitError(f"array of {n} elements exceeds {MAX_ARRAY_LEN}")
                objects += n
                if objects > MAX_OBJECTS:
                    raise LimitError(f"message holds more than {MAX_OBJECTS} objects")
                pos = _array_end(data, pos + head, n)
    except IndexError:
        raise DecodeError(f"message truncated at byte {pos}") from None
    if pos != len(data):
        raise DecodeError(f"{len(data) - pos} bytes after the message" if pos < len(data) else "message truncated")
    return objects


def _reject_ext(code: int, data: bytes) -> Any:
    raise DecodeError(f"msgpack ext type {code} is not allowed")


def encode(msg: dict[str, Any]) -> bytes:
    """Pack a message into bytes.

    Raises:
        LimitError: if the packed message is larger than :data:`MAX_MESSAGE_BYTES`.
    """
    data = msgpack.packb(msg, use_bin_type=True)
    if len(data) > MAX_MESSAGE_BYTES:
        raise LimitError(f"message of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}")
    return data


def decode(data: bytes | bytearray | memoryview, check: Callable[[int], None] | None = None, version: int = PROTOCOL_VERSION) -> dict[str, Any]:
    """Check the structure of one message (:func:`scan`), unpack it, check its schema.

    Args:
        data: the whole message.
        check: called with the message's object count before anything is
            unpacked; it may raise (a per-source budget does).
        version: the protocol version it came in (its schema's).

    Raises:
        LimitError: if the bytes, or a length, depth or object count inside them,
            exceed a limit.
        DecodeError: if the bytes are not one msgpack map with string keys.
        SchemaError: if the value is not a valid message.
    """
    objects = scan(data)
    if check is not None:
        check(objects)
    try:
        value = msgpack.unpackb(
            data,
            raw=False,
            use_list=True,
            strict_map_key=True,
            max_str_len=MAX_STR_LEN,
            max_bin_len=MAX_MESSAGE_BYTES,
            max_array_len=MAX_ARRAY_LEN,
            max_map_len=MAX_MAP_LEN,
            max_ext_len=0,
            ext_hook=_reject_ext,
        )
    except (DecodeError, LimitError):
        raise
    except ValueError as exc:
        # msgpack reports exceeded limits and bad bytes as ValueError subclasses.
        text = str(exc)
        if "exceeds max" in text:
            raise LimitError(f"msgpack limit: {text}") from exc
        raise DecodeError(f"not msgpack: {text}") from exc
    except (TypeError, msgpack.UnpackException, RecursionError) as exc:
        raise DecodeError(f"not msgpack: {exc}") from exc
    return validate(value, version)
