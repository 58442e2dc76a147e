"""Live driving by a human: a pygame window, the keyboard, and any SDL joystick or wheel.

pygame (the maintained ``pygame-ce`` fork) is an optional extra: ``pip install
'vacc[human]'``. This module imports it only when a window is opened, so the rest of
the client works without it.

Keyboard (see docs/human.md):

* Up or W: throttle. Down or S: brake. Holding a key ramps the force away from 0 at
  ``RAMP_PRESS`` (full force after 1 s); with no key held it returns toward 0 at
  ``RAMP_RELEASE`` (from full force in 0.5 s). A key that opposes the current sign
  first takes the force back to 0 at the release rate. Both held: brake wins.
* Space: full brake (u = -1) at once, while held.
* Esc, Q or closing the window ends the run cleanly.

Joystick or wheel: the force is ``throttle - brake`` from two pedal axes, each
mapped linearly from its released raw value (0) to its pressed raw value (1), with a
dead zone. The default fits a Logitech G27-style pedal set as SDL sees it on Linux
(throttle axis 1, brake axis 2, raw +1 released, -1 pressed). A pedal out of its
dead zone overrides the keyboard.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_client.drive import StopEpisode
from agent_client.errors import ClientError
from agent_client.session import Session

__all__ = [
    "RAMP_PRESS",
    "RAMP_RELEASE",
    "FORCE_DECIMALS",
    "INSTALL_HINT",
    "PygameMissing",
    "require_pygame",
    "NoDisplay",
    "DISPLAY_VARIABLES",
    "has_display",
    "require_display",
    "ramp",
    "JoystickMap",
    "DrivingWindow",
    "KeyboardController",
]

RAMP_PRESS = 1.0  # [1/s] force rate away from 0 while a pedal key is held: 0 -> 1 in 1 s
RAMP_RELEASE = 2.0  # [1/s] force rate toward 0 with no key held: 1 -> 0 in 0.5 s
FORCE_DECIMALS = 4  # forces are rounded so human-files read cleanly (0.3, not 0.30000000000000004)
LAG_WARN = 0.25  # [s] the overlay warns when the world runs this far behind the wall clock
INSTALL_HINT = "pip install 'vacc[human]'"


class PygameMissing(ImportError, ClientError):
    """pygame is not installed; the message says how to install it."""


def require_pygame() -> Any:
    """Import pygame (quietly) and return the module.

    Raises:
        PygameMissing: if it is not installed.
    """
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError:
        raise PygameMissing(f"live driving needs pygame, which is not installed: {INSTALL_HINT}") from None
    return pygame


class NoDisplay(RuntimeError, ClientError):
    """No display to open a window on; the message says what to set."""


# Where SDL finds a desktop on X11/Wayland systems. SDL_VIDEODRIVER names a driver
# explicitly ("dummy" for headless tests, "kmsdrm" on a bare console).
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")


def has_display(environ: Mapping[str, str] | None = None, platform: str | None = None) -> bool:
    """Whether a window SDL opens can be seen (or a driver was chosen explicitly).

    macOS and Windows always have a desktop; elsewhere one of
    :data:`DISPLAY_VARIABLES` must be set.

    Args:
        environ: the environment to look in (default ``os.environ``).
        platform: the platform to judge (default ``sys.platform``).
    """
    if (sys.platform if platform is None else platform) in ("darwin", "win32", "cygwin"):
        return True
    env = os.environ if environ is None else environ
    return any(env.get(name) for name in DISPLAY_VARIABLES)


def require_display(environ: Mapping[str, str] | None = None, platform: str | None = None) -> None:
    """Refuse to open a window where nobody can see it (see :func:`has_display`).

    Without a display SDL quietly falls back to its offscreen driver: no window, no
    key ever pressed, a run driven at zero force.

    Raises:
        NoDisplay: one line naming the variables.
    """
    if not has_display(environ, platform):
        raise NoDisplay(
            "live driving needs a display, and none is set (DISPLAY, WAYLAND_DISPLAY); "
            "run it on a desktop or with ssh -X, or set SDL_VIDEODRIVER to choose a driver"
        )


def ramp(u: float, throttle: bool, brake: bool, dt: float) -> float:
    """The keyboard force after ``dt`` [s] with the given keys held.

    Away from 0 the force moves at RAMP_PRESS, toward 0 at RAMP_RELEASE; crossing 0
    stops at 0 for that step. Brake wins over throttle.
    """
    target = -1.0 if brake else 1.0 if throttle else 0.0
    if target == 0.0 or u * target < 0.0:
        # Returning toward 0 (released, or reversing): release rate, stop at 0.
        step = RAMP_RELEASE * dt
        return 0.0 if abs(u) <= step else u - math.copysign(step, u)
    return max(-1.0, min(1.0, u + target * RAMP_PRESS * dt))


@dataclass(frozen=True)
class JoystickMap:
    """Which SDL axes are the pedals, and their raw travel.

    ``throttle`` and ``brake`` are SDL axis indices (-1: no such pedal). ``released``
    and ``pressed`` are the raw readings (in [-1, 1]) of a pedal at rest and fully
    down; the G27 on Linux reads +1 at rest and -1 fully pressed. ``deadzone`` is the
    fraction of travel read as 0, so a resting pedal does not creep.
    """

    throttle: int = 1
    brake: int = 2
    released: float = 1.0
    pressed: float = -1.0
    deadzone: float = 0.05

    @classmethod
    def parse(cls, text: str) -> JoystickMap:
        """From ``'throttle=1,brake=2,released=1,pressed=-1,deadzone=0.05'`` (any subset).

        Raises:
            ValueError: on an unknown key or a bad value.
        """
        fields: dict[str, Any] = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            key, sep, value = item.partition("=")
            key = key.strip()
            if not sep or key not in ("throttle", "brake", "released", "pressed", "deadzone"):
                raise ValueError(f"joystick map item {item!r}: expected throttle|brake|released|pressed|deadzone=VALUE")
            try:
                fields[key] = int(value) if key in ("throttle", "brake") else float(value)
            except ValueError:
                raise ValueError(f"joystick map item {item!r}: bad number") from None
        jm = cls(**fields)
        if jm.released == jm.pressed or not all(-1.0 <= x <= 1.0 for x in (jm.released, jm.pressed)):
            raise ValueError("joystick map: released and pressed must differ and lie in [-1, 1]")
        if not 0.0 <= jm.deadzone < 1.0:
            raise ValueError("joystick map: deadzone must be in [0, 1)")
        return jm

    def pedal(self, raw: float) -> float:
        """A pedal's depression in [0, 1] from its raw axis value."""
        travel = (raw - self.released) / (self.pressed - self.released)
        travel = min(1.0, max(0.0, travel))
        return 0.0 if travel <= self.deadzone else (travel - self.deadzone) / (1.0 - self.deadzone)

    def force(self, axes: list[float]) -> float:
        """The force u in [-1, 1] from all raw axis values (throttle - brake)."""

        def read(i: int) -> float:
            return self.pedal(axes[i]) if 0 <= i < len(axes) else 0.0

        return max(-1.0, min(1.0, read(self.throttle) - read(self.brake)))


