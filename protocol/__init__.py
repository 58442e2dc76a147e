"""The vacc wire protocol, shared by the simulator server and its clients.

It imports neither side. See ``protocol/SPEC.md`` for the full specification.
"""

from protocol.codec import decode, encode
from protocol.errors import (
    DecodeError,
    FragmentError,
    LimitError,
    ProtocolError,
    SchemaError,
    VersionError,
)
from protocol.fragment import DEFAULT_DATAGRAM, Reassembler
from protocol.messages import PROTOCOL_VERSION, ErrorCode, make, validate

__all__ = [
    "PROTOCOL_VERSION",
    "DEFAULT_DATAGRAM",
    "ErrorCode",
    "ProtocolError",
    "DecodeError",
    "SchemaError",
    "LimitError",
    "FragmentError",
    "VersionError",
    "encode",
    "decode",
    "make",
    "validate",
    "Reassembler",
]
