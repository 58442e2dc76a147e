"""The env in the Gymnasium ecosystem: gym.make after install alone, TimeLimit, rendering.

Every env here spawns and reaps a real server on 127.0.0.1.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import textwrap
import warnings

import cv2
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from agent_client.controllers import keyboard as kb
from agent_client.env import CONTROL_PERIOD, ENV_ID, MAX_EPISODE_STEPS, VisionACCEnv
from sim_server.trajectory import TEST_DURATION


def test_max_episode_steps_is_the_test_trajectory_in_control_periods():
    assert CONTROL_PERIOD == pytest.approx(0.1)
    assert MAX_EPISODE_STEPS == 2400 == round(TEST_DURATION / CONTROL_PERIOD)
    assert gym.spec(ENV_ID).max_episode_steps == MAX_EPISODE_STEPS
    assert VisionACCEnv.metadata["render_fps"] == 10


def test_gym_make_in_a_fresh_interpreter_needs_no_import(tmp_path):
    # What a user types after `pip install`: nothing of vacc imported, run from another folder.
    script = textwrap.dedent(
        f"""
        import sys
        import gymnasium as gym
        from gymnasium.wrappers import TimeLimit
        assert "agent_client.env" not in sys.modules
        env = gym.make("agent_client.env:{ENV_ID}", episode_seconds=0.3)
        try:
            assert isinstance(env, TimeLimit) and env.spec.max_episode_steps == {MAX_EPISODE_STEPS}
            obs, info = env.reset(seed=0)
            assert obs["frames"].shape == (8, 105, 150)
            steps, done = 0, False
            while not done:
                obs, reward, terminated, truncated, info = env.step(10)
                steps, done = steps + 1, terminated or truncated
            assert truncated and steps == 3, steps
        finally:
            env.close()
        # after the import, the plain id is there too
        assert "{ENV_ID}" in gym.registry
        print("ok")
        """
    )
    result = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr


def _episode(env: gym.Env, seed: int, actions: tuple[int, ...]) -> tuple[np.ndarray, list[np.ndarray | None]]:
    obs, _ = env.reset(seed=seed)
    frames, renders = [obs["frames"].copy()], [env.render()]
    for a in actions:
        obs, *_ = env.step(a)
        frames.append(obs["frames"].copy())
        renders.append(env.render())
    return np.stack(frames), renders


@pytest.mark.parametrize("zoom", [1, 2])
def test_rgb_array_is_the_colour_camera_and_leaves_observations_bit_identical(zoom):
    actions = (20, 0, 15, 5, 10)
    plain = VisionACCEnv(episode_seconds=2.0, zoom=zoom)
    coloured = VisionACCEnv(episode_seconds=2.0, zoom=zoom, render_mode="rgb_array")
    try:
        seen, nothing = _episode(plain, 3, actions)
        seen_rendering, renders = _episode(coloured, 3, actions)
    finally:
        plain.close()
        coloured.close()
    np.testing.assert_array_equal(seen, seen_rendering)
    assert all(r is None for r in nothing)
    side = 200 * zoom
    for frame in renders:
        assert frame is not None and frame.shape == (side, side, 3) and frame.dtype == np.uint8
        # colour, not one gray channel copied three times: the sky is bluer than it is red
        assert not np.array_equal(frame[..., 0], frame[..., 2])
        assert frame[: side // 4, :, 2].mean() > frame[: side // 4, :, 0].mean()
    assert not np.array_equal(renders[0], renders[-1])  # the view changes as the cars move
    renders[-1][:] = 0  # the caller owns its copy
    assert coloured._last_image is not None and coloured._last_image.any()


def test_human_opens_a_window_per_step_and_close_shuts_it(monkeypatch):
    pygame = pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    env = gym.make(ENV_ID, episode_seconds=0.5, render_mode="human")
    try:
        env.reset(seed=0)
        assert pygame.display.get_init() and pygame.display.get_surface().get_size() == (400, 400)
        done, steps = False, 0
        while not done:
            *_, terminated, truncated, _ = env.step(10)
            done, steps = terminated or truncated, steps + 1
        assert steps == 5 and env.render() is None
    finally:
        env.close()
    assert not pygame.display.get_init()
    env.close()  # twice is fine


def test_human_without_a_display_is_quiet_and_check_env_still_passes(monkeypatch, capfd, caplog):
    # Gymnasium's check_env makes every render mode; headless CI must not fail on "human",
    # and must not be told about a display it never asked for (issue 56): a log line at info only.
    pytest.importorskip("pygame")
    for name in kb.DISPLAY_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    env = gym.make(ENV_ID, episode_seconds=1.0, render_mode="rgb_array")
    try:
        with warnings.catch_warnings(record=True) as caught, caplog.at_level(logging.INFO, logger="vacc.env"):
            warnings.simplefilter("always")
            check_env(env.unwrapped)
    finally:
        env.close()
    assert not [w for w in caught if "display" in str(w.message)], [str(w.message) for w in caught]
    assert "without a display" in caplog.text  # still said, to whoever logs at info
    assert "XDG_RUNTIME_DIR" not in capfd.readouterr().err


def test_an_unknown_render_mode_is_refused():
    with pytest.raises(ValueError, match="render_mode 'ansi' is not one of"):
        VisionACCEnv(("127.0.0.1", 9), render_mode="ansi")


def test_record_video_writes_an_episode(tmp_path):
    pytest.importorskip("moviepy", reason="RecordVideo needs moviepy (gymnasium[other])")
    from gymnasium.wrappers import RecordVideo

    folder = tmp_path / "videos"
    env = RecordVideo(
        gym.make(ENV_ID, episode_seconds=1.0, render_mode="rgb_array"),
        str(folder),
        episode_trigger=lambda episode: True,
        name_prefix="vacc",
    )
    try:
        env.reset(seed=0)
        done = False
        for _ in range(MAX_EPISODE_STEPS):  # bounded; the episode ends after 10
            *_, terminated, truncated, _ = env.step(15)
            if terminated or truncated:
                done = True
                break
        assert done and len(env.recorded_frames) == 11  # the reset frame and 10 steps
    finally:
        env.close()  # writes the video
    video = folder / "vacc-episode-0.mp4"
    assert video.is_file() and os.path.getsize(video) > 1000
    capture = cv2.VideoCapture(str(video))  # read it back, in colour
    try:
        frames = []
        for _ in range(100):  # bounded
            ok, frame = capture.read()
            if not ok:
                break
            frames.append(frame)
    finally:
        capture.release()
    # moviepy's encoder may drop the last frame of a clip
    assert len(frames) in (10, 11) and frames[0].shape == (200, 200, 3)
    assert not np.array_equal(frames[0][..., 0], frames[0][..., 2])