class DrivingWindow:
    """The pygame window: the camera frame scaled up, with an overlay.

    Args:
        scale: integer zoom of the camera image.
        title: window caption.
        offscreen_ok: open it even without a display (a watched env that nobody
            watches); a human driver needs one.

    Raises:
        PygameMissing: pygame is not installed.
        NoDisplay: there is no display to open the window on.
    """

    def __init__(self, scale: int = 2, title: str = "vacc: drive (Up/Down, Esc to end)", *, offscreen_ok: bool = False):
        self.pg = require_pygame()
        if not offscreen_ok:
            require_display()
        self.scale = scale
        self.title = title
        if not has_display():  # offscreen_ok: SDL's dummy driver, not its probing of absent desktops (XDG_RUNTIME_DIR noise)
            os.environ["SDL_VIDEODRIVER"] = "dummy"
        self.pg.display.init()
        self.pg.font.init()
        self.pg.joystick.init()
        self.screen: Any = None
        self.font = self.pg.font.Font(None, 26)

    def events(self) -> list[Any]:
        """Pending input events."""
        return list(self.pg.event.get())

    def draw(self, image: np.ndarray | None, lines: list[str], warn: str = "") -> None:
        """Show ``image`` (H, W, 3) or (H, W) uint8 with overlay ``lines``."""
        pg = self.pg
        if image is None:
            image = np.zeros((200, 200, 3), dtype=np.uint8)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        h, w = image.shape[:2]
        size = (w * self.scale, h * self.scale)
        if self.screen is None or self.screen.get_size() != size:
            self.screen = pg.display.set_mode(size)
            pg.display.set_caption(self.title)
        frame = pg.surfarray.make_surface(np.ascontiguousarray(image.transpose(1, 0, 2)))
        self.screen.blit(pg.transform.scale(frame, size), (0, 0))
        y = 8
        for text, color in [(s, (255, 255, 255)) for s in lines] + ([(warn, (255, 80, 60))] if warn else []):
            label = self.font.render(text, True, color)
            box = pg.Surface((label.get_width() + 10, label.get_height() + 4), pg.SRCALPHA)
            box.fill((0, 0, 0, 150))
            self.screen.blit(box, (6, y - 2))
            self.screen.blit(label, (11, y))
            y += label.get_height() + 6
        pg.display.flip()

    def close(self) -> None:
        """Close the window; safe to call twice."""
        if self.pg.display.get_init():
            self.pg.display.quit()


