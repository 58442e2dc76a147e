"""Live driving: keyboard ramps, joystick mapping, and scripted key events through the real CLI.

Headless: SDL's dummy video driver. Tests that need pygame skip without it; the
dev extra installs it, so they run in CI.
"""

from __future__ import annotations

import functools
import os
import re
import sys

import pytest
from click.testing import CliRunner

from agent_client import cli
from agent_client.controllers import keyboard as kb
from agent_client.controllers.human_file import MAGIC, read_human_file
from agent_client.errors import ClientError

os.environ["SDL_VIDEODRIVER"] = "dummy"
os.environ["SDL_AUDIODRIVER"] = "dummy"


@pytest.fixture
def pygame():
    pg = pytest.importorskip("pygame")
    yield pg
    pg.quit()


def _run(*args: str):
    return CliRunner().invoke(cli.drive, list(args), catch_exceptions=False)


# -- pure logic -------------------------------------------------------------------


def test_ramp_rates():
    dt = 0.1  # [s]
    u = 0.0
    for _ in range(10):
        u = kb.ramp(u, throttle=True, brake=False, dt=dt)
    assert u == pytest.approx(1.0)  # full throttle after 1 s held (RAMP_PRESS)
    for _ in range(4):
        u = kb.ramp(u, throttle=False, brake=False, dt=dt)
    assert u == pytest.approx(0.2)  # back toward 0 at RAMP_RELEASE
    u = kb.ramp(u, throttle=False, brake=False, dt=dt)
    assert u == 0.0  # stops at 0, never overshoots
    u = kb.ramp(0.5, throttle=False, brake=True, dt=dt)
    assert u == pytest.approx(0.3)  # reversing: first back to 0 at the release rate
    assert kb.ramp(0.0, throttle=True, brake=True, dt=dt) == pytest.approx(-0.1)  # brake wins
    assert kb.ramp(-1.0, throttle=False, brake=True, dt=dt) == -1.0


def test_joystick_map_g27_default():
    jm = kb.JoystickMap()
    assert jm.force([0.3, 1.0, 1.0]) == 0.0  # pedals at rest read +1
    assert jm.force([0.0, -1.0, 1.0]) == 1.0  # throttle floored
    assert jm.force([0.0, 1.0, -1.0]) == -1.0  # brake floored
    assert jm.force([0.0, 0.0, 1.0]) == pytest.approx((0.5 - 0.05) / 0.95)  # half throttle, dead zone
    assert jm.force([0.0, 0.95, 1.0]) == 0.0  # inside the dead zone
    assert jm.force([]) == 0.0  # no joystick


def test_joystick_map_parse():
    jm = kb.JoystickMap.parse("throttle=2, brake=3, released=-1, pressed=1, deadzone=0")
    assert (jm.throttle, jm.brake, jm.released, jm.pressed, jm.deadzone) == (2, 3, -1.0, 1.0, 0.0)
    assert jm.force([0, 0, 1.0, -1.0]) == 1.0
    for bad in ("gas=1", "throttle=x", "released=1,pressed=1", "deadzone=1"):
        with pytest.raises(ValueError):
            kb.JoystickMap.parse(bad)
    result = _run("--controller", "keyboard", "--joystick-map", "gas=1", "--log", "x.csv")
    assert result.exit_code != 0 and "gas=1" in result.output


def test_without_pygame_the_error_says_how_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame raises ImportError
    with pytest.raises(kb.PygameMissing, match=r"pip install 'vacc\[human\]'"):
        kb.require_pygame()
    assert issubclass(kb.PygameMissing, ClientError)
    result = _run("--controller", "keyboard", "--log", str(tmp_path / "log.csv"))
    assert result.exit_code != 0
    assert "pip install 'vacc[human]'" in result.output and "Traceback" not in result.output


@pytest.mark.parametrize("name", kb.DISPLAY_VARIABLES)
def test_a_display_or_an_explicit_sdl_driver_is_enough(name):
    kb.require_display({name: ":0" if name == "DISPLAY" else "x"}, platform="linux")


def test_no_display_is_refused():
    with pytest.raises(kb.NoDisplay, match=r"needs a display.*DISPLAY, WAYLAND_DISPLAY.*SDL_VIDEODRIVER"):
        kb.require_display({"DISPLAY": "", "HOME": "/root"}, platform="linux")
    assert issubclass(kb.NoDisplay, ClientError)
    kb.require_display({}, platform="darwin")  # a desktop is always there
    kb.require_display({}, platform="win32")


def test_keyboard_without_a_display_fails_in_one_line_before_any_server(monkeypatch, pygame, tmp_path):
    # Before: SDL's offscreen fallback drove a whole episode at zero force and exited 0.
    for name in kb.DISPLAY_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    result = _run("--controller", "keyboard", "--log", str(tmp_path / "log.csv"), "--duration", "1")
    assert result.exit_code == 1
    errors = [line for line in result.output.splitlines() if line]
    assert errors == [errors[0]] and errors[0].startswith("Error: live driving needs a display"), result.output
    assert not (tmp_path / "log.csv").exists()


# -- scripted key events through `vacc drive --controller keyboard` ----------------------


