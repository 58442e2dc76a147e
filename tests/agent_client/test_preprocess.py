"""Client-side preprocessing: shapes, exactness of the fast path, the fixed mask."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from agent_client import preprocess as pp
from agent_client.preprocess import FRAME_H, FRAME_W, MASK, preprocess, preprocess_reference


def _frame(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (400, 400, 3), dtype=np.uint8)


def test_output_shape_dtype_for_every_accepted_input() -> None:
    rgb = _frame()
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    half_rgb = cv2.resize(rgb, (200, 200), interpolation=cv2.INTER_AREA)
    half_gray = cv2.cvtColor(half_rgb, cv2.COLOR_RGB2GRAY)
    for img in (rgb, gray, gray[:, :, None], half_rgb, half_gray):
        out = preprocess(img)
        assert out.shape == (FRAME_H, FRAME_W) == (105, 150)
        assert out.dtype == np.uint8 and out.flags["C_CONTIGUOUS"]


def test_fast_path_equals_the_paper_order() -> None:
    """Cropping before the 2x2 area resize must not change a single pixel."""
    for seed in range(3):
        img = _frame(seed)
        np.testing.assert_array_equal(preprocess(img), preprocess_reference(img))
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        np.testing.assert_array_equal(preprocess(gray), preprocess_reference(gray))


def test_half_resolution_input_skips_the_resize() -> None:
    img = _frame(4)
    gray_half = cv2.resize(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), (200, 200), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(preprocess(gray_half), preprocess(img))


def test_mask_is_fixed_and_independent_of_content() -> None:
    white = np.full((400, 400, 3), 255, np.uint8)
    np.testing.assert_array_equal(preprocess(white), MASK)
    assert not np.any(preprocess(np.zeros((400, 400), np.uint8)))
    a, b = preprocess(_frame(1)), preprocess(_frame(2))
    assert not np.any(a[MASK == 0]) and not np.any(b[MASK == 0])


def test_mask_shape_keeps_the_host_lane_and_drops_the_sides() -> None:
    keep = MASK > 0
    row_vp = int(pp.VANISH_ROW_200 - pp.ROW0)  # the horizon row inside the output
    col_vp = int(pp.VANISH_COL_200 - pp.COL0)
    assert keep[row_vp, col_vp]  # a distant lead sits at the vanishing point
    assert not keep[row_vp, 0] and not keep[row_vp, FRAME_W - 1]  # adjacent lanes / roadside
    assert keep[FRAME_H - 1].all()  # the ground right in front: all host lane
    widths = keep.sum(axis=1)
    assert np.all(np.diff(widths[row_vp:]) >= 0)  # the corridor widens towards the bottom
    assert 0.3 < keep.mean() < 0.9


def test_mask_numbers_match_the_simulators_default_camera() -> None:
    """preprocess repeats a few camera numbers (no sim_server import); keep them in sync."""
    from sim_server.render import CameraConfig

    cfg = CameraConfig()
    assert (cfg.width, cfg.height) == (400, 400)
    assert pp.FOCAL_200 == pytest.approx(cfg.focal_px / 2)
    u, v = cfg.vanishing_point
    assert pp.VANISH_ROW_200 == pytest.approx(v / 2 - 0.25)  # 2x2 area average of centres
    assert pp.VANISH_COL_200 == pytest.approx(u / 2 - 0.25)
    assert (pp.VANISH_COL_400, pp.VANISH_ROW_400) == pytest.approx((u, v))  # zoom 2: full resolution
    assert pp.MOUNT_HEIGHT == cfg.mount_height
    assert math.isclose(cfg.pitch, 0.0)


def test_lead_car_is_visible_through_the_mask() -> None:
    from sim_server.render import CameraConfig, Renderer
    from sim_server.scene import CarView, SceneState

    r = Renderer(CameraConfig())
    for gap in (10.0, 55.0, 150.0):
        with_lead = preprocess(r.render(SceneState(host_s=10.0, cars=(CarView(dx=gap, lane=0),))))
        empty = preprocess(r.render(SceneState(host_s=10.0)))
        diff = with_lead.astype(int) != empty
        assert diff.sum() >= 3, f"lead at {gap} m invisible after preprocessing"
        assert np.all(MASK[diff] > 0)


@pytest.mark.parametrize(
    "bad",
    [np.zeros((400, 400, 3), np.float32), np.zeros((300, 300, 3), np.uint8),
     np.zeros((400, 400, 4), np.uint8), np.zeros((400,), np.uint8)],
)
def test_bad_images_are_rejected(bad: np.ndarray) -> None:
    with pytest.raises(ValueError):
        preprocess(bad)


# ----------------------------------------------------------------------------- zoom 2


def test_zoom2_is_the_same_window_at_full_resolution() -> None:
    """Zoom 2 cuts the 105x150 window around the horizon from the 400x400 frame."""
    img = _frame(5)
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    out = preprocess(img, zoom=2)
    assert out.shape == (FRAME_H, FRAME_W) and out.dtype == np.uint8 and out.flags["C_CONTIGUOUS"]
    window = gray[pp.ROW0_400:pp.ROW0_400 + FRAME_H, pp.COL0_400:pp.COL0_400 + FRAME_W]
    np.testing.assert_array_equal(out, cv2.bitwise_and(window, pp.MASKS[2]))
    np.testing.assert_array_equal(preprocess(np.full((400, 400), 255, np.uint8), zoom=2), pp.MASKS[2])
    # the horizon sits on the same output row at both zooms
    assert pp.VANISH_ROW_400 - pp.ROW0_400 == pp.VANISH_ROW_200 - pp.ROW0
    assert pp.VANISH_COL_400 - pp.COL0_400 == pp.VANISH_COL_200 - pp.COL0


def test_zoom2_doubles_the_lead_cars_width() -> None:
    from sim_server.render import CameraConfig, Renderer
    from sim_server.scene import CarView, SceneState

    r = Renderer(CameraConfig())
    empty = r.render(SceneState(host_s=10.0))

    def width(gap: float, zoom: int) -> int:
        img = r.render(SceneState(host_s=10.0, cars=(CarView(dx=gap, lane=0),)))
        diff = preprocess(img, zoom).astype(int) != preprocess(empty, zoom)
        assert np.all(pp.MASKS[zoom][diff] > 0)
        cols = np.nonzero(diff.any(axis=0))[0]
        return int(cols.max() - cols.min() + 1)

    for gap in (20.0, 55.0, 100.0):
        w1, w2 = width(gap, 1), width(gap, 2)
        assert 1.6 * w1 <= w2 <= 2.4 * w1, (gap, w1, w2)
    assert width(50.0, 2) - width(60.0, 2) >= 3  # 10 m of gap: >= 3 px at zoom 2


def test_camera_size_follows_zoom_and_bad_zooms_are_rejected() -> None:
    assert pp.camera_size(1) == (200, 200) and pp.camera_size(2) == (400, 400)
    with pytest.raises(ValueError, match="zoom"):
        pp.camera_size(3)
    with pytest.raises(ValueError, match="zoom"):
        preprocess(_frame(), zoom=0)
    with pytest.raises(ValueError, match="400x400"):
        preprocess(np.zeros((200, 200), np.uint8), zoom=2)
