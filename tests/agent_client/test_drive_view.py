"""`vacc drive --view` never changes a log byte, fails without a display in one line; the progress bar stays off a pipe."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from agent_client.cli import DriveEpisode, expected_seconds
from agent_client.view import Hud, compose


def vacc(*args: str, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout, env=env)


@contextlib.contextmanager
def xvfb():
    """A virtual X display for the block; skips the test when Xvfb is not installed."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed: apt-get install -y xvfb (Debian) to run the --view tests")
    display = f":{90 + os.getpid() % 500}"
    proc = subprocess.Popen(["Xvfb", display, "-screen", "0", "1024x768x24", "-nolisten", "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        assert proc.poll() is None, "Xvfb did not start"
        yield display
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.parametrize("controller", [["--controller", "acc"], ["--controller", "ddqn", "--checkpoint", "models/ice-gap.pt"]], ids=["acc", "ddqn"])
def test_the_view_never_changes_a_log_byte(tmp_path, controller):
    plain, viewed = tmp_path / "plain.csv", tmp_path / "viewed.csv"
    assert vacc("drive", *controller, "--trajectory", "test-1", "--duration", "10", "--log", str(plain), "--quiet").returncode == 0
    with xvfb() as display:
        env = {k: v for k, v in os.environ.items() if k not in ("WAYLAND_DISPLAY", "SDL_VIDEODRIVER")} | {"DISPLAY": display}
        result = vacc("drive", *controller, "--trajectory", "test-1", "--duration", "10", "--log", str(viewed), "--quiet", "--view", env=env)
    assert result.returncode == 0, result.stderr
    assert viewed.read_bytes() == plain.read_bytes()
    assert len(plain.read_text().splitlines()) == 102


def test_no_display_is_the_keyboard_drivers_one_line(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")}
    result = vacc("drive", "--controller", "acc", "--duration", "1", "--log", str(tmp_path / "x.csv"), "--view", env=env)
    assert result.returncode == 1 and not (tmp_path / "x.csv").exists()
    assert result.stderr.strip().splitlines() == ["Error: live driving needs a display, and none is set (DISPLAY, WAYLAND_DISPLAY); "
                                                  "run it on a desktop or with ssh -X, or set SDL_VIDEODRIVER to choose a driver"]  # fmt: skip
    result = vacc("drive", "--controller", "keyboard", "--log", str(tmp_path / "x.csv"), "--view", env=env)
    assert result.returncode == 2 and "keyboard driver shows its own window" in result.stderr


def test_no_progress_bar_off_a_terminal(tmp_path):
    result = vacc("drive", "--controller", "acc", "--duration", "30", "--log", str(tmp_path / "x.csv"), "--quiet")
    assert result.returncode == 0 and result.stderr == ""


def test_expected_seconds():
    ep = DriveEpisode("ice", "test-1", 0, {}, None, False, None)
    assert expected_seconds(ep) == 240.0
    assert expected_seconds(ep.__class__("ice", "test-1", 0, {}, 30.0, False, None)) == 30.0
    assert expected_seconds(ep.__class__("ice", "brake-stop", 0, {}, None, False, None)) is None


def test_the_picture_keeps_its_size_and_shows_the_network_input():
    hud = Hud()
    obs = {"t": 0.0, "frame": 0, "v_host": 20.0, "v_lead": 21.0, "gap": 50.0, "accel": 0.1, "force": 0.2, "collision": 0, "set_speed": 33.5}
    sizes = set()
    for k in range(300):
        obs = {**obs, "t": k / 10, "frame": k, "gap": 50.0 + np.sin(k / 10)}
        hud.update(obs)
        sizes.add(hud.frame(np.zeros((200, 200), np.uint8), obs).shape)
    assert sizes == {(400 + 64 + 2 * 74, 400, 3)} and len(hud.rows) == 201  # 20 s of history
    net = np.full((105, 150), 200, np.uint8)
    picture = compose(None, obs, np.array(hud.rows), net)
    assert picture.shape[1] == 400 + 300 + 16 and (picture[30:240, 408:708] == 200).all()
