"""Golden frames: the renderer's bytes for a fixed set of scenes do not drift.

The SHA-256 of each case's frames is kept in ``render_hashes.json`` beside this file,
written from the renderer before its structure-only refactor (issue 53). A change of
one pixel value anywhere fails the case. Regenerate the file only for a deliberate
change of the picture::

    python tests/sim_server/test_render_hash.py --write
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from sim_server.render import CameraConfig, Renderer
from sim_server.scene import CarView, SceneState
from vacc.snapshot_cmd import snapshot_scene

HASHES = Path(__file__).with_name("render_hashes.json")


def _drive(cfg: CameraConfig, seed: int, azimuth: float, elevation: float, gap: float,
           frames: int = 40, step: float = 6.7) -> list[tuple[Renderer, SceneState]]:
    """A host driving past scenery with a lead and two neighbours: buildings and trees
    come close to and pass beside the camera, their shadows reach under it."""
    r = Renderer(cfg)
    out = []
    for k in range(frames):
        cars = (CarView(dx=gap + 0.3 * math.sin(k), lane=0, braking=k % 3 == 0),
                CarView(dx=9.0 + k % 7, lane=1, color=(40, 70, 160), lateral=0.2),
                CarView(dx=60.0 - k, lane=-3, color=(200, 170, 40)),
                CarView(dx=140.0, lane=-1, color=(30, 30, 32), length=12.0, height=3.4,
                        width=2.5))
        out.append((r, SceneState(host_s=100.0 + step * k, cars=cars, light_azimuth=azimuth,
                                  light_elevation=elevation, scenery_seed=seed)))
    return out


def _snap(gaps: tuple[float, ...], scenario: str, seed: int, cfg: CameraConfig | None = None,
          **kw: float) -> list[tuple[Renderer, SceneState]]:
    r = Renderer(cfg or CameraConfig())
    return [(r, snapshot_scene(g, scenario, seed=seed, **kw)) for g in gaps]


def _plain(scenery: bool, detail: bool) -> list[tuple[Renderer, SceneState]]:
    r = Renderer(CameraConfig(), scenery=scenery, car_detail=detail)
    cars = (CarView(dx=0.4, lane=0), CarView(dx=7.0, lane=1), CarView(dx=35.0, lane=-2),
            CarView(dx=190.0, lane=-1))
    return [(r, SceneState(host_s=s, cars=cars, light_azimuth=az, light_elevation=0.6,
                           scenery_seed=3)) for s, az in ((0.0, 0.6), (77.7, 3.0), (901.3, -1.3))]


def _few(scenery: bool, cars: tuple[CarView, ...], azimuth: float,
         elevation: float) -> list[tuple[Renderer, SceneState]]:
    """Traffic in reach of the camera, behind it and beyond its far plane."""
    r = Renderer(CameraConfig(), scenery=scenery)
    return [(r, SceneState(host_s=s, cars=cars, light_azimuth=azimuth, light_elevation=elevation,
                           scenery_seed=10)) for s in (12.0, 530.5)]


NEAR_TRAFFIC = (CarView(dx=25.0, lane=0), CarView(dx=3.0, lane=1, color=(60, 120, 70)),
                CarView(dx=1.0, lane=-1, color=(220, 220, 215)), CarView(dx=-8.0, lane=1),
                CarView(dx=500.0, lane=-1), CarView(dx=4.0, lane=-4, color=(120, 30, 100)))
PITCHED = CameraConfig(pitch=0.06)
UP = CameraConfig(pitch=-0.04, mount_height=1.1, hfov=1.0)
SMALL = CameraConfig(width=200, height=200)
WIDE = CameraConfig(width=320, height=240, hfov=1.4)

CASES: dict[str, Callable[[], list[tuple[Renderer, SceneState]]]] = {
    "ice_seed0_gaps": lambda: _snap((0.3, 2.0, 8.0, 25.0, 55.0, 120.0, 300.0), "ice", 0),
    "ev_seed5_gaps": lambda: _snap((0.3, 2.0, 8.0, 25.0, 55.0, 120.0, 300.0), "ev", 5),
    "ice_seed9_braking": lambda: _snap((1.0, 14.0, 70.0), "ice", 9, braking=True),
    "ev_low_sun_behind": lambda: _snap((0.5, 3.0, 40.0), "ev", 2, light_azimuth=3.0,
                                       light_elevation=0.05),
    "ice_sun_left_high": lambda: _snap((0.5, 20.0, 90.0), "ice", 4, light_azimuth=-1.2,
                                       light_elevation=1.3),
    "ev_sun_right_low": lambda: _snap((0.5, 20.0, 90.0), "ev", 7, light_azimuth=1.5,
                                      light_elevation=0.3),
    "ice_sun_ahead": lambda: _snap((6.0, 45.0), "ice", 11, light_azimuth=0.0,
                                   light_elevation=0.9),
    "drive_seed1_sun_behind_right": lambda: _drive(CameraConfig(), 1, 2.4, 0.35, 1.5),
    "drive_seed2_sun_left": lambda: _drive(CameraConfig(), 2, -0.9, 0.7, 30.0),
    "drive_seed6_sun_behind_left": lambda: _drive(CameraConfig(), 6, -2.8, 0.25, 0.6),
    "drive_pitched_down": lambda: _drive(PITCHED, 3, 0.6, 0.8, 4.0, frames=15),
    "drive_pitched_up": lambda: _drive(UP, 4, 2.9, 0.3, 0.8, frames=15),
    "pitched_gaps": lambda: _snap((0.3, 10.0, 60.0), "ev", 8, PITCHED),
    "small_gaps": lambda: _snap((0.3, 10.0, 60.0), "ice", 3, SMALL),
    "wide_gaps": lambda: _snap((0.3, 10.0, 60.0), "ev", 12, WIDE, light_azimuth=-2.0,
                               light_elevation=0.4),
    "near_traffic_low_sun_ahead": lambda: _few(True, NEAR_TRAFFIC, 0.1, 0.1),
    "near_traffic_sun_behind_left": lambda: _few(True, NEAR_TRAFFIC, -2.6, 0.45),
    "lead_only_no_scenery": lambda: _few(False, (CarView(dx=0.2, lane=0),), 2.0, 0.5),
    "empty_road": lambda: _few(False, (), 0.6, 0.8),
    "no_scenery": lambda: _plain(False, True),
    "no_detail": lambda: _plain(True, False),
    "no_scenery_no_detail": lambda: _plain(False, False),
}


def frame_hash(case: str) -> str:
    """SHA-256 of one case's frames, rendered in order, shape and bytes of each."""
    h = hashlib.sha256()
    for r, scene in CASES[case]():
        img = r.render(scene)
        h.update(repr(img.shape).encode())
        h.update(img.tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("case", sorted(CASES))
def test_frames_match_the_golden_hashes(case: str) -> None:
    expected = json.loads(HASHES.read_text())
    assert frame_hash(case) == expected[case], f"frames of {case!r} changed"


def test_every_case_has_a_golden_hash() -> None:
    assert sorted(json.loads(HASHES.read_text())) == sorted(CASES)


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/sim_server/test_render_hash.py --write")
    HASHES.write_text(json.dumps({c: frame_hash(c) for c in sorted(CASES)}, indent=1) + "\n")
