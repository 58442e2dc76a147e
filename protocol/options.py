"""Click option types that the simulator's command line shares with the clients' (click and
:mod:`protocol` only: both sides import it, and neither imports the other)."""

from __future__ import annotations

from typing import Any

import click

from protocol.scenarios import parse_sun_elevation

__all__ = ["SunElevation"]


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
