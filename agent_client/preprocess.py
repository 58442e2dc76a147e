"""The paper's image preprocessing: camera frame -> 105x150 network input.

Wei et al. (2019), Figure 3: grayscale, resize by 0.5 (400x400 -> 200x200), a fixed
mask that keeps only where the preceding vehicle can be, and a crop of the top
border to 105x200. The network then takes 105x150; the paper does not say how 200
columns become 150. Here the 150 are the middle columns (25 cut from each side):

* a crop keeps the pixel scale, so the sub-pixel edge information the renderer's
  anti-aliasing puts into the lead car's outline survives (a horizontal resize
  by 0.75 would blur it and make the lead's apparent width a non-integer
  resampling of the gap);
* after the mask, the outer 25 columns only hold road at the very bottom of the
  image, i.e. ground closer than ~3.5 m; a lead car that close is a collision.

The mask is fixed pixel geometry (no image content), derived once from the default
camera of ``sim_server.render.CameraConfig`` (400x400, 45 deg horizontal field of
view, 1.4 m mount height, level). The agent never imports the simulator: both take
these numbers from :mod:`protocol.constants`, and ``tests/agent_client/test_preprocess.py``
checks that the derived ones still match the camera. The kept region is the union of the silhouettes of a
2x2.3 m wide, 1.8 m tall box in the host lane at any distance beyond
:data:`MASK_NEAR` (a rectangle around the vanishing point), plus the host lane's
ground corridor (a trapezoid widening towards the bottom), 2.3 m either side of the
lane centre. A 1.8 m wide lead, even 0.3 m off-centre, stays whole down to a
camera distance of ~10.4 m (gap ~9 m); closer, its lower part still shows in the
corridor. Adjacent-lane cars (inner side 2.8 m from the lane centre) are cut away
up to ~24 m; farther ones partly stay inside the rectangle, as they must with
any fixed mask that keeps a distant lead whole.

Rows and columns below are at the half resolution (200x200), with pixel centres at
integers, so the 400 px image centre 199.5 maps to 99.5.

**Zoom 2** (``zoom=2``, an improvement over the paper, not in it): the same 105x150
window around the horizon, but cut from the 400x400 frame at full resolution,
without the halving. The network then sees the road 8.8 to ~80 m ahead at twice the
pixel scale: the lead at 55 m is ~16 px wide instead of ~8, and 5 m of gap change
its width by ~1.5 px instead of ~0.7. Nearer than ~6.8 m from the camera its bottom
leaves the window, but its body still fills most of it. The mask is the same
geometry at twice the focal length. Checkpoints record their zoom, so a policy
always gets the frames it was trained on.
"""

from __future__ import annotations

import cv2
import numpy as np

from protocol.constants import CAMERA_HFOV, CAMERA_MOUNT_HEIGHT, CAMERA_SIZE

__all__ = ["FRAME_H", "FRAME_W", "MASK", "MASKS", "ZOOMS", "camera_size", "preprocess", "preprocess_reference"]

FRAME_H = 105  # [px] network input height
FRAME_W = 150  # [px] network input width

# --- the default camera's numbers (protocol.constants, which the renderer's CameraConfig uses too)
FOCAL_200 = 100.0 / np.tan(CAMERA_HFOV / 2)  # [px] focal length at 200 px width (45 deg hfov)
VANISH_ROW_200 = 99.5  # [px] horizon row at 200x200 (level camera)
VANISH_COL_200 = 99.5  # [px] vanishing point column at 200x200
MOUNT_HEIGHT = CAMERA_MOUNT_HEIGHT  # [m] camera height above the road

# --- mask geometry --------------------------------------------------------------------
MASK_HALF_WIDTH = 2.3  # [m] lane half width 1.85 + room for the car's lateral offset
MASK_NEAR = 20.0  # [m] camera distance from which the full 2x2.3 m box is kept
MASK_TOP = 1.8  # [m] tallest lead vehicle the mask keeps whole

ROW0 = 200 - FRAME_H  # first kept row at 200x200 ("crop the top border")
COL0 = (200 - FRAME_W) // 2  # first kept column at 200x200 (centre crop)

ZOOMS = (1, 2)  # 1: the paper's x0.5 pipeline; 2: the same window at full resolution
# zoom 2, at 400x400: the horizon stays on the same output row as with zoom 1
VANISH_ROW_400 = 2 * (VANISH_ROW_200 + 0.25)  # [px] 199.5: half-res pixel i covers rows 2i, 2i + 1
VANISH_COL_400 = 2 * (VANISH_COL_200 + 0.25)  # [px] 199.5
ROW0_400 = int(VANISH_ROW_400 - (VANISH_ROW_200 - ROW0))  # 195
COL0_400 = (400 - FRAME_W) // 2  # 125


