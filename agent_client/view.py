"""What a person sees of a run: the camera with a head-up strip and a scrolling plot.

One picture, drawn with OpenCV into an RGB array, serves the live window of
``vacc drive --view`` (:class:`LiveView`, shown through the keyboard driver's pygame
window) and every frame of ``vacc video``:

* the camera as the simulator rendered it (a smaller gray frame is scaled up to the
  full camera size, pixel for pixel);
* a head-up strip: time, speed, set speed, gap, acceleration and the force that
  produced the frame;
* a plot of the last :data:`HISTORY_S` seconds of gap (against the 55 m target) and of
  the host's and the lead's speed, scrolling as the run goes;
* optionally the network's own input (the 105x150 grey crop) beside the camera.

The view only reads observations: it never sends, so a run with it is the run without it.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import cv2
import numpy as np

from protocol.constants import CAMERA_SIZE, DESIRED_GAP

__all__ = ["HISTORY_S", "Hud", "compose", "LiveView"]

HISTORY_S = 20.0  # [s] the scrolling plot's span
STRIP_H = 64  # [px] head-up strip height
PLOT_H = 74  # [px] each of the two plot panels
NET_SCALE = 2  # the 105x150 network input shown at twice its size
INK, DIM, GAP_C, HOST_C, LEAD_C, TARGET_C = (235, 235, 235), (90, 90, 90), (80, 200, 255), (255, 170, 60), (200, 200, 200), (120, 255, 120)  # RGB
FONT = cv2.FONT_HERSHEY_SIMPLEX


class Hud:
    """The recent history a frame's plot shows: (t [s], gap [m], host and lead speed [m/s])."""

    def __init__(self, period: float = 0.1):
        self.rows: deque[tuple[float, float, float, float]] = deque(maxlen=int(round(HISTORY_S / period)) + 1)

    def update(self, obs: dict[str, Any]) -> None:
        """Add one observation."""
        self.rows.append((float(obs["t"]), float(obs["gap"]), float(obs["v_host"]), float(obs["v_lead"])))

    def frame(self, image: np.ndarray | None, obs: dict[str, Any], network: np.ndarray | None = None) -> np.ndarray:
        """The picture of ``obs`` (add it with :meth:`update` first): see :func:`compose`."""
        return compose(image, obs, np.array(self.rows, dtype=np.float64).reshape(-1, 4), network)


def _camera(image: np.ndarray | None) -> np.ndarray:
    """The camera frame as (H, W, 3) RGB at the full camera size (a blank one without an image)."""
    w, h = CAMERA_SIZE
    if image is None:
        return np.zeros((h, w, 3), np.uint8)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.shape[:2] != (h, w):
        image = cv2.resize(image, (w, h), interpolation=cv2.INTER_NEAREST)
    return np.ascontiguousarray(image)


def _text(img: np.ndarray, text: str, x: int, y: int, color: tuple[int, int, int] = INK, size: float = 0.45) -> None:
    cv2.putText(img, text, (x, y), FONT, size, color, 1, cv2.LINE_AA)


def _strip(obs: dict[str, Any], width: int) -> np.ndarray:
    img = np.zeros((STRIP_H, width, 3), np.uint8)
    v, vs = float(obs["v_host"]), float(obs.get("set_speed") or 0.0)
    _text(img, f"t {obs['t']:6.1f} s   speed {v:5.2f} m/s ({v * 3.6:5.1f} km/h)   set {vs:4.1f} m/s", 8, 20)
    _text(img, f"gap {obs['gap']:6.1f} m   accel {obs['accel']:+5.2f} m/s^2   force {obs['force']:+.3f}", 8, 42)
    _text(img, f"lead {obs['v_lead']:5.2f} m/s   frame {obs['frame']}" + ("   COLLISION" if obs["collision"] else ""), 8, 60, DIM, 0.38)
    return img


