"""Camera renderer: determinism, projective geometry, occlusion, light, sub-pixel AA."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from agent_client.preprocess import FRAME_H, FRAME_W, preprocess
from sim_server.render import CameraConfig, Renderer
from sim_server.scene import CarView, SceneState
from vacc.snapshot_cmd import snapshot, snapshot_scene

CFG = CameraConfig()


def _scene(*cars: CarView, **kw: float) -> SceneState:
    return SceneState(host_s=kw.pop("host_s", 321.0), cars=tuple(cars), **kw)


def test_same_state_gives_identical_bytes() -> None:
    scene = snapshot_scene(37.0, "ev", seed=5)
    a = Renderer(CFG).render(scene)
    r = Renderer(CFG)
    r.render(snapshot_scene(80.0, "ice", seed=9))  # other seed, phase bucket, traffic
    b = r.render(scene)
    c = r.render(scene)
    assert a.dtype == np.uint8 and a.shape == (400, 400, 3) and a.flags["C_CONTIGUOUS"]
    assert a.tobytes() == b.tobytes() == c.tobytes()
    c[0, 0] = 0  # the caller owns the frame: scribbling on it changes nothing cached
    assert r.render(scene).tobytes() == a.tobytes()


@pytest.mark.parametrize("size", [(200, 200), (320, 240), (64, 48)])
def test_any_image_size(size: tuple[int, int]) -> None:
    w, h = size
    img = Renderer(CameraConfig(width=w, height=h)).render(snapshot_scene(30.0, seed=1))
    assert img.shape == (h, w, 3) and img.dtype == np.uint8 and img.flags["C_CONTIGUOUS"]


def test_focal_length_and_vanishing_point_from_config() -> None:
    assert CFG.focal_px == pytest.approx(200.0 / math.tan(math.pi / 8))
    cfg = CameraConfig(pitch=0.05)
    u, v = cfg.vanishing_point
    far = cfg.project(np.array([[3.0, 0.0, 1e7], [-5.0, 2.0, 1e7]]))
    np.testing.assert_allclose(far, [[u, v], [u, v]], atol=1e-3)


def _line_centres(img: np.ndarray, rows: range, colour: str, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Intensity-weighted column of the painted line nearest the image edge ``side``."""
    f = img.astype(np.float64)
    r, g, b = f[..., 0], f[..., 1], f[..., 2]
    if colour == "white":
        w = np.clip((np.minimum(np.minimum(r, g), b) - 150.0) / 80.0, 0, 1)
    else:  # yellow: red and green high, blue low
        w = np.clip((np.minimum(r, g) - b - 60.0) / 80.0, 0, 1)
    half = img.shape[1] // 2
    ys, xs = [], []
    for y in rows:
        row = w[y].copy()
        if side == "right":
            row[:half] = 0
        else:
            row[half:] = 0
        cols = np.nonzero(row > 0.05)[0]
        if len(cols) == 0:
            continue
        edge = cols.max() if side == "right" else cols.min()
        sel = np.abs(np.arange(len(row)) - edge) <= 3 * (1 + (y - rows[0]) / 40)
        # the line nearest the edge: take only its own run of columns
        run = row * sel
        ys.append(y)
        xs.append(float((run * np.arange(len(row))).sum() / run.sum()))
    return np.array(ys, float), np.array(xs, float)


@pytest.mark.parametrize("pitch", [0.0, 0.04])
def test_lane_lines_converge_at_the_vanishing_point(pitch: float) -> None:
    """The host carriageway's edge lines (yellow left, white right) meet at the VP."""
    cfg = CameraConfig(pitch=pitch)
    img = Renderer(cfg, scenery=False).render(_scene())
    u, v = cfg.vanishing_point
    rows = range(int(v) + 12, int(v) + 45)
    ty, tx = _line_centres(img, rows, "white", "right")
    ly, lx = _line_centres(img, rows, "yellow", "left")
    assert len(ty) > 20 and len(ly) > 20
    a1, b1 = np.polyfit(ty, tx, 1)  # col = a * row + b
    a2, b2 = np.polyfit(ly, lx, 1)
    y_meet = (b2 - b1) / (a1 - a2)
    x_meet = a1 * y_meet + b1
    assert y_meet == pytest.approx(v, abs=1.5)
    assert x_meet == pytest.approx(u, abs=1.5)
    if pitch == 0.0:  # level camera: col - cx = f X / Z and row - cy = f h / Z
        x_line = 5.55 - 0.1 - 0.075  # [m] centre of the right edge line
        assert a1 == pytest.approx(x_line / cfg.mount_height, rel=0.03)


