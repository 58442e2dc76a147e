"""msgpack codec with strict limits for untrusted bytes.

A message is one msgpack map (see :mod:`protocol.messages`). Decoding bounds every
length msgpack could allocate for, rejects ext types and non-string map keys, and
then checks the schema, so a hostile datagram costs at most a bounded parse.
"""

from __future__ import annotations

from typing import Any

import msgpack

from protocol.errors import DecodeError, LimitError
from protocol.messages import validate

__all__ = ["MAX_MESSAGE_BYTES", "MAX_ARRAY_LEN", "MAX_MAP_LEN", "MAX_STR_LEN", "encode", "decode"]

MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # [bytes] largest whole message (a 1024x1024x3 image fits)
MAX_ARRAY_LEN = 1 << 17  # longest array: a 36 h trace at 1 Hz, or image_shape
MAX_MAP_LEN = 32  # largest map: the biggest schema has 16 fields
MAX_STR_LEN = 4096  # [bytes] longest string (error details, names)


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


def decode(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """Unpack and check one message.

    Raises:
        LimitError: if the bytes, or a length inside them, exceed a limit.
        DecodeError: if the bytes are not one msgpack value.
        SchemaError: if the value is not a valid message.
    """
    if len(data) > MAX_MESSAGE_BYTES:
        raise LimitError(f"message of {len(data)} bytes exceeds {MAX_MESSAGE_BYTES}")
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
    return validate(value)