def _script(monkeypatch, pg, script: dict[int, list[tuple[int, int]]]) -> None:
    """Before input is read at frame n, post the pygame events script[n]."""

    def on_frame(frame: int) -> None:
        for kind, key in script.get(frame, []):
            pg.event.post(pg.event.Event(kind) if kind == pg.QUIT else pg.event.Event(kind, key=key))

    monkeypatch.setattr(cli, "KeyboardController", functools.partial(kb.KeyboardController, on_frame=on_frame))


def test_scripted_keys_drive_record_and_replay_byte_identical(monkeypatch, pygame, tmp_path):
    pg = pygame
    _script(monkeypatch, pg, {
        2: [(pg.KEYDOWN, pg.K_UP)], 12: [(pg.KEYUP, pg.K_UP)],
        20: [(pg.KEYDOWN, pg.K_DOWN)], 25: [(pg.KEYUP, pg.K_DOWN)],
        35: [(pg.KEYDOWN, pg.K_SPACE)], 37: [(pg.KEYUP, pg.K_SPACE)],
    })  # fmt: skip
    live, human, replay = tmp_path / "live.csv", tmp_path / "human.csv", tmp_path / "replay.csv"
    result = _run("--controller", "keyboard", "--no-realtime", "--duration", "5", "--log", str(live), "--record", str(human))
    assert result.exit_code == 0, result.output
    hf = read_human_file(human)
    assert hf.header.scenario == "ice" and hf.header.trajectory == "test-1" and hf.header.duration == 5.0
    assert "# controller=keyboard" in human.read_text()
    u = hf.forces
    assert len(u) == 50
    assert u[:2] == (0.0, 0.0)
    assert u[2:12] == tuple(round(0.1 * k, 4) for k in range(1, 11))  # ramp up, full after 1 s
    assert u[12:17] == (0.8, 0.6, 0.4, 0.2, 0.0)  # released: back to 0 in 0.5 s
    assert u[20:25] == (-0.1, -0.2, -0.3, -0.4, -0.5)  # brake ramp
    assert u[35:37] == (-1.0, -1.0)  # space: full brake at once
    assert u[-1] == 0.0
    # The log carries the forces too, one frame later (force is what produced the frame).
    log_forces = [float(r.split(",")[6]) for r in live.read_text().splitlines()[1:]]
    assert log_forces[1:] == list(u)

    result = _run("--controller", "human-file", "--human-file", str(human), "--log", str(replay), "--quiet")
    assert result.exit_code == 0, result.output
    assert replay.read_bytes() == live.read_bytes()


@pytest.mark.parametrize("how", ["escape", "close"])
def test_escape_or_closing_the_window_ends_cleanly(monkeypatch, pygame, tmp_path, how):
    pg = pygame
    event = (pg.KEYDOWN, pg.K_ESCAPE) if how == "escape" else (pg.QUIT, 0)
    _script(monkeypatch, pg, {3: [(pg.KEYDOWN, pg.K_UP)], 10: [event]})
    live, human = tmp_path / "live.csv", tmp_path / "human.csv"
    result = _run("--controller", "keyboard", "--no-realtime", "--log", str(live), "--record", str(human))
    assert result.exit_code == 0, result.output
    assert "stopped" in result.output
    assert len(live.read_text().splitlines()) == 1 + 11  # frames 0..10: Esc read at frame 10
    text = human.read_text()
    assert text.startswith(MAGIC) and text.splitlines()[-1] == "9,0.7"  # forces for frames 0..9
    # Replaying a run that was cut short: the file ends before the trajectory.
    result = _run("--controller", "human-file", "--human-file", str(human), "--log", str(tmp_path / "r.csv"))
    assert result.exit_code != 0 and "ends at frame 9" in result.output


def test_realtime_pacing_by_default(monkeypatch, pygame, tmp_path):
    _script(monkeypatch, pygame, {})
    result = _run("--controller", "keyboard", "--duration", "1.5", "--log", str(tmp_path / "rt.csv"))
    assert result.exit_code == 0, result.output
    wall = float(re.search(r"wall time\s+([0-9.]+) s", result.output).group(1))  # reset to end, no start-up
    assert 1.4 <= wall < 3.0  # the spawned server paced 15 steps of 0.1 s to the wall clock
    result = _run("--controller", "keyboard", "--no-realtime", "--duration", "1.5", "--log", str(tmp_path / "fast.csv"))
    assert result.exit_code == 0, result.output
    assert (tmp_path / "fast.csv").read_bytes() == (tmp_path / "rt.csv").read_bytes()  # pacing changes no result


def test_window_draws_overlay(pygame):
    import numpy as np

    window = kb.DrivingWindow(scale=2)
    try:
        ctl = kb.KeyboardController(0.1, window, joystick=None)
        img = np.full((40, 50, 3), 90, dtype=np.uint8)
        obs = {"frame": 0, "t": 0.0, "v_host": 30.0, "v_lead": 29.0, "gap": 50.0, "image": img.tobytes(), "image_shape": [40, 50, 3]}
        assert ctl(obs) == 0.0
        assert window.screen.get_size() == (100, 80)
        assert window.screen.get_at((99, 79))[:3] == (90, 90, 90)  # the camera, scaled up
    finally:
        window.close()