def _coverage_width(with_car: np.ndarray, without: np.ndarray, row: int, col_c: int) -> float:
    """Sum of per-pixel coverage of the car along one image row [px]."""
    a = with_car[row].astype(np.float64)
    b = without[row].astype(np.float64)
    car = a[col_c]  # a fully covered pixel in the middle of the car
    d = car - b
    alpha = np.sum((a - b) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-9)
    return float(np.clip(alpha, 0.0, 1.0).sum())


@pytest.mark.parametrize("gap", [8.5, 20.0, 55.0, 100.0, 150.0, 198.5])
def test_lead_width_follows_focal_length_over_distance(gap: float) -> None:
    """Apparent width = focal_px * width / distance within 5 %, measured in pixels."""
    r = Renderer(CFG, scenery=False, car_detail=False)
    lead = CarView(dx=gap, lane=0, color=(20, 200, 40))
    light = dict(light_azimuth=math.pi, light_elevation=1.5)  # short shadow, lit rear
    with_car = r.render(_scene(lead, **light))
    without = r.render(_scene(**light))
    z = gap + CFG.setback  # [m] camera to the lead's rear face
    _, cy = CFG.principal_point
    row = int(round(cy + CFG.focal_px * (CFG.mount_height - 0.7) / z))  # mid-height of the box
    expected = CFG.focal_px * lead.width / z
    measured = _coverage_width(with_car, without, row, int(round(CFG.principal_point[0])))
    assert measured == pytest.approx(expected, rel=0.05)


def test_nearer_car_occludes_farther_one_in_any_list_order() -> None:
    near = CarView(dx=30.0, lane=0, color=(20, 200, 40))
    truck = CarView(dx=60.0, lane=0, color=(30, 60, 220), width=2.5, height=4.0, length=10.0)
    r = Renderer(CFG, scenery=False, car_detail=False)
    cx, cy = (int(round(c)) for c in CFG.principal_point)
    below = cy + 10  # both cars cover this pixel; the near one must win
    above = cy - 15  # only the tall far truck reaches up here
    for cars in ((near, truck), (truck, near)):
        img = r.render(_scene(*cars, light_azimuth=math.pi)).astype(int)
        g, b = img[below, cx], img[above, cx]
        assert g[1] > g[2] + 60, f"near car should be in front, got {g}"
        assert b[2] > b[1] + 60, f"far truck should show above the near car, got {b}"


def test_light_changes_shading_and_shadows() -> None:
    r = Renderer(CFG, scenery=False)
    lead = CarView(dx=15.0, lane=0)
    z = lead.dx + CFG.setback
    cx, cy = CFG.principal_point
    f = CFG.focal_px
    # shading: sun behind the camera lights the rear face, sun ahead leaves it in shade
    lit = r.render(_scene(lead, light_azimuth=math.pi, light_elevation=0.5))
    shade = r.render(_scene(lead, light_azimuth=0.0, light_elevation=0.5))
    y_body, x_body = int(cy + f * (CFG.mount_height - 0.6) / z), int(cx + f * 0.6 / z)
    assert lit[y_body, x_body].astype(int).sum() > shade[y_body, x_body].astype(int).sum() + 30

    # shadows: sun from the right throws the shadow to the left of the car, and back
    def side_darkness(img: np.ndarray) -> float:
        y = int(cy + f * CFG.mount_height / (z + 2.0))  # road beside the car's middle
        half = f * 0.9 / (z + 2.0)  # [px] half car width there
        gray = img.astype(float).mean(axis=2)
        left = gray[y - 2:y + 3, int(cx - 3 * half):int(cx - 1.3 * half)].mean()
        right = gray[y - 2:y + 3, int(cx + 1.3 * half):int(cx + 3 * half)].mean()
        return right - left  # > 0: the left side is darker

    sun_right = r.render(_scene(lead, light_azimuth=1.3, light_elevation=0.45))
    sun_left = r.render(_scene(lead, light_azimuth=-1.3, light_elevation=0.45))
    assert side_darkness(sun_right) > 15
    assert side_darkness(sun_left) < -15


def test_brake_lights_brighten_the_tail_lamps() -> None:
    r = Renderer(CFG, scenery=False)
    off = r.render(_scene(CarView(dx=12.0, lane=0))).astype(int)
    on = r.render(_scene(CarView(dx=12.0, lane=0, braking=True))).astype(int)
    z = 12.0 + CFG.setback
    cx, cy = CFG.principal_point
    y = int(round(cy + CFG.focal_px * (CFG.mount_height - 0.77) / z))
    x = int(round(cx + CFG.focal_px * (-0.9 + 0.22) / z))
    assert on[y, x, 0] > off[y, x, 0] + 60


