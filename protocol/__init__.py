"""The vacc wire protocol, shared by the simulator server and its clients.

It imports neither side. See ``protocol/SPEC.md`` for the full specification.
"""

from protocol.auth import load_key
from protocol.codec import decode, encode, scan
from protocol.errors import (
    AuthError,
    DecodeError,
    FragmentError,
    KeyFileError,
    LimitError,
    ProtocolError,
    ReplayError,
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
    "AuthError",
    "ReplayError",
    "KeyFileError",
    "encode",
    "decode",
    "scan",
    "load_key",
    "make",
    "validate",
    "Reassembler",
]
