"""Front-camera software raster renderer (numpy + OpenCV, no GPU, no game engine).

A pinhole camera on the host car looks down the road. World frame: ``X`` lateral
[m] (0 = centre of the host's lane, + right), ``Y`` up [m] (0 = road), ``Z`` along
the road [m] measured from the camera. A world point maps to pixel coordinates
(pixel centres at integers, the image centre at ``((W-1)/2, (H-1)/2)``) by::

    z_c = Z cos(pitch) - (Y - h) sin(pitch)
    u   = c_x + f X / z_c
    v   = c_y - f ((Y - h) cos(pitch) + Z sin(pitch)) / z_c

with ``f = (W/2) / tan(hfov/2)`` and ``h`` the mount height. The road's vanishing
point is ``(c_x, c_y - f tan(pitch))``.

How a frame is made (painter's algorithm, far to near):

1. the sky band (rows above the horizon: gradient, the seed's hills; cached per seed)
   stacked on the ground band for the current lane-dash phase bucket (grass, both
   carriageways, median barrier, lines, haze and dashes; :data:`PHASE_BUCKETS` per
   dash period, cached once per camera configuration for all seeds);
2. ground shadows: trees, buildings and traffic into one binary mask, copied from a
   darkened twin of the ground band; the lead car's shadow with anti-aliased edges;
3. buildings, then trees, then cars, each far to near (scenery stands beside the
   road, so it never hides a car);
4. cars use ``cv2.LINE_AA`` with 4 fractional bits (1/16 px) per coordinate, shrunk
   by :data:`AA_INSET` so their edge pixels hold the true coverage; scenery uses
   aliased ``LINE_8`` fills.

Per-frame cost is call overhead, not pixels: scenery geometry is computed in Python
scalars from a per-tile cache, car faces in one numpy pass, and objects wholly outside
the picture are skipped.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import cv2
import numpy as np

from protocol.constants import CAMERA_HFOV, CAMERA_MOUNT_HEIGHT, CAMERA_SIZE
from protocol.messages import MIN_IMAGE_SIDE
from sim_server import scenery as sc
from sim_server.scene import CAR_HEIGHT, CAR_LENGTH, CAR_WIDTH, CarView, SceneState

__all__ = ["CameraConfig", "Renderer", "in_format"]

SHIFT = 4  # fractional bits of cv2 drawing coordinates (1/16 px)
ONE = 1 << SHIFT
AA = cv2.LINE_AA  # cars and road: anti-aliased, sub-pixel
L8 = cv2.LINE_8  # scenery: aliased but 2-3x cheaper, and masked out before the network
PHASE_BUCKETS = 32  # cached backgrounds per dash period (12.19 m / 32 = 0.38 m)
SHADOW_FACTOR = 0.55  # shadowed ground keeps this fraction of its light
AMBIENT = 0.5  # share of light on a face turned away from the sun
DIFFUSE = 0.6  # Lambert term weight
MIN_SUN_ELEVATION = 0.2  # [rad] caps shadow length at ~5 object heights
SCENERY_FAR = 220.0  # [m] trees and buildings are drawn up to here (cost grows with it)
SHADOW_FAR = 150.0  # [m] scenery and traffic shadows beyond this are thin slivers at the horizon
AA_INSET = 0.7  # [px] cv2's LINE_AA fill paints this far beyond each edge (measured)
LOD_WIDTH = 12.0  # [px] traffic narrower than this is drawn without small parts
TINY_WIDTH = 6.0  # [px] traffic narrower than this is drawn as three faces


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera mounted on the host car.

    The defaults put the horizon on the middle row, show a car at 10 m whole (about
    87 px wide) and a car at 200 m as a 4 px blob, and make the lead at 55 m about
    15 px wide (7 px at the network's half resolution).

    Attributes:
        width: image width [px].
        height: image height [px].
        mount_height: camera height above the road [m] (roof-line dash camera).
        pitch: downward tilt of the optical axis [rad]; 0 = level, horizon mid-image.
        hfov: horizontal field of view [rad] (45 deg).
        setback: camera distance behind the host's front bumper [m]; the lead's rear
            is ``gap + setback`` from the camera.
        near: near clipping distance [m].
        far: objects beyond this distance are not drawn [m].
    """

    width: int = CAMERA_SIZE[0]  # [px]
    height: int = CAMERA_SIZE[1]  # [px]
    mount_height: float = CAMERA_MOUNT_HEIGHT  # [m]
    pitch: float = 0.0  # [rad]
    hfov: float = CAMERA_HFOV  # [rad]
    setback: float = 1.5  # [m]
    near: float = 0.5  # [m]
    far: float = 450.0  # [m]

    def __post_init__(self) -> None:
        if self.width < MIN_IMAGE_SIDE or self.height < MIN_IMAGE_SIDE:
            raise ValueError(f"image must be at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE} px, got {self.width}x{self.height}")
        if not 0.05 < self.hfov < 3.0:
            raise ValueError(f"hfov must be in (0.05, 3.0) rad, got {self.hfov}")
        if not abs(self.pitch) < 0.5:
            raise ValueError(f"|pitch| must be below 0.5 rad, got {self.pitch}")
        if self.mount_height <= 0:
            raise ValueError(f"mount_height must be positive, got {self.mount_height}")

    @property
    def focal_px(self) -> float:
        """Focal length [px] (square pixels): ``(width/2) / tan(hfov/2)``."""
        return 0.5 * self.width / math.tan(0.5 * self.hfov)

    @property
    def principal_point(self) -> tuple[float, float]:
        """Image centre ``(c_x, c_y)`` [px], pixel centres at integers."""
        return 0.5 * (self.width - 1), 0.5 * (self.height - 1)

    @property
    def vanishing_point(self) -> tuple[float, float]:
        """Where the road's parallel lines meet ``(u, v)`` [px]."""
        cx, cy = self.principal_point
        return cx, cy - self.focal_px * math.tan(self.pitch)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points to pixel coordinates.

        Args:
            points: ``(..., 3)`` array of ``(X, Y, Z)`` [m], Z measured from the camera.

        Returns:
            ``(..., 2)`` float array of ``(u, v)`` [px]. Points with ``Z <= 0`` give
            meaningless values; callers clip first.
        """
        p = np.asarray(points, dtype=np.float64)
        u, v = _pinhole(self)(p[..., 0], p[..., 1], p[..., 2])
        return np.stack((u, v), axis=-1)


_Projection = Callable[[Any, Any, Any], tuple[Any, Any]]


def _pinhole(cfg: CameraConfig, *, shortcut: bool = False) -> _Projection:
    """The camera's projection ``(X, Y, Z) -> (u, v)`` [m -> px], the one place it is written.

    The returned function takes Python floats (a few points, cheaper than numpy) or
    numpy arrays of one shape, elementwise with the same operations, so both give
    the same bits.

    Args:
        cfg: the camera.
        shortcut: for a level camera, evaluate ``u = X / Z f + c_x`` and
            ``v = (h - Y) / Z f + c_y`` (fewer operations; the renderer's objects).
            Its last bits can differ from the general form's, which the cached road
            layers and :meth:`CameraConfig.project` use, so each caller keeps the form
            it was drawn with (frames stay bit-identical).

    Returns:
        ``project(x, y, z) -> (u, v)``; points with ``Z <= 0`` give meaningless values.
    """
    f = cfg.focal_px
    cx, cy = cfg.principal_point
    h = cfg.mount_height
    if shortcut and cfg.pitch == 0.0:
        def project_level(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
            return x / z * f + cx, (h - y) / z * f + cy
        return project_level
    cp, sp = math.cos(cfg.pitch), math.sin(cfg.pitch)

    def project(x: Any, y: Any, z: Any) -> tuple[Any, Any]:
        dy = y - h
        zc = z * cp - dy * sp
        return cx + f * x / zc, cy - f * (dy * cp + z * sp) / zc
    return project


# --- car model ----------------------------------------------------------------------
# Boxes in a car's own frame for the default 4.6 x 1.8 x 1.45 m car, scaled per car.
# x: +-half width, y: height, z: 0 at the face nearest the camera.
_W2 = CAR_WIDTH / 2
_H = CAR_HEIGHT
_L = CAR_LENGTH


class _Box(NamedTuple):
    """An axis-aligned box in a car's own frame [m]."""

    x0: float
    x1: float
    y0: float
    y1: float
    z0: float
    z1: float


class _Decal(NamedTuple):
    """A quad on a car's face at depth ``z`` in the car's own frame [m]."""

    x0: float
    x1: float
    y0: float
    y1: float
    z: float


_BOXES = {
    "under": _Box(-_W2 + 0.1, _W2 - 0.1, 0.0, 0.36, 0.3, _L - 0.3),
    "body": _Box(-_W2, _W2, 0.30, 0.95, 0.0, _L),
    "cabin": _Box(-_W2 + 0.1, _W2 - 0.1, 0.95, _H, 0.75, _L - 1.2),
    "plain": _Box(-_W2, _W2, 0.0, _H, 0.0, _L),  # the whole car as one box (car_detail=False)
}
_DECALS_REAR = {  # quads on the near faces
    "window": _Decal(-_W2 + 0.2, _W2 - 0.2, 1.0, _H - 0.05, 0.75),
    "bumper": _Decal(-_W2, _W2, 0.30, 0.40, 0.0),
    "plate": _Decal(-0.26, 0.26, 0.44, 0.56, 0.0),
    "tail_l": _Decal(-_W2 + 0.05, -_W2 + 0.40, 0.70, 0.84, 0.0),
    "tail_r": _Decal(_W2 - 0.40, _W2 - 0.05, 0.70, 0.84, 0.0),
}
_DECALS_BRAKE = {  # lit lamps bloom a little and the centre brake light comes on
    "window": _DECALS_REAR["window"],
    "bumper": _DECALS_REAR["bumper"],
    "plate": _DECALS_REAR["plate"],
    "brake_l": _Decal(-_W2 + 0.03, -_W2 + 0.44, 0.68, 0.86, 0.0),
    "brake_r": _Decal(_W2 - 0.44, _W2 - 0.03, 0.68, 0.86, 0.0),
    "brake_c": _Decal(-0.22, 0.22, _H - 0.13, _H - 0.07, 0.75),
}
_DECALS_FRONT = {
    "window": _Decal(-_W2 + 0.18, _W2 - 0.18, 1.0, _H - 0.04, 1.2),
    "bumper": _Decal(-_W2, _W2, 0.30, 0.40, 0.0),
    "plate": _Decal(-0.26, 0.26, 0.42, 0.52, 0.0),
    "grille": _Decal(-0.45, 0.45, 0.55, 0.72, 0.0),
    "head_l": _Decal(-_W2 + 0.08, -_W2 + 0.45, 0.64, 0.76, 0.0),
    "head_r": _Decal(_W2 - 0.45, _W2 - 0.08, 0.64, 0.76, 0.0),
}
# corner index within a box = ix + 2*iy + 4*iz
_FACE_NEAR = (0, 1, 3, 2)
_FACE_LEFT = (0, 4, 6, 2)
_FACE_RIGHT = (1, 5, 7, 3)
_FACE_TOP = (2, 3, 7, 6)


class _Visible(NamedTuple):
    """When a box's side face shows: ``side`` ``left`` (its left side ``at`` [m] is
    right of the camera), ``right`` (left of the camera) or ``top`` (the camera is
    above its top ``at`` [m]); in the car's frame, scaled with the car."""

    side: str
    at: float  # [m]


class _Face(NamedTuple):
    """A face of a car model: ``role`` names its colour; ``when`` is None if always drawn."""

    role: str
    when: _Visible | None


@dataclass(frozen=True)
class _CarTemplate:
    """Corner points of a car model and its faces in drawing order.

    ``index[j]`` holds the 4 point indices of ``faces[j]``.
    """

    points: np.ndarray  # (N, 3) [m]
    index: np.ndarray  # (F, 4) int
    faces: tuple[_Face, ...]


def _make_template(kind: str, lod: bool = False, tiny: bool = False) -> _CarTemplate:
    """Build a car model: ``rear``, ``brake`` (rear, braking), ``front`` or ``plain``.

    ``lod`` drops what is sub-pixel on a distant car: the underbody, the cabin's
    sides and top, the bumper and the plate.
    ``tiny`` keeps only three near faces: the underbody, the body and the cabin drawn
    as glass (a car a few pixels wide).
    """
    oncoming = kind == "front"
    if tiny:
        lod = False
    boxes = ("plain",) if kind == "plain" else (("body", "cabin") if lod else ("under", "body", "cabin"))
    decals = {"rear": _DECALS_REAR, "brake": _DECALS_BRAKE, "front": _DECALS_FRONT,
              "plain": {}}[kind]
    if lod:
        decals = {k: v for k, v in decals.items() if k not in ("bumper", "plate", "grille")}
    if tiny:
        decals = {}
    pts: list[tuple[float, float, float]] = []
    index: list[list[int]] = []
    faces: list[_Face] = []
    for name in boxes:
        x0, x1, y0, y1, z0, z1 = _BOXES[name]
        if oncoming:  # mirrored: the cabin sits further from the near (front) face
            z0, z1 = _L - z1, _L - z0
        o = len(pts)
        pts += [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
        if name == "under" or tiny:
            index.append([o + c for c in _FACE_NEAR])
            faces.append(_Face("under" if name == "under" else ("near" if name == "body" else "window"), None))
            continue
        sides: tuple[tuple[tuple[int, ...], str, _Visible], ...] = (
            (_FACE_LEFT, "left", _Visible("left", x0)), (_FACE_RIGHT, "right", _Visible("right", x1)),
            (_FACE_TOP, "top", _Visible("top", y1)))
        if lod and name == "cabin":
            sides = ()
        for face, role, cond in (*sides, (_FACE_NEAR, "near", None)):
            index.append([o + c for c in face])
            faces.append(_Face(role, cond))
    for name, (x0, x1, y0, y1, z) in decals.items():
        o = len(pts)
        pts += [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]
        index.append([o, o + 1, o + 2, o + 3])
        faces.append(_Face(name.split("_")[0], None))
    return _CarTemplate(np.array(pts, np.float64), np.array(index, np.intp), tuple(faces))


_TEMPLATES = {k: _make_template(k) for k in ("rear", "brake", "front", "plain")}
_TEMPLATES.update({k + "_lod": _make_template(k, lod=True) for k in ("rear", "brake", "front")})
_TEMPLATES.update({k + "_tiny": _make_template(k, tiny=True) for k in ("rear", "brake", "front")})
# fixed colours (RGB) of the parts that are not body paint; lamps are emissive
_FIXED = {
    "under": ((28, 28, 30), 0.0),
    "window": ((40, 48, 60), 0.15),
    "bumper": ((45, 45, 48), 0.2),
    "plate": ((225, 225, 215), 0.1),
    "grille": ((30, 30, 32), 0.0),
}
_LAMPS = {"tail": (125, 18, 18), "brake": (255, 45, 35), "head": (245, 240, 215)}
_HR, _HG, _HB = (float(c) for c in sc.HAZE)


def _shade(rgb: tuple[float, ...] | np.ndarray, lam: float, fog: float) -> tuple[float, float, float]:
    """Lambert shading (ambient + diffuse * max(lam, 0)), then haze; an RGB tuple."""
    k = AMBIENT + DIFFUSE * (lam if lam > 0.0 else 0.0)
    g = 1.0 - fog
    r, gg, b = float(rgb[0]) * k, float(rgb[1]) * k, float(rgb[2]) * k
    return (min(r, 255.0) * g + _HR * fog, min(gg, 255.0) * g + _HG * fog,
            min(b, 255.0) * g + _HB * fog)


def _haze(rgb: tuple[float, ...], fog: float) -> tuple[float, float, float]:
    """A colour (lit or emissive) seen through haze of density ``fog`` (0 to 1)."""
    g = 1.0 - fog
    return (rgb[0] * g + _HR * fog, rgb[1] * g + _HG * fog, rgb[2] * g + _HB * fog)


def _clip_near(poly: np.ndarray, z_near: float) -> np.ndarray:
    """Clip a convex polygon ``(N, 3)`` to ``Z >= z_near`` (Sutherland-Hodgman)."""
    if poly[:, 2].min() >= z_near:
        return poly
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ina, inb = a[2] >= z_near, b[2] >= z_near
        if ina:
            out.append(a)
        if ina != inb:
            t = (z_near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out) if out else np.zeros((0, 3))


def _fix(uv: np.ndarray) -> np.ndarray:
    """Pixel coordinates to cv2 fixed point (``SHIFT`` fractional bits), int32."""
    return np.rint(uv * ONE).astype(np.int32)


def _shrink(uv: np.ndarray, d: float = AA_INSET) -> np.ndarray:
    """Pull polygon vertices ``(..., n, 2)`` [px] towards their centroid by ``d`` [px] per axis.

    The one shrink step: ``d = AA_INSET`` for anti-aliased fills, 0.5 for ``LINE_8``
    fills, which paint every pixel whose centre is on or inside the outline.

    cv2's anti-aliased fill covers about :data:`AA_INSET` px beyond every edge, so
    a polygon drawn as given comes out 1.4 px too wide and tall. Shrinking each
    coordinate towards the centroid removes that bias exactly for the axis-aligned
    rectangles that car and building faces are (a level camera sees vertical planes
    facing it as rectangles) and nearly for their trapezoidal sides. Parts thinner
    than 1.4 px collapse to a line, which cv2 draws about 1 px wide.

    The centroid is summed vertex by vertex in order (numpy reduces a middle axis
    row by row), and an offset inside ``d`` becomes a zero whose sign the later
    rounding to fixed point drops, so small and batched calls give the same bits.
    """
    c = uv.sum(axis=-2, keepdims=True)
    c *= 1.0 / uv.shape[-2]
    r = uv - c
    return c + np.copysign(np.maximum(np.abs(r) - d, 0.0), r)


class _SweepPattern(NamedTuple):
    """Which corners of a ground rectangle make up its shadow hexagon for one sun.

    Point ``k`` of the hexagon is ``(x[ix[k]] + moved[k] a, z[iz[k]] + moved[k] b)``
    with ``x = (x0, x1)``, ``z = (z0, z1)`` and ``(a, b)`` [m] the shadow's ground
    displacement; 6 points, the last repeated as padding where the sweep gives 4.
    """

    ix: np.ndarray  # (6,) int: 0 for x0, 1 for x1
    iz: np.ndarray  # (6,) int: 0 for z0, 1 for z1
    moved: np.ndarray  # (6,) float: 1.0 where the point is displaced
    corners: list[tuple[int, int, float]]  # the same as Python scalars (ix, iz, moved)


def _sweep_pattern(a: float, b: float) -> _SweepPattern:
    """The shadow hexagon of a box whose top is displaced by ``(a, b)`` on the ground.

    The shadow is the box's footprint swept along ``(a, b)``. The pattern depends only
    on the signs, so one pattern serves every box of a frame (all heights are
    positive).
    """
    corners = ((0, 0), (1, 0), (1, 1), (0, 1))  # counter-clockwise in (X, Z)
    leads = (-b > 0, a > 0, b > 0, -a > 0)  # edge c_i c_i+1 faces along the sweep
    pts: list[tuple[int, int, int]] = []
    for i, (x, z) in enumerate(corners):
        prev_lead, next_lead = leads[i - 1], leads[i]
        if not prev_lead:
            pts.append((x, z, 0))
        if prev_lead or next_lead:
            pts.append((x, z, 1))
        if prev_lead and not next_lead:
            pts.append((x, z, 0))
    pts += [pts[-1]] * (6 - len(pts))
    ix, iz, mv = (np.array(c) for c in zip(*pts, strict=True))
    moved = mv.astype(np.float64)
    return _SweepPattern(ix, iz, moved, list(zip(ix.tolist(), iz.tolist(), moved.tolist(), strict=True)))


def _swept_many(x0: np.ndarray, x1: np.ndarray, z0: np.ndarray, z1: np.ndarray, a: np.ndarray,
                b: np.ndarray, pattern: _SweepPattern) -> np.ndarray:
    """Shadow hexagons of many boxes at once: ``(N, 6, 3)`` ground points (Y = 0) [m]."""
    out = np.zeros((len(x0), 6, 3))
    out[:, :, 0] = np.where(pattern.ix, x1[:, None], x0[:, None]) + pattern.moved * a[:, None]
    out[:, :, 2] = np.where(pattern.iz, z1[:, None], z0[:, None]) + pattern.moved * b[:, None]
    return out


def _inset_many(poly: np.ndarray, d: float = AA_INSET) -> np.ndarray:
    """Offset each edge of convex polygons ``(N, n, 2)`` [px] inwards by ``d`` [px] (miter).

    Polygons thinner than the offset fall back to the per-axis :func:`_shrink`.
    """
    x, y = poly[..., 0], poly[..., 1]
    xr, yr = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    area2 = np.sum(x * yr - xr * y, axis=-1)
    n = np.stack([y - yr, xr - x], -1) * np.where(area2 > 0, 1.0, -1.0)[:, None, None]
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    n_prev = np.roll(n, 1, axis=-2)
    denom = np.maximum(1.0 + np.sum(n * n_prev, axis=-1, keepdims=True), 0.2)
    out = poly + d * (n + n_prev) / denom
    xo, yo = out[..., 0], out[..., 1]
    area2_out = np.sum(xo * np.roll(yo, -1, axis=-1) - np.roll(xo, -1, axis=-1) * yo, axis=-1)
    bad = area2_out * area2 <= 0  # thinner than the AA fringe: fall back to per-axis shrink
    if bad.any():
        out[bad] = _shrink(poly[bad])
    return out


def _fill_batched(img: np.ndarray, polys: np.ndarray, color: float | tuple, line: int) -> None:
    """Fill fixed-point polygons ``(N, k, 2)`` of one colour with as few cv2 calls as possible.

    ``cv2.fillPoly`` fills by the even-odd rule, so only polygons whose bounding
    boxes overlap no other go into the one batched call; the rest are drawn alone.
    """
    n = len(polys)
    if n == 0:
        return
    if n == 1:
        cv2.fillConvexPoly(img, polys[0], color, line, SHIFT)
        return
    lo = polys.min(axis=1)
    hi = polys.max(axis=1)
    pad = ONE + 2 if line == AA else 2  # the anti-aliased fringe reaches beyond the outline
    ov = ((lo[:, None, :] <= hi[None, :, :] + pad) & (lo[None, :, :] <= hi[:, None, :] + pad)).all(axis=2)
    alone = ov.sum(axis=1) == 1
    if alone.all():
        cv2.fillPoly(img, list(polys), color, line, SHIFT)
        return
    if alone.any():
        cv2.fillPoly(img, list(polys[alone]), color, line, SHIFT)
    for p in polys[~alone]:
        cv2.fillConvexPoly(img, p, color, line, SHIFT)


# --- records: scene objects, visible cars, the frame's sun and draw lists -------------
_RGB = tuple[float, float, float]


class _Tree(NamedTuple):
    """A roadside tree in road coordinates, lit for the frame's sun but not yet hazed."""

    s: float  # [m] road position of the trunk
    x: float  # [m] lateral position of the trunk
    crown_y: float  # [m] height of the crown's centre
    radius: float  # [m] crown radius
    lit_dx: float  # [m] the sunlit spot's offset from the crown's centre, lateral
    lit_dy: float  # [m] the sunlit spot's offset from the crown's centre, up
    crown_rgb: _RGB  # crown colour in shade
    lit_rgb: _RGB  # colour of the sunlit spot
    shadow_x: tuple[float, ...]  # [m] the crown's shadow hexagon on the ground, lateral
    shadow_s: tuple[float, ...]  # [m] the crown's shadow hexagon, road position
    shadow_reach: float  # [m] how far the shadow may reach nearer to the camera than ``s``


class _Building(NamedTuple):
    """A roadside building in road coordinates, lit for the frame's sun but not yet hazed."""

    s: float  # [m] road position of the face towards the camera
    x_wall: float  # [m] lateral position of the road-facing wall
    x_far: float  # [m] lateral position of the back wall
    length: float  # [m] along the road
    height: float  # [m]
    floors: int  # window bands on the road-facing wall
    near_rgb: _RGB  # colour of the face towards the camera
    wall_rgb: _RGB  # colour of the road-facing wall
    shadow_x: tuple[float, ...]  # [m] the shadow hexagon on the ground, lateral
    shadow_s: tuple[float, ...]  # [m] the shadow hexagon, road position
    shadow_reach: float  # [m] how far the shadow reaches nearer to the camera than ``s``


class _SceneryWindow(NamedTuple):
    """The scenery of the road ahead, far to near."""

    trees: list[_Tree]
    neg_s: list[float]  # [m] ``-tree.s``, ascending, for bisection
    buildings: list[_Building]


class _CarItem(NamedTuple):
    """A car in front of the camera, placed in the camera's frame."""

    z_near: float  # [m] camera to the car's face nearest to it, along the road
    x: float  # [m] lateral position of the car's centre
    oncoming: bool  # faces the camera (beyond the median)
    car: CarView
    is_lead: bool


class _Sun(NamedTuple):
    """The frame's light."""

    light: tuple[float, float, float]  # unit vector towards the sun (X, Y, Z)
    shift: tuple[float, float]  # [m/m] ground displacement (X, Z) of a shadow per metre of height
    pattern: _SweepPattern  # shadow hexagon corners for this sun


class _BuildingDraw(NamedTuple):
    """A visible building: its first quad in :attr:`_SceneryView.quads` and hazed colours.

    The quads are the face towards the camera (when ``near``), the road-facing wall,
    then ``windows`` window bands.
    """

    quad: int
    near: bool  # the face towards the camera is in front of the camera
    windows: int
    near_rgb: _RGB
    wall_rgb: _RGB
    window_rgb: _RGB


class _Disc(NamedTuple):
    """A filled circle in cv2 fixed point."""

    center: tuple[int, int]  # [px / ONE]
    radius: int  # [px / ONE]
    rgb: _RGB


class _TreeDraw(NamedTuple):
    """A visible tree: trunk quad (None when its crown hides it), crown, sunlit spot."""

    trunk: int | None  # index in :attr:`_SceneryView.quads`
    trunk_rgb: _RGB | None
    crown: _Disc
    lit: _Disc | None


class _SceneryView(NamedTuple):
    """What the scenery adds to one frame, far to near, in cv2 fixed point."""

    quads: np.ndarray  # (N, 4, 2) int32: building faces, windows and trunks
    buildings: list[_BuildingDraw]
    trees: list[_TreeDraw]
    shadows: np.ndarray  # (M, 6, 2) int32 ground shadow hexagons
    clipped: list[np.ndarray]  # near-clipped shadow polygons of other sizes


class _CarShadows(NamedTuple):
    """The cars' ground shadows in cv2 fixed point."""

    hexes: np.ndarray  # (N, 6, 2) int32: traffic, shrunk for LINE_8
    clipped: list[np.ndarray]  # traffic shadows clipped at the camera
    soft: np.ndarray | None  # the lead's, shrunk for an anti-aliased fill


class Renderer:
    """Renders :class:`~sim_server.scene.SceneState` snapshots to RGB images.

    The renderer caches the static background per lane-dash phase bucket and the
    scenery of the road ahead; the output depends only on the ``SceneState`` (and
    the flags below), so the same state always gives identical bytes.

    Args:
        config: the camera.
        scenery: draw trees, buildings and distant hills (off only for tests and
            diagnostics on a plain road).
        car_detail: draw lights, plates, windows, bumpers and cabins (off gives
            plain boxes; used to measure apparent widths exactly).
    """

    def __init__(self, config: CameraConfig | None = None, *, scenery: bool = True,
                 car_detail: bool = True) -> None:
        self.config = config or CameraConfig()
        self.scenery = scenery
        self.car_detail = car_detail
        self._sky_cache: dict[int, np.ndarray] = {}
        self._pattern: dict[tuple[float, float], _SweepPattern] = {}
        self._win: _SceneryWindow | None = None
        self._win_key: tuple | None = None
        self._scenery = sc.SceneryCache()
        self._face_cache: dict[tuple, tuple[np.ndarray, list]] = {}
        cfg = self.config
        self._f = cfg.focal_px
        self._h = cfg.mount_height
        self._level = cfg.pitch == 0.0  # cars beside the picture can be culled by X/Z alone
        self._cx, self._cy = cfg.principal_point
        self._project = _pinhole(cfg, shortcut=True)  # scenery, cars and shadows
        self._project_exact = _pinhole(cfg)  # the form CameraConfig.project uses
        self._horizon = cfg.vanishing_point[1]
        # smallest ground depth in view: below this the road is under the image
        self._z_ground_min = max(cfg.near, 0.5)
        # first row that holds only ground (pure haze at the horizon): rows above it are
        # sky and hills (per seed), rows from it down come from the ground layers
        self._g0 = min(max(int(math.floor(self._horizon)), 0), cfg.height)

    # ------------------------------------------------------------------ background
    def _sky_gradient(self, height: int | None = None) -> np.ndarray:
        """The sky gradient (rows by ray elevation): the top ``height`` rows of a frame."""
        cfg = self.config
        rows = np.arange(cfg.height if height is None else height, dtype=np.float64)
        elev = np.arctan((self._cy - rows) / self._f) - cfg.pitch  # [rad] ray elevation per row
        t = np.clip(elev / 0.45, 0.0, 1.0)[:, None]
        sky = (sc.SKY_HORIZON * (1 - t) + sc.SKY_TOP * t).astype(np.float32).astype(np.uint8)
        return np.repeat(sky[:, None, :], cfg.width, axis=1)

    def _draw_road(self, img: np.ndarray) -> None:
        """Both carriageways, shoulders, median, solid lines and barrier, in one projection."""
        z0, z1 = self._z_ground_min, 6000.0
        quads = np.zeros((len(_STRIPS) + 2, 4, 3))
        for i, (x0, x1, _) in enumerate(_STRIPS):
            quads[i] = [[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]]
        bx = sc.BARRIER_X + 0.5 * sc.BARRIER_WIDTH  # median barrier: the top, then the host-facing side
        bh = sc.BARRIER_HEIGHT
        quads[-2] = [[bx - sc.BARRIER_WIDTH, bh, z0], [bx, bh, z0], [bx, bh, z1], [bx - sc.BARRIER_WIDTH, bh, z1]]
        quads[-1] = [[bx, 0, z0], [bx, bh, z0], [bx, bh, z1], [bx, 0, z1]]
        fx = _fix(_inset_many(self.config.project(quads)))
        cols = [c for _, _, c in _STRIPS] + [tuple(0.95 * c for c in sc.CONCRETE),
                                            tuple(0.8 * c for c in sc.CONCRETE)]
        for poly, col in zip(fx, cols, strict=True):
            cv2.fillConvexPoly(img, poly, col, AA, SHIFT)

    def _ground_static(self) -> np.ndarray:
        """Full frame without hills or dashes: sky, grass, road, haze (once per camera)."""
        cfg = self.config
        H = cfg.height
        img = self._sky_gradient()
        g0 = self._g0
        img[g0:] = np.array(sc.GRASS, np.uint8)
        if 0 <= g0 < H and math.floor(self._horizon) == g0:  # horizon row: partial grass
            a = float(np.clip(g0 + 0.5 - self._horizon, 0.0, 1.0))
            img[g0] = (img[max(g0 - 1, 0)] * (1 - a) + np.array(sc.GRASS) * a).astype(np.uint8)
        self._draw_road(img)
        # haze: every ground row is at one depth (no roll), so fog per row is exact
        rows = np.arange(H, dtype=np.float64)
        below = rows - self._horizon
        with np.errstate(divide="ignore", invalid="ignore"):
            zrow = np.where(below > 0, self._ground_depth(rows), np.inf)
        fog = (1.0 - np.exp(-zrow / sc.FOG_DISTANCE)).astype(np.float32)
        rs = slice(g0, H)
        blended = img[rs].astype(np.float32) * (1 - fog[rs, None, None]) + sc.HAZE * fog[rs, None, None]
        img[rs] = np.clip(blended + 0.5, 0, 255).astype(np.uint8)
        return img

    def _sky(self, seed: int) -> np.ndarray:
        """Rows above the horizon: sky, hills from the seed, the road's far fringe.

        The only per-seed layer. It is drawn into the rows above the horizon and a few
        below (enough for the anti-aliased edges; the pixels come out the same as in
        a full frame), which takes a fraction of a millisecond.
        """
        key = seed if self.scenery else -1
        hit = self._sky_cache.get(key)
        if hit is not None:
            return hit
        cfg = self.config
        img = self._sky_gradient(min(self._g0 + 4, cfg.height))
        if self.scenery:
            W, f = cfg.width, self._f
            prof = sc.hills_profile(seed)
            us = np.linspace(-2, W + 2, len(prof))
            vs = self._horizon - f * np.tan(prof)
            poly = np.concatenate([np.stack([us, vs], 1), [[W + 2, self._horizon + 1], [-2, self._horizon + 1]]])
            hill = tuple(float(0.55 * c + 0.45 * h) for c, h in zip(sc.HILLS, sc.HAZE, strict=True))
            cv2.fillPoly(img, [_fix(poly)], hill, AA, SHIFT)
        self._draw_road(img)  # its anti-aliased far end reaches a row above the horizon
        sky = img[:self._g0].copy()
        if len(self._sky_cache) >= 4:
            self._sky_cache.clear()
        self._sky_cache[key] = sky
        return sky

    def _ground_depth(self, v: np.ndarray) -> np.ndarray:
        """Depth Z [m] of the road point seen at image row ``v`` (below the horizon)."""
        cfg = self.config
        a = np.arctan((v - self._cy) / self._f) + cfg.pitch  # [rad] angle below horizontal
        return cfg.mount_height / np.tan(a)

    def _background(self, bucket: int) -> tuple[np.ndarray, np.ndarray]:
        """Ground rows (from the horizon down) and their shadowed twin for one dash phase.

        They do not depend on the seed, so they are built once per camera
        configuration and shared by all renderers in the process.
        """
        layers = _GROUND_CACHE.get(self.config)
        if layers is None:
            if len(_GROUND_CACHE) >= 4:
                _GROUND_CACHE.clear()
            layers = _GROUND_CACHE[self.config] = {-1: (self._ground_static(), np.empty(0, np.uint8))}
        hit = layers.get(bucket)
        if hit is not None:
            return hit
        cfg = self.config
        img = layers[-1][0].copy()
        phase = bucket * sc.DASH_PERIOD / PHASE_BUCKETS  # [m] camera position within a period
        za = np.arange(0.0, cfg.far + sc.DASH_PERIOD + 1.0, sc.DASH_PERIOD) - phase
        za = za[za <= cfg.far]
        zb = za + sc.DASH_LENGTH
        keep = zb >= self._z_ground_min
        za, zb = np.maximum(za[keep], self._z_ground_min), zb[keep]
        fog = 1.0 - np.exp(-0.5 * (za + zb) / sc.FOG_DISTANCE)
        cols = (np.array(sc.WHITE) * (1 - fog[:, None]) + sc.HAZE.astype(np.float64) * fog[:, None]).tolist()
        hw = 0.5 * sc.LINE_WIDTH
        n, m = len(za), len(sc.DASH_X)
        quads = np.zeros((n, m, 4, 3))
        xs = np.array(sc.DASH_X)[None, :, None]
        quads[..., 0] = xs + np.array([-hw, hw, hw, -hw])
        quads[..., 2] = np.stack([za, za, zb, zb], 1)[:, None, :]
        fx = _fix(_inset_many(cfg.project(quads.reshape(n * m, 4, 3)))).reshape(n, m, 4, 2)
        for k in range(n):
            col = tuple(cols[k])
            for poly in fx[k]:
                cv2.fillConvexPoly(img, poly, col, AA, SHIFT)
        ground = img[self._g0:].copy()
        hit = (ground, cv2.convertScaleAbs(ground, alpha=SHADOW_FACTOR))
        layers[bucket] = hit
        return hit

    # ---------------------------------------------------------------------- frame
    def _proj(self, p: np.ndarray) -> np.ndarray:
        """Project points ``(..., 3)`` [m] to pixels ``(..., 2)`` with :attr:`_project`."""
        u, v = self._project(p[..., 0], p[..., 1], p[..., 2])
        return np.stack((u, v), axis=-1)

    def render(self, scene: SceneState) -> np.ndarray:
        """Render one camera frame.

        Args:
            scene: what is visible now.

        Returns:
            ``(height, width, 3)`` uint8 RGB image, C-contiguous, owned by the caller.

        Raises:
            ValueError: a car is in a lane that does not exist.
        """
        s_cam = scene.host_s - self.config.setback  # [m] camera position along the road
        img, dark = self._backdrop(scene.scenery_seed, s_cam)
        sun = self._sun(scene.light_azimuth, scene.light_elevation)
        cars = self._cars_ahead(scene)
        view = self._scenery_view(scene.scenery_seed, s_cam, sun) if self.scenery else None
        # 1. shadows on the ground (nothing stands on the ground in front of them)
        self._draw_shadows(img, dark, view, cars, sun)
        # 2. buildings, then trees far to near: they stand beside the road, farther out
        # than any car, so they never hide a car (a car may hide them)
        if view is not None:
            self._draw_buildings(img, view)
            self._draw_trees(img, view)
        # 3. cars, far to near
        self._draw_cars(img, cars, sun.light)
        return img

    def _backdrop(self, seed: int, s_cam: float) -> tuple[np.ndarray, np.ndarray]:
        """A new frame holding sky and ground, and the shadowed twin of its ground rows.

        Args:
            seed: scenery seed (the hills).
            s_cam: camera position along the road [m] (the dash phase).
        """
        cfg = self.config
        phase = s_cam % sc.DASH_PERIOD
        bucket = int(phase / sc.DASH_PERIOD * PHASE_BUCKETS) % PHASE_BUCKETS
        ground, dark = self._background(bucket)
        g0 = self._g0
        img = np.empty((cfg.height, cfg.width, 3), np.uint8)
        if g0 > 0:
            img[:g0] = self._sky(seed)
        img[g0:] = ground
        return img, dark

    def _sun(self, azimuth: float, elevation: float) -> _Sun:
        """The light vector, shadow displacement and shadow pattern for a sun [rad]."""
        el = max(elevation, MIN_SUN_ELEVATION)
        light = (math.sin(azimuth) * math.cos(el), math.sin(el), math.cos(azimuth) * math.cos(el))
        shift = (-math.sin(azimuth) / math.tan(el), -math.cos(azimuth) / math.tan(el))
        pattern = self._pattern.get(shift)
        if pattern is None:
            if len(self._pattern) > 64:
                self._pattern.clear()
            pattern = self._pattern[shift] = _sweep_pattern(*shift)
        return _Sun(light, shift, pattern)

    def _cars_ahead(self, scene: SceneState) -> list[_CarItem]:
        """The cars between the near and far planes, far to near."""
        cfg = self.config
        lead = scene.lead
        cars = []
        for car in scene.cars:
            oncoming = car.lane <= -2
            x_c = sc.lane_center_x(car.lane) + car.lateral
            z_near = car.dx + cfg.setback - (car.length if oncoming else 0.0)
            if z_near < cfg.near or z_near > cfg.far:
                continue  # beside or behind the camera: outside the field of view
            cars.append(_CarItem(z_near, x_c, oncoming, car, car is lead))
        cars.sort(key=lambda c: -c.z_near)  # far to near
        return cars

    def _draw_shadows(self, img: np.ndarray, dark: np.ndarray, view: _SceneryView | None,
                      cars: list[_CarItem], sun: _Sun) -> None:
        """Ground shadows: scenery and traffic hard-edged through one mask, the lead's soft."""
        hard: list[np.ndarray] = []  # (N, 6, 2) fixed-point hexagons, hard-edged
        extra: list[np.ndarray] = []  # near-clipped polygons of other sizes (rare)
        if view is not None:
            hard.append(view.shadows)
            extra += view.clipped
        soft = None
        if cars:
            car_shadows = self._car_shadows(cars, sun)
            hard.append(car_shadows.hexes)
            extra += car_shadows.clipped
            soft = car_shadows.soft
        polys = np.concatenate(hard) if len(hard) > 1 else (hard[0] if hard else np.zeros((0, 6, 2), np.int32))
        if len(polys) or extra:
            self._mask_shadows(img, dark, polys, extra)
        if soft is not None:
            self._soft_shadow(img, soft)

    def _mask_shadows(self, img: np.ndarray, dark: np.ndarray, polys: np.ndarray,
                      extra: list[np.ndarray]) -> None:
        """Copy the shadowed ground under the fixed-point polygons into ``img``."""
        cfg = self.config
        g0 = self._g0
        shadow_mask = np.zeros((cfg.height, cfg.width), np.uint8)
        y0, y1 = cfg.height, -1
        if len(polys):
            ys = polys[:, :, 1]
            y0, y1 = int(ys.min()) >> SHIFT, (int(ys.max()) >> SHIFT) + 1
            _fill_batched(shadow_mask, polys, 255, cv2.LINE_8)
        for poly in extra:
            cv2.fillConvexPoly(shadow_mask, poly, 255, cv2.LINE_8, SHIFT)
            y0 = min(y0, int(poly[:, 1].min()) >> SHIFT)
            y1 = max(y1, (int(poly[:, 1].max()) >> SHIFT) + 1)
        r0, r1 = max(y0, g0), min(y1 + 1, cfg.height)
        if r1 > r0:
            cv2.copyTo(dark[r0 - g0:r1 - g0], shadow_mask[r0:r1], img[r0:r1])

    def _draw_cars(self, img: np.ndarray, cars: list[_CarItem], light: tuple) -> None:
        """Cars far to near, anti-aliased (their shadows are already drawn)."""
        if self._level:  # cars wholly beside the picture
            cars = [c for c in cars if self._in_view(c)]
        if cars:
            fq, cols = self._car_geometry(cars, light)
            fill = cv2.fillConvexPoly
            for j, col in enumerate(cols):
                fill(img, fq[j], col, AA, SHIFT)

    def _in_view(self, item: _CarItem) -> bool:
        """Whether a car's box reaches into the picture (level camera: u depends on X/Z only)."""
        x0, x1 = item.x - 0.5 * item.car.width, item.x + 0.5 * item.car.width
        z_far = item.z_near + item.car.length
        right = self._project_exact(x1, 0.0, item.z_near if x1 >= 0 else z_far)[0]
        left = self._project_exact(x0, 0.0, item.z_near if x0 <= 0 else z_far)[0]
        return right >= -2.0 and left <= self.config.width + 1.0

    # ------------------------------------------------------------------- shadows
    def _car_shadows(self, cars: list[_CarItem], sun: _Sun) -> _CarShadows:
        """Ground shadows of the cars' boxes in fixed point.

        The shadow of a box on the ground is its footprint swept along the sun's
        ground displacement: a hexagon (:func:`_sweep_pattern`), built here in Python
        scalars (a dozen cars) and projected in one batch.
        """
        zmin = self._z_ground_min
        traffic: list[list[tuple[float, float, float]]] = []  # hexagons clear of the camera
        clipped = []
        soft = None
        for item in cars:
            z_near, x_c, car, is_lead = item.z_near, item.x, item.car, item.is_lead
            if z_near > SHADOW_FAR and not is_lead:
                continue  # a sliver at the horizon, like the scenery's
            hgt = 0.92 * car.height  # the cabin is narrower than the footprint
            a, b = sun.shift[0] * hgt, sun.shift[1] * hgt
            x0 = x_c - 0.5 * car.width
            xs, zs = (x0, x0 + car.width), (z_near, z_near + car.length)
            pts = [(xs[i] + m * a, 0.0, zs[k] + m * b) for i, k, m in sun.pattern.corners]
            d = AA_INSET if is_lead else 0.5
            if min(p[2] for p in pts) < zmin:  # rare: a shadow reaching under the camera
                p3 = _clip_near(np.array(pts), zmin)
                if len(p3) < 3:
                    continue
                poly = _fix(_shrink(self._proj(p3), d))
            elif is_lead:
                poly = _fix(_shrink(self._proj(np.array(pts)), d))
            else:
                traffic.append(pts)
                continue
            if is_lead:
                soft = poly
            else:
                clipped.append(poly)
        hexes = _fix(_shrink(self._proj(np.array(traffic, np.float64).reshape(-1, 6, 3)), 0.5))
        return _CarShadows(hexes, clipped, soft)

    def _soft_shadow(self, img: np.ndarray, poly: np.ndarray) -> None:
        """Darken the ground under ``poly`` with anti-aliased edges (the lead car's)."""
        H, W = img.shape[:2]
        x0 = max((int(poly[:, 0].min()) >> SHIFT) - 1, 0)
        x1 = min((int(poly[:, 0].max()) >> SHIFT) + 2, W)
        y0 = max((int(poly[:, 1].min()) >> SHIFT) - 1, 0)
        y1 = min((int(poly[:, 1].max()) >> SHIFT) + 2, H)
        if x1 <= x0 or y1 <= y0:
            return
        m = np.zeros((y1 - y0, x1 - x0), np.uint8)
        off = np.array([x0 << SHIFT, y0 << SHIFT], np.int32)
        cv2.fillConvexPoly(m, poly - off, 255, AA, SHIFT)
        fac = cv2.convertScaleAbs(m, alpha=-(1 - SHADOW_FACTOR), beta=255)
        roi = img[y0:y1, x0:x1]
        cv2.multiply(roi, cv2.cvtColor(fac, cv2.COLOR_GRAY2RGB), dst=roi, scale=1 / 255)

    # ------------------------------------------------------------------- scenery
    def _scenery_window(self, seed: int, s_cam: float, sun: _Sun) -> _SceneryWindow:
        """The scenery of the road ahead, far to near, lit but not hazed.

        Cached until the camera enters a new road tile or the light changes. Shadows
        are hexagons in road coordinates. A handful of objects is cheaper in Python
        scalars than in a few dozen small numpy operations.
        """
        batch = self._scenery.window(seed, s_cam, s_cam + SCENERY_FAR)
        light, sh = sun.light, sun.shift
        if self._win is not None and self._win_key is not None and self._win_key[0] is batch \
                and self._win_key[1] == light:  # holding the batch keeps its identity unique
            return self._win
        b = batch
        k_crown = AMBIENT + DIFFUSE * 0.1
        k_lit = AMBIENT + DIFFUSE * (max(0.0, 0.35 - 0.65 * light[2]) + 0.3 * light[1] + 0.3)
        lit_dx = 0.35 * float(np.clip(2 * light[0], -1, 1))  # sunlit side of the crown
        trees = []
        for i in np.argsort(-b.tree_s, kind="stable").tolist():
            s, x, r = float(b.tree_s[i]), float(b.tree_x[i]), float(b.tree_r[i])
            yc = float(b.tree_h[i]) + 0.8 * r  # [m] crown centre height
            rgb = b.tree_rgb[i].tolist()
            trees.append(_Tree(
                s=s, x=x, crown_y=yc, radius=r, lit_dx=lit_dx * r, lit_dy=0.3 * r,
                crown_rgb=tuple(min(c * k_crown, 255.0) for c in rgb),
                lit_rgb=tuple(min(c * k_lit, 255.0) for c in rgb),
                shadow_x=tuple(x + sh[0] * yc + r * c for c in _HEX_COS.tolist()),
                shadow_s=tuple(s + sh[1] * yc + r * c for c in _HEX_SIN.tolist()),
                shadow_reach=r - sh[1] * yc))
        blds = []
        o = np.argsort(-b.bld_s, kind="stable")
        x_out = b.bld_x[o] + np.where(b.bld_x[o] > 0, b.bld_depth[o], -b.bld_depth[o])
        hexes = _swept_many(np.minimum(b.bld_x[o], x_out), np.maximum(b.bld_x[o], x_out), b.bld_s[o],
                            b.bld_s[o] + b.bld_len[o], sh[0] * b.bld_h[o], sh[1] * b.bld_h[o], sun.pattern)
        for j, i in enumerate(o.tolist()):
            xb, hb = float(b.bld_x[i]), float(b.bld_h[i])
            side = 1.0 if xb > 0 else -1.0
            rgb = b.bld_rgb[i]
            hx = hexes[j]
            blds.append(_Building(
                s=float(b.bld_s[i]), x_wall=xb, x_far=xb + side * float(b.bld_depth[i]),
                length=float(b.bld_len[i]), height=hb, floors=min(int(hb // 3.5), _WINDOW_FLOORS),
                near_rgb=_shade(rgb, -light[2], 0.0), wall_rgb=_shade(rgb, -side * light[0], 0.0),
                shadow_x=tuple(hx[:, 0].tolist()), shadow_s=tuple(hx[:, 2].tolist()),
                shadow_reach=float(b.bld_s[i] - hx[:, 2].min())))
        self._win = _SceneryWindow(trees, [-t.s for t in trees], blds)
        self._win_key = (batch, light)
        return self._win

    def _scenery_view(self, seed: int, s_cam: float, sun: _Sun) -> _SceneryView:
        """Visible buildings and trees (far to near) and their shadows, in fixed point.

        Faces and trunks are collected as world quads and projected and shrunk (0.5 px
        per axis, for ``LINE_8``) in one batch, as are the shadow hexagons.
        """
        win = self._scenery_window(seed, s_cam, sun)
        quads: list[tuple] = []  # 4 points (X, Y, Z) [m] each
        ground: list[list[tuple[float, float, float]]] = []  # shadow hexagons, 6 points each
        clipped: list[np.ndarray] = []
        blds = self._building_draws(win.buildings, s_cam, quads, ground, clipped)
        trees = self._tree_draws(win, s_cam, quads, ground)
        qa = _fix(_shrink(self._proj(np.array(quads, np.float64).reshape(-1, 4, 3)), 0.5))
        hexa = _fix(self._proj(np.array(ground, np.float64).reshape(-1, 6, 3)))
        return _SceneryView(qa, blds, trees, hexa, clipped)

    def _building_draws(self, blds: list[_Building], s_cam: float, quads: list, ground: list,
                        clipped: list[np.ndarray]) -> list[_BuildingDraw]:
        """Buildings in reach: their quads into ``quads``, their shadows into ``ground``
        (or, clipped at the camera and in fixed point, into ``clipped``)."""
        zmin = self._z_ground_min
        width = self.config.width
        proj = self._project
        out = []
        for b in blds:
            zb = b.s - s_cam  # [m] camera to the near face
            if zb >= SCENERY_FAR or zb + b.length <= 4.0:
                continue
            z0 = zb if zb > zmin else zmin
            z1 = zb + b.length
            # out of the picture (beside the camera): its shadow may still show
            ua, ub = proj(b.x_wall, 0.0, z1)[0], proj(b.x_wall, b.height, z1)[0]
            if (min(ua, ub) <= width + 1.0) if b.x_wall > 0 else (max(ua, ub) >= -2.0):
                out.append(self._building_quads(b, z0, z1, zb >= zmin, quads))
            if zb <= SHADOW_FAR:
                pts = [(gx, 0.0, gs - s_cam) for gx, gs in zip(b.shadow_x, b.shadow_s, strict=True)]
                if zb - b.shadow_reach < zmin:  # reaches beside the camera: clip
                    p3 = _clip_near(np.array(pts), zmin)
                    if len(p3) >= 3:
                        clipped.append(_fix(self._proj(p3)))
                else:
                    ground.append(pts)
        return out

    @staticmethod
    def _building_quads(b: _Building, z0: float, z1: float, near: bool, quads: list) -> _BuildingDraw:
        """A building's face towards the camera (if ``near``), road-facing wall and window
        bands between depths ``z0`` and ``z1`` [m], into ``quads``; its hazed colours."""
        q0 = len(quads)
        x, x1, hgt = b.x_wall, b.x_far, b.height
        if near:
            quads.append(((x, 0.0, z0), (x1, 0.0, z0), (x1, hgt, z0), (x, hgt, z0)))
        quads.append(((x, 0.0, z0), (x, 0.0, z1), (x, hgt, z1), (x, hgt, z0)))
        nwin = b.floors if z0 < 120.0 else 0  # window bands on the road-facing wall
        for k in range(nwin):
            ya, yb = 1.2 + 3.5 * k, 2.4 + 3.5 * k
            quads.append(((x, ya, z0 + 1.0), (x, ya, z1 - 1.0), (x, yb, z1 - 1.0), (x, yb, z0 + 1.0)))
        fog = 1.0 - math.exp(-z0 / sc.FOG_DISTANCE)
        wall = _haze(b.wall_rgb, fog)
        return _BuildingDraw(q0, near, nwin, _haze(b.near_rgb, fog), wall,
                             (0.45 * wall[0], 0.45 * wall[1], 0.45 * wall[2]))

    def _tree_draws(self, win: _SceneryWindow, s_cam: float, quads: list,
                    ground: list) -> list[_TreeDraw]:
        """Trees in reach: trunks into ``quads``, shadows clear of the camera into ``ground``."""
        zmin = self._z_ground_min
        f = self._f
        width = self.config.width
        proj = self._project
        i0 = bisect.bisect_right(win.neg_s, -(s_cam + SCENERY_FAR))
        i1 = bisect.bisect_left(win.neg_s, -(s_cam + 4.0))
        out = []
        for t in win.trees[i0:i1]:
            z = t.s - s_cam  # [m] camera to the trunk
            rad = int(max(f * t.radius / z - 0.5, 0.0) * ONE)
            u, v = proj(t.x, t.crown_y, z)
            if -2 * ONE <= u * ONE + rad and u * ONE - rad <= (width + 1) * ONE:  # in the picture
                out.append(self._tree_parts(t, z, (round(u * ONE), round(v * ONE)), rad, quads))
            if z < SHADOW_FAR and z - t.shadow_reach > zmin:  # shadow clear of the camera
                ground.append([(gx, 0.0, gs - s_cam) for gx, gs in zip(t.shadow_x, t.shadow_s, strict=True)])
        return out

    def _tree_parts(self, t: _Tree, z: float, center: tuple[int, int], rad: int,
                    quads: list) -> _TreeDraw:
        """A tree ``z`` [m] ahead whose crown is a disc at ``center`` of radius ``rad`` (fixed point)."""
        fog = 1.0 - math.exp(-z / sc.FOG_DISTANCE)
        trunk = trunk_rgb = lit = None
        if rad > 3 * ONE:  # the trunk of a distant tree is hidden under its crown
            trunk = len(quads)
            x, yc = t.x, t.crown_y
            quads.append(((x - 0.18, 0.0, z), (x + 0.18, 0.0, z), (x + 0.18, yc, z), (x - 0.18, yc, z)))
            trunk_rgb = _haze(_TRUNK_RGB, fog)
        if rad > 5 * ONE:
            u, v = self._project(t.x + t.lit_dx, t.crown_y + t.lit_dy, z)
            lit = _Disc((round(u * ONE), round(v * ONE)), int(0.6 * rad), _haze(t.lit_rgb, fog))
        return _TreeDraw(trunk, trunk_rgb, _Disc(center, rad, _haze(t.crown_rgb, fog)), lit)

    # ------------------------------------------------------------------- objects
    @staticmethod
    def _draw_buildings(img: np.ndarray, view: _SceneryView) -> None:
        """Buildings far to near: the face towards the camera, the road-facing wall, windows."""
        qa = view.quads
        fill = cv2.fillConvexPoly
        for d in view.buildings:
            q = d.quad
            if d.near:
                fill(img, qa[q], d.near_rgb, L8, SHIFT)
                q += 1
            fill(img, qa[q], d.wall_rgb, L8, SHIFT)
            if d.windows:
                cv2.fillPoly(img, list(qa[q + 1:q + 1 + d.windows]), d.window_rgb, L8, SHIFT)

    @staticmethod
    def _draw_trees(img: np.ndarray, view: _SceneryView) -> None:
        """Trees far to near: trunk (when it shows below the crown), crown, sunlit spot."""
        qa = view.quads
        circle, fill = cv2.circle, cv2.fillConvexPoly
        for t in view.trees:
            if t.trunk is not None:
                fill(img, qa[t.trunk], t.trunk_rgb or _TRUNK_RGB, L8, SHIFT)  # set wherever trunk is
            circle(img, t.crown.center, t.crown.radius, t.crown.rgb, -1, L8, SHIFT)
            if t.lit is not None:
                circle(img, t.lit.center, t.lit.radius, t.lit.rgb, -1, L8, SHIFT)

    def _car_faces(self, item: _CarItem, light: tuple, lod: str) -> tuple[np.ndarray, list]:
        """A car's visible faces: their corners ``(F, 4, 3)`` in the car's frame (scaled to
        its size) and their colours, in drawing order.

        Cached per template, visibility case, size, body colour and light: the world
        sends the same few cars every step.
        """
        x_c, oncoming, car = item.x, item.oncoming, item.car
        if not self.car_detail:
            kind = "plain"
        elif oncoming:
            kind = "front"
        else:
            kind = "brake" if car.braking else "rear"
        if lod and kind != "plain":
            kind += lod
        tpl = _TEMPLATES[kind]
        sx, sy = car.width / CAR_WIDTH, car.height / CAR_HEIGHT
        side = 1 if x_c - 0.5 * car.width > 0 else (-1 if x_c + 0.5 * car.width < 0 else 0)
        key = (kind, side, car.color, car.height, car.width, car.length, light)
        hit = self._face_cache.get(key)
        if hit is not None:
            return hit
        body = car.color
        h = self._h
        cols: dict[str, tuple[float, float, float]] = {}
        out = []
        for j, (role, when) in enumerate(tpl.faces):
            if when is not None:
                if when.side == "left" and not x_c + when.at * sx > 0:
                    continue
                if when.side == "right" and not x_c + when.at * sx < 0:
                    continue
                if when.side == "top" and not when.at * sy < h:
                    continue
            col = cols.get(role)
            if col is None:
                if role == "near":
                    col = _shade(body, -light[2], 0.0)
                elif role == "top":
                    col = _shade(body, light[1], 0.0)
                elif role == "left":
                    col = _shade(body, -light[0], 0.0)
                elif role == "right":
                    col = _shade(body, light[0], 0.0)
                elif role in _LAMPS:
                    col = _haze(_LAMPS[role], 0.0)
                else:
                    base, lam = _FIXED[role]
                    if role == "window" and oncoming:
                        base = (60, 72, 88)
                    col = _shade(base, lam, 0.0)
                cols[role] = col
            out.append((j, col))
        pts = tpl.points * np.array([sx, sy, car.length / CAR_LENGTH])
        quads = pts[tpl.index[[j for j, _ in out]]] if out else np.zeros((0, 4, 3))
        if len(self._face_cache) > 512:
            self._face_cache.clear()
        faces = (quads, [col for _, col in out])
        self._face_cache[key] = faces
        return faces

    def _car_geometry(self, cars: list[_CarItem], light: tuple) -> tuple[np.ndarray, list]:
        """The visible faces of all cars in fixed point ``(F, 4, 2)``, in one projection,
        and their colours, in drawing order (cars far to near)."""
        parts, offs, counts = [], [], []
        cols: list = []
        for item in cars:
            lod = ""
            if not item.is_lead:
                w_px = self._f * item.car.width / item.z_near
                lod = "_tiny" if w_px < TINY_WIDTH else ("_lod" if w_px < LOD_WIDTH else "")
            quads, faces = self._car_faces(item, light, lod)
            parts.append(quads)
            cols += faces
            offs.append((item.x, 0.0, item.z_near))
            counts.append(len(faces))
        p = np.concatenate(parts)
        p += np.repeat(np.array(offs), counts, axis=0)[:, None, :]
        return _fix(_shrink(self._proj(p))), cols


_HEX_COS = np.cos(np.linspace(0, 2 * np.pi, 7)[:-1])
_HEX_SIN = np.sin(np.linspace(0, 2 * np.pi, 7)[:-1])
_TRUNK_RGB = (95 * 0.62, 70 * 0.62, 45 * 0.62)
_WINDOW_FLOORS = 3  # at most this many window bands per building
# ground strips (X from, X to, colour): shoulders, lanes, median, then the solid lines
_STRIPS = (
    (sc.ONCOMING_EDGE_OUT - sc.SHOULDER_OUTER, sc.ONCOMING_EDGE_OUT, sc.SHOULDER),
    (sc.ONCOMING_EDGE_OUT, sc.ONCOMING_EDGE_IN, sc.ASPHALT),
    (sc.ONCOMING_EDGE_IN, sc.MEDIAN_R, sc.SHOULDER),
    (sc.MEDIAN_R, sc.MEDIAN_L, sc.MEDIAN_GRASS),
    (sc.MEDIAN_L, sc.CARRIAGEWAY_EDGE_L, sc.SHOULDER),
    (sc.CARRIAGEWAY_EDGE_L, sc.CARRIAGEWAY_EDGE_R, sc.ASPHALT),
    (sc.CARRIAGEWAY_EDGE_R, sc.CARRIAGEWAY_EDGE_R + sc.SHOULDER_OUTER, sc.SHOULDER),
    # solid edge lines: yellow next to the median, white outside
    (sc.CARRIAGEWAY_EDGE_L + 0.1, sc.CARRIAGEWAY_EDGE_L + 0.1 + sc.LINE_WIDTH, sc.YELLOW),
    (sc.CARRIAGEWAY_EDGE_R - 0.1 - sc.LINE_WIDTH, sc.CARRIAGEWAY_EDGE_R - 0.1, sc.WHITE),
    (sc.ONCOMING_EDGE_IN - 0.1 - sc.LINE_WIDTH, sc.ONCOMING_EDGE_IN - 0.1, sc.YELLOW),
    (sc.ONCOMING_EDGE_OUT + 0.1, sc.ONCOMING_EDGE_OUT + 0.1 + sc.LINE_WIDTH, sc.WHITE),
)
# ground layers per camera configuration: {config: {bucket: (ground, shadowed twin)}},
# bucket -1 holding the full frame without dashes; shared by all renderers
_GROUND_CACHE: dict[CameraConfig, dict[int, tuple[np.ndarray, np.ndarray]]] = {}


def in_format(rgb: np.ndarray, image_format: str) -> np.ndarray:
    """A rendered RGB frame in a session's image format: "rgb" as is, "gray" converted
    (the pixels a policy sees, through the server or in a platoon driven in-process)."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if image_format == "gray" else rgb
