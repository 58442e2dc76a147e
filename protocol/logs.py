"""Log levels of the vacc programs, one list for both sides.

``vacc serve --log-level``, the ``vacc`` group's ``-v``/``--log-level`` (the client) and
the launcher, which passes a level to every server it spawns, all take these.
"""

from __future__ import annotations

__all__ = ["LOG_LEVELS"]

LOG_LEVELS = ("debug", "info", "warning", "error")
