"""Errors of the agent client, split as traci does into recoverable and fatal."""

from __future__ import annotations

import errno
import os
from pathlib import Path

__all__ = [
    "ClientError",
    "SessionError",
    "FatalSessionError",
    "ServerTimeout",
    "ServerLaunchError",
    "InputFileError",
    "OutputFileError",
    "write_cause",
    "write_text",
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


# torch.save meets a full disk as a short write and says only this (inline_container.cc)
TORCH_SHORT_WRITE = "unexpected pos"


def write_cause(exc: BaseException) -> str:
    """Why a write failed, in a few words: "no space left on device" for a full disk
    (also torch.save's short write), else the system's words for the errno.

    Args:
        exc: the OSError (or torch's RuntimeError) the write raised.
    """
    number = getattr(exc, "errno", None)
    text = str(exc).strip()
    if number == errno.ENOSPC or "No space left" in text or TORCH_SHORT_WRITE in text:
        return "no space left on device"
    if isinstance(number, int) and number > 0:
        return os.strerror(number).lower()
    first = text.splitlines()[0][:200] if text else ""
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def write_text(path: str | Path, text: str) -> None:
    """``Path(path).write_text(text)``.

    Raises:
        OutputFileError: one line naming the file and the cause (e.g. a full disk).
    """
    try:
        Path(path).write_text(text)
    except OSError as exc:
        raise OutputFileError(f"{path}: could not be written: {write_cause(exc)}") from None
