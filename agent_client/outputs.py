"""Output files and folders: checked before a run starts, and a failed write said in one line.

A path that cannot be written (``--log /proc/x.csv``, ``--out`` in a read-only place) is
refused before any work, naming the option and the path; a write that fails later (a
full disk) names the file and says why, never as a traceback.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

import click

from agent_client.errors import OutputFileError

__all__ = ["write_cause", "write_text", "unwritable_file", "unwritable_dir", "writable_file_option", "writable_dir_option"]

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


def unwritable_file(path: str | Path) -> str | None:
    """Why ``path`` cannot be written as a file (its folder made if missing), or None.
    Leaves nothing behind: an existing file is opened for appending (not changed), a new
    one created and removed.

    Args:
        path: the file a run will write.
    """
    p = Path(path)
    if p.is_dir():
        return "is a folder"
    if not p.parent.exists():  # made by the run: probe where it will be made
        return unwritable_dir(p.parent)
    existed = p.exists()
    try:
        with open(p, "ab"):
            pass
    except OSError as exc:
        return write_cause(exc)
    if not existed:
        p.unlink(missing_ok=True)
    return None


def unwritable_dir(path: str | Path) -> str | None:
    """Why files cannot be written in the folder ``path`` (made if missing), or None.
    Creates nothing: it probes the nearest existing folder above with a temporary file.

    Args:
        path: the folder a run will write in.
    """
    p = Path(path).absolute()
    ancestor = p
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        return f"{ancestor} is not a folder"
    try:
        with tempfile.TemporaryFile(dir=ancestor):
            pass
    except OSError as exc:
        return write_cause(exc) if ancestor == p else f"{ancestor}: {write_cause(exc)}"
    return None


def _refuse(param: click.Parameter, value: str, why: str) -> click.ClickException:
    return click.ClickException(f"{param.opts[0]} {value}: cannot be written: {why}")


def writable_file_option(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """Click callback: an output file that cannot be written is refused in one line.

    Raises:
        click.ClickException: naming the option, the path and why.
    """
    if value is not None and (why := unwritable_file(value)) is not None:
        raise _refuse(param, value, why)
    return value


def writable_dir_option(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """Click callback: an output folder that cannot be made or written in is refused in one line.

    Raises:
        click.ClickException: naming the option, the path and why.
    """
    if value is not None and (why := unwritable_dir(value)) is not None:
        raise _refuse(param, value, why)
    return value