def camera_size(zoom: int) -> tuple[int, int]:
    """The gray camera frame ``(width, height)`` [px] to ask the server for at ``zoom``."""
    _check_zoom(zoom)
    full = CAMERA_SIZE
    return (full[0] // 2, full[1] // 2) if zoom == 1 else full  # zoom 1: the paper's halved camera


def _check_zoom(zoom: int) -> None:
    if zoom not in ZOOMS:
        raise ValueError(f"zoom must be one of {ZOOMS}, got {zoom!r}")


def _make_mask(zoom: int = 1) -> np.ndarray:
    """The fixed mask on the 105x150 output grid: 255 keep, 0 drop."""
    if zoom == 1:
        focal, row0, col0, v_row, v_col = FOCAL_200, ROW0, COL0, VANISH_ROW_200, VANISH_COL_200
    else:  # full resolution: pixel centres of the 400 px frame
        focal, row0, col0 = 2 * FOCAL_200, ROW0_400, COL0_400
        v_row, v_col = VANISH_ROW_400, VANISH_COL_400
    rows = np.arange(row0, row0 + FRAME_H, dtype=np.float64)[:, None]
    cols = np.arange(col0, col0 + FRAME_W, dtype=np.float64)[None, :]
    dy = rows - v_row  # [px] below the horizon
    dx = np.abs(cols - v_col)
    rect_hw = focal * MASK_HALF_WIDTH / MASK_NEAR  # [px] lead at MASK_NEAR, either side
    rect_bottom = focal * MOUNT_HEIGHT / MASK_NEAR  # [px] its bottom edge below horizon
    rect_top = -focal * (MASK_TOP - MOUNT_HEIGHT) / MASK_NEAR  # [px] its roof (above)
    corridor_hw = dy * (MASK_HALF_WIDTH / MOUNT_HEIGHT)  # [px] ground corridor at that row
    keep = ((dy >= rect_top) & (dy <= rect_bottom) & (dx <= rect_hw + 0.5)) | (
        (dy > rect_bottom) & (dx <= corridor_hw + 0.5)
    )
    mask = np.where(keep, 255, 0).astype(np.uint8)
    mask.setflags(write=False)
    return mask


MASKS = {z: _make_mask(z) for z in ZOOMS}  # (105, 150) uint8 each, 255 where the lead can be
MASK = MASKS[1]  # the paper's


def _gray(img: np.ndarray) -> np.ndarray:
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    return img


def preprocess(image: np.ndarray, zoom: int = 1) -> np.ndarray:
    """Turn one camera frame into the network's input.

    Only the window that survives the crop is converted and resized: with even
    crop offsets, the 2x2 area averages are the same as for the whole frame, so the
    result equals :func:`preprocess_reference` exactly, at a fraction of the cost.

    Args:
        image: uint8 camera frame, 400x400 RGB or gray (the paper's camera), or, with
            ``zoom=1``, an already halved 200x200 RGB or gray frame (then the resize
            is skipped). Gray may be ``(H, W)`` or ``(H, W, 1)``.
        zoom: 1, the paper's pipeline; 2, the window at full resolution (400x400 only).

    Returns:
        ``(FRAME_H, FRAME_W)`` = (105, 150) uint8, C-contiguous, masked.

    Raises:
        ValueError: wrong dtype, shape or zoom.
    """
    _check_zoom(zoom)
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"expected a uint8 image, got {img.dtype}")
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
        raise ValueError(f"expected (H, W), (H, W, 1) or (H, W, 3), got shape {img.shape}")
    hw = img.shape[:2]
    if zoom == 2:
        if hw != (400, 400):
            raise ValueError(f"zoom 2 needs the full 400x400 frame, got {hw[0]}x{hw[1]}")
        # OpenCV reads the window as a view: the masked result is the only copy
        return cv2.bitwise_and(_gray(img[ROW0_400:ROW0_400 + FRAME_H, COL0_400:COL0_400 + FRAME_W]), MASKS[2])
    if hw == (400, 400):
        win = img[2 * ROW0:, 2 * COL0:2 * (COL0 + FRAME_W)]
        out = cv2.resize(_gray(win), (FRAME_W, FRAME_H), interpolation=cv2.INTER_AREA)
    elif hw == (200, 200):
        out = _gray(img[ROW0:, COL0:COL0 + FRAME_W])  # a view (see zoom 2)
    else:
        raise ValueError(f"expected a 400x400 or 200x200 frame, got {hw[0]}x{hw[1]}")
    return cv2.bitwise_and(out, MASK)


def preprocess_reference(image: np.ndarray) -> np.ndarray:
    """The same pipeline step by step, in the paper's order (slow; for tests and docs).

    Args:
        image: 400x400 uint8 RGB or gray frame.

    Returns:
        ``(105, 150)`` uint8.
    """
    gray = _gray(np.asarray(image))  # 1. grayscale
    half = cv2.resize(gray, (200, 200), interpolation=cv2.INTER_AREA)  # 2. x0.5
    full_mask = np.zeros((200, 200), np.uint8)
    full_mask[ROW0:, COL0:COL0 + FRAME_W] = MASK
    masked = cv2.bitwise_and(half, full_mask)  # 3. fixed mask
    top_cropped = masked[ROW0:, :]  # 4. crop the top border: 105x200
    return np.ascontiguousarray(top_cropped[:, COL0:COL0 + FRAME_W])  # 5. 105x150