def _panel(history: np.ndarray, series: list[tuple[int, tuple[int, int, int]]], target: float | None, width: int, label: str) -> np.ndarray:
    """One scrolling panel: the columns ``series`` of ``history`` over its last HISTORY_S seconds."""
    img = np.full((PLOT_H, width, 3), 18, np.uint8)
    x0, x1, y0, y1 = 40, width - 6, 6, PLOT_H - 6
    cv2.rectangle(img, (x0, y0), (x1, y1), DIM, 1)
    if history.shape[0] == 0:
        return img
    t_end = history[-1, 0]
    values = np.concatenate([history[:, c] for c, _ in series] + ([np.array([target])] if target is not None else []))
    lo, hi = float(values.min()), float(values.max())
    pad = max(1.0, 0.1 * (hi - lo))
    lo, hi = max(0.0, lo - pad), hi + pad

    def pts(col: np.ndarray) -> np.ndarray:
        x = x1 - (t_end - history[:, 0]) / HISTORY_S * (x1 - x0)
        y = y1 - (col - lo) / (hi - lo) * (y1 - y0)
        return np.stack([x, y], axis=1).round().astype(np.int32)

    if target is not None:
        ty = int(round(y1 - (target - lo) / (hi - lo) * (y1 - y0)))
        cv2.line(img, (x0, ty), (x1, ty), TARGET_C, 1)
    for col, color in series:
        cv2.polylines(img, [pts(history[:, col])], False, color, 1, cv2.LINE_AA)
    _text(img, f"{hi:.0f}", 4, y0 + 10, DIM, 0.33)
    _text(img, f"{lo:.0f}", 4, y1, DIM, 0.33)
    _text(img, label, x0 + 4, y0 + 12, INK, 0.36)
    return img


def compose(image: np.ndarray | None, obs: dict[str, Any], history: np.ndarray, network: np.ndarray | None = None) -> np.ndarray:
    """One picture of a run: camera, head-up strip, gap and speed panels, and the network input beside.

    Args:
        image: the camera frame (RGB or gray, any size; scaled to the camera's), or None.
        obs: the observation shown in the strip.
        history: rows of (t [s], gap [m], host speed, lead speed [m/s]), oldest first.
        network: the (105, 150) uint8 network input, or None: not shown.

    Returns:
        (H, W, 3) uint8 RGB, C-contiguous; the same size for every frame of a run.
    """
    cam = _camera(image)
    width = cam.shape[1]
    gap_panel = _panel(history, [(1, GAP_C)], DESIRED_GAP, width, f"gap [m] (green: {DESIRED_GAP:g} m), last {HISTORY_S:g} s")
    speed_panel = _panel(history, [(3, LEAD_C), (2, HOST_C)], None, width, "speed [m/s]: host (orange), lead (grey)")
    left = np.concatenate([cam, _strip(obs, width), gap_panel, speed_panel], axis=0)
    if network is None:
        return left
    net = cv2.resize(network, (network.shape[1] * NET_SCALE, network.shape[0] * NET_SCALE), interpolation=cv2.INTER_NEAREST)
    side = np.zeros((left.shape[0], net.shape[1] + 16, 3), np.uint8)
    side[30:30 + net.shape[0], 8:8 + net.shape[1]] = net[:, :, None]
    _text(side, "network input (105x150 grey)", 8, 20, INK, 0.4)
    return np.ascontiguousarray(np.concatenate([left, side], axis=1))


class LiveView:
    """``vacc drive --view``: the composed picture in a window, redrawn at every step.

    Closing the window only stops the drawing; the run goes on to its end.

    Args:
        period: the control period [s] (the plot's history length).
        title: the window's caption.

    Raises:
        PygameMissing, NoDisplay: as the keyboard driver's window (one line each).
    """

    def __init__(self, period: float = 0.1, title: str = "vacc: drive --view"):
        # pygame only when a window is asked for
        from agent_client.controllers.keyboard import DrivingWindow

        self.window: Any = DrivingWindow(scale=1, title=title)
        self.hud = Hud(period)
        self.open = True
        self.last: np.ndarray | None = None

    def __call__(self, obs: dict[str, Any]) -> None:
        """Show ``obs`` (an ``on_step`` callback of :func:`agent_client.drive.drive_episode`)."""
        from agent_client.session import Session

        self.hud.update(obs)
        if not self.open:
            return
        if any(e.type == self.window.pg.QUIT for e in self.window.events()):
            self.close()
            return
        self.last = self.hud.frame(Session.image(obs), obs)
        self.window.draw(self.last, [])

    def save(self, path: str) -> None:
        """Write the window's current picture as a PNG (the screen as drawn)."""
        if self.window.screen is not None:
            self.window.pg.image.save(self.window.screen, path)

    def close(self) -> None:
        """Close the window; safe to call twice."""
        self.open = False
        self.window.close()