class KeyboardController:
    """A human drives: keyboard ramps, or pedals of a joystick/wheel, shown in a window.

    Args:
        control_period: [s] simulated time per step (the welcome's ``control_period``).
        window: the window to draw in and read events from.
        joystick: SDL joystick index to read pedals from if one is plugged in; None: none.
        joystick_map: which axes are the pedals.
        on_frame: called with the frame number before input is read (tests post
            scripted events there).
        clock: wall clock [s], for the overlay's real-time lag.

    Raises (from ``__call__``):
        StopEpisode: Esc, Q or the window was closed.
    """

    def __init__(
        self,
        control_period: float,
        window: DrivingWindow,
        *,
        joystick: int | None = 0,
        joystick_map: JoystickMap | None = None,
        on_frame: Callable[[int], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.control_period = control_period
        self.window = window
        self.joystick_map = joystick_map or JoystickMap()
        self.on_frame = on_frame
        self.clock = clock
        self.stick: Any = None
        pg = window.pg
        if joystick is not None and 0 <= joystick < pg.joystick.get_count():
            self.stick = pg.joystick.Joystick(joystick)
            self.stick.init()
        self.reset()

    name = "keyboard"

    def reset(self) -> None:
        """Release every key and the force."""
        self.u = 0.0
        self.held: set[str] = set()
        self._wall0: float | None = None

    def _read_events(self) -> None:
        pg = self.window.pg
        keys = {pg.K_UP: "throttle", pg.K_w: "throttle", pg.K_DOWN: "brake", pg.K_s: "brake", pg.K_SPACE: "full-brake"}
        for event in self.window.events():
            if event.type == pg.QUIT or (event.type == pg.KEYDOWN and event.key in (pg.K_ESCAPE, pg.K_q)):
                raise StopEpisode()
            if event.type == pg.KEYDOWN and event.key in keys:
                self.held.add(keys[event.key])
            elif event.type == pg.KEYUP and event.key in keys:
                self.held.discard(keys[event.key])
            elif event.type == getattr(pg, "WINDOWFOCUSLOST", -1):
                self.held.clear()  # key-ups are lost while another window has focus

    def _axes(self) -> list[float]:
        if self.stick is None:
            return []
        return [float(self.stick.get_axis(i)) for i in range(self.stick.get_numaxes())]

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force for this frame: read input, ramp, draw, return u in [-1, 1]."""
        frame = int(obs["frame"])
        if self.on_frame is not None:
            self.on_frame(frame)
        self._read_events()
        self.u = ramp(self.u, "throttle" in self.held, "brake" in self.held, self.control_period)
        if "full-brake" in self.held:
            self.u = -1.0
        axes = self._axes()
        pedals = self.joystick_map.force(axes)
        u = pedals if pedals != 0.0 else self.u
        u = round(max(-1.0, min(1.0, u)), FORCE_DECIMALS) + 0.0  # + 0.0: no "-0.0" in files

        now = self.clock()
        if self._wall0 is None:
            self._wall0 = now - float(obs["t"])
        lag = (now - self._wall0) - float(obs["t"])  # > 0: the world is behind the wall clock
        lines = [
            f"t {obs['t']:6.1f} s   speed {obs['v_host']:5.2f} m/s ({obs['v_host'] * 3.6:5.1f} km/h)",
            f"gap {obs['gap']:6.1f} m   lead {obs['v_lead']:5.2f} m/s",
            f"force {u:+.2f}" + ("   [pedals]" if pedals != 0.0 else ""),
        ]
        if axes:
            lines.append("axes " + " ".join(f"{a:+.2f}" for a in axes))
        warn = f"behind real time by {lag:.1f} s" if lag > LAG_WARN else ""
        self.window.draw(Session.image(obs), lines, warn)
        return u
