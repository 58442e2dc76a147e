"""Errors of the agent client, split as traci does into recoverable and fatal."""

from __future__ import annotations

__all__ = [
    "ClientError",
    "SessionError",
    "FatalSessionError",
    "ServerTimeout",
    "ServerLaunchError",
    "InputFileError",
    "OutputFileError",
    "ResumeError",
]


class ClientError(Exception):
    """Base class of every error raised by :mod:`agent_client`."""


class SessionError(RuntimeError, ClientError):
    """The server refused one request; the session goes on (e.g. a bad reset)."""

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.code = code


class FatalSessionError(ConnectionError, ClientError):
    """The session is gone: the server refused it, lost it, or stopped answering."""

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.code = code


class ServerTimeout(TimeoutError, FatalSessionError):
    """No reply within the session's bounded give-up time."""


class ServerLaunchError(RuntimeError, ClientError):
    """A local server process could not be started."""


class InputFileError(ValueError, ClientError):
    """A user file (trace, human-file, checkpoint) is malformed; the message names file and line."""


class OutputFileError(OSError, ClientError):
    """An output file (a log, a checkpoint, a run folder's file) could not be written;
    the message names it and says why, in one line."""


class ResumeError(RuntimeError, ClientError):
    """A run could not be taken up exactly where it stopped; the message says where it parted."""
