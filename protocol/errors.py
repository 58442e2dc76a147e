"""Errors of the wire format.

Every error subclasses both :class:`ProtocolError` and a builtin, as msgpack does,
so callers can catch either the package base or the familiar builtin.
"""

from __future__ import annotations

__all__ = [
    "ProtocolError",
    "DecodeError",
    "SchemaError",
    "LimitError",
    "FragmentError",
    "VersionError",
    "AuthError",
    "ReplayError",
    "ForeignSessionError",
    "KeyFileError",
]


class ProtocolError(Exception):
    """Base class of every error raised by :mod:`protocol`."""


class DecodeError(ValueError, ProtocolError):
    """Bytes that are not a valid message (bad header, bad msgpack)."""


class SchemaError(ValueError, ProtocolError):
    """A well-formed msgpack value that is not a valid message of its type."""


class LimitError(ValueError, ProtocolError):
    """A size or count limit was exceeded."""


class FragmentError(ValueError, ProtocolError):
    """A fragment header is inconsistent with the message it belongs to."""


class VersionError(ValueError, ProtocolError):
    """The peer speaks another protocol version."""


class AuthError(ValueError, ProtocolError):
    """A datagram's MAC is missing, wrong, or present where no key is set."""


class ReplayError(AuthError):
    """An authentic datagram whose sequence number was already seen or is too old."""


class ForeignSessionError(AuthError):
    """A sealed datagram of another session (or none this side knows), or from another address than its session's."""


class KeyFileError(ValueError, ProtocolError):
    """A shared key file that cannot be read or is too short."""