def test_half_metre_of_gap_changes_the_preprocessed_image() -> None:
    r = Renderer(CFG)
    a = preprocess(r.render(snapshot_scene(50.0, seed=2)))
    b = preprocess(r.render(snapshot_scene(50.5, seed=2)))
    a2 = preprocess(r.render(snapshot_scene(50.0, seed=2)))
    assert np.array_equal(a, a2)
    assert not np.array_equal(a, b)
    assert np.abs(a.astype(int) - b).sum() > 100  # not a single flickering pixel


def test_lead_car_dash_moves_with_host_travel() -> None:
    r = Renderer(CFG, scenery=False)
    a = r.render(_scene(host_s=100.0))
    b = r.render(_scene(host_s=103.0))
    assert not np.array_equal(a, b)


@pytest.mark.parametrize("kw", [dict(hfov=0.0), dict(width=2), dict(pitch=1.0), dict(mount_height=-1.0)])
def test_bad_camera_config_is_rejected(kw: dict) -> None:
    with pytest.raises(ValueError):
        CameraConfig(**kw)


def test_snapshot_cli_writes_frame_and_preprocessed_view(tmp_path: Path) -> None:
    out = tmp_path / "frame.png"
    res = CliRunner().invoke(snapshot, ["--gap", "55", "--out", str(out), "--seed", "3",
                                        "--light-azimuth", "-2.0"])
    assert res.exit_code == 0, res.output
    img = cv2.imread(str(out))
    pre = cv2.imread(str(tmp_path / "frame.pre.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (400, 400, 3)
    assert pre.shape == (FRAME_H, FRAME_W) and pre.dtype == np.uint8


@pytest.mark.parametrize("args", [["--gap", "-3"], ["--out", "/nonexistent-dir/x.png"], ["--out", "x.jpg"]])
def test_snapshot_cli_rejects_bad_options(tmp_path: Path, args: list[str]) -> None:
    base = {"--gap": "50", "--out": str(tmp_path / "f.png")}
    for k, v in zip(args[::2], args[1::2], strict=True):
        base[k] = v
    res = CliRunner().invoke(snapshot, [x for kv in base.items() for x in kv])
    assert res.exit_code == 2
    assert "Error" in res.output


def test_new_seed_renders_the_same_with_cold_or_warm_caches() -> None:
    """The per-seed sky, the shared ground layers and the scenery cache hold no history."""
    from sim_server import render as render_mod

    scenes = [snapshot_scene(gap, "ev", seed=11) for gap in (12.0, 55.0)]
    scenes += [_scene(CarView(dx=30.0, lane=0), host_s=h, scenery_seed=11, light_azimuth=-2.4,
                      light_elevation=0.5) for h in (0.0, 4.0, 250.0)]
    render_mod._GROUND_CACHE.clear()
    cold = [Renderer(CFG).render(s) for s in scenes]  # a fresh renderer per frame, empty caches
    warm = Renderer(CFG)
    for seed in (1, 2, 3):  # other seeds, dash phases, lights and traffic first
        for gap in (20.0, 80.0):
            warm.render(snapshot_scene(gap, "ice", seed=seed))
    for s, c in zip(scenes, cold, strict=True):
        assert warm.render(s).tobytes() == c.tobytes()
    other = Renderer(CFG)  # a second instance sharing the ground layers
    assert all(other.render(s).tobytes() == c.tobytes() for s, c in zip(scenes, cold, strict=True))


def test_seed_changes_only_hills_and_scenery() -> None:
    """The sky row band holds the seed's hills; the road is the same for every seed."""
    r = Renderer(CFG)
    a = r.render(_scene(scenery_seed=1))
    b = r.render(_scene(scenery_seed=2))
    assert not np.array_equal(a, b)
    r0 = Renderer(CFG, scenery=False)
    assert np.array_equal(r0.render(_scene(scenery_seed=1)), r0.render(_scene(scenery_seed=2)))


def test_distant_traffic_is_still_drawn() -> None:
    """Cars a few pixels wide use a three-face model, but they are there."""
    r = Renderer(CFG, scenery=False)
    far = CarView(dx=180.0, lane=1, color=(30, 60, 220))
    with_car = r.render(_scene(far)).astype(int)
    without = r.render(_scene()).astype(int)
    z = far.dx + CFG.setback
    cx, cy = CFG.principal_point
    u = int(round(cx + CFG.focal_px * 3.7 / z))
    v = int(round(cy + CFG.focal_px * (CFG.mount_height - 0.6) / z))
    diff = np.abs(with_car - without).sum(axis=2)
    assert diff[v - 2:v + 3, u - 3:u + 4].max() > 60
    assert diff.sum() > 0 and np.count_nonzero(diff) < 200
