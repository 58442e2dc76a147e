"""Click option types that the simulator's command line shares with the clients' (click and
:mod:`protocol` only: both sides import it, and neither imports the other)."""

from __future__ import annotations

from typing import Any

import click

from protocol.auth import load_key
from protocol.errors import KeyFileError
from protocol.scenarios import parse_sun_elevation

__all__ = ["SunElevation", "key_option"]


def key_option(key_file: str | None) -> bytes | None:
    """``--key-file``'s key, or None without one: `vacc serve` and `vacc drive` read it alike.

    Raises:
        click.BadParameter: an unreadable or malformed key file, in one line naming the option.
    """
    if key_file is None:
        return None
    try:
        return load_key(key_file)
    except KeyFileError as exc:
        raise click.BadParameter(str(exc), param_hint="--key-file") from None


class SunElevation(click.ParamType):
    """``--sun-elevation LOW,HIGH`` [rad] as a checked range, or one line naming the option (a
    type, not a callback, so that a command invoked from another gets its default converted too).
    ``vacc serve``, ``vacc drive`` and ``vacc evaluate`` share it."""

    name = "LOW,HIGH"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> tuple[float, float]:
        if isinstance(value, tuple):
            return value
        try:
            return parse_sun_elevation(str(value))
        except ValueError as exc:
            self.fail(str(exc), param, ctx)
