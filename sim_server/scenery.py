"""Road layout, static background and seeded roadside scenery for the camera.

Everything here is in the road frame used by :mod:`sim_server.render`: ``X`` lateral
[m] (0 = centre of the host's lane, + to the right), ``Y`` up [m] (0 = road surface)
and ``s`` along the road [m] in the host's direction of travel.

Scenery (trees, buildings) is generated per road *tile* of :data:`TILE_LENGTH` from
``np.random.default_rng((seed, tile))``, so the objects at a given ``s`` depend only
on the seed, never on how the host got there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_server.scene import LANE_WIDTH

# --- Cross-section of the freeway [m], X of each boundary ------------------------
HALF_LANE = 0.5 * LANE_WIDTH  # [m]
CARRIAGEWAY_EDGE_R = 1.5 * LANE_WIDTH  # [m] right edge of the host carriageway (+5.55)
CARRIAGEWAY_EDGE_L = -1.5 * LANE_WIDTH  # [m] left edge of the host carriageway (-5.55)
SHOULDER_OUTER = 2.5  # [m] paved shoulder width on the outside of each carriageway
SHOULDER_INNER = 1.0  # [m] paved shoulder width next to the median
MEDIAN_WIDTH = 4.0  # [m] grass between the two inner shoulders
BARRIER_HEIGHT = 0.8  # [m] concrete barrier in the middle of the median
BARRIER_WIDTH = 0.5  # [m]
MEDIAN_L = CARRIAGEWAY_EDGE_L - SHOULDER_INNER  # [m] host side of the median (-6.55)
MEDIAN_R = MEDIAN_L - MEDIAN_WIDTH  # [m] oncoming side of the median (-10.55)
ONCOMING_EDGE_IN = MEDIAN_R - SHOULDER_INNER  # [m] inner edge of oncoming lanes (-11.55)
ONCOMING_EDGE_OUT = ONCOMING_EDGE_IN - 3 * LANE_WIDTH  # [m] outer edge (-22.65)
BARRIER_X = 0.5 * (MEDIAN_L + MEDIAN_R)  # [m] barrier centre line

LINE_WIDTH = 0.15  # [m] painted line width
DASH_LENGTH = 3.05  # [m] 10 ft dash (MUTCD)
DASH_PERIOD = 12.19  # [m] 10 ft dash + 30 ft gap
DASH_X = (
    -HALF_LANE,
    HALF_LANE,
    ONCOMING_EDGE_IN - LANE_WIDTH,
    ONCOMING_EDGE_IN - 2 * LANE_WIDTH,
)  # [m] lane boundaries with dashed lines, both carriageways

TILE_LENGTH = 100.0  # [m] scenery is generated per tile of road


def lane_center_x(lane: int) -> float:
    """Lateral position of a lane's centre line.

    Args:
        lane: 0 host lane, -1 left, +1 right, -2..-4 oncoming (-2 next to the median).

    Returns:
        X of the lane centre [m].

    Raises:
        ValueError: for a lane that does not exist.
    """
    if -1 <= lane <= 1:
        return lane * LANE_WIDTH
    if -4 <= lane <= -2:
        return ONCOMING_EDGE_IN - HALF_LANE - (-2 - lane) * LANE_WIDTH
    raise ValueError(f"lane {lane} does not exist (valid: -4..1)")


# --- Colours (RGB) ----------------------------------------------------------------
SKY_TOP = np.array([95, 145, 215], np.float32)
SKY_HORIZON = np.array([200, 218, 235], np.float32)
HAZE = np.array([185, 200, 210], np.float32)  # colour far objects fade to
GRASS = (92, 128, 58)
MEDIAN_GRASS = (100, 134, 62)
ASPHALT = (118, 118, 122)
SHOULDER = (132, 130, 126)
WHITE = (235, 235, 230)
YELLOW = (225, 190, 60)
CONCRETE = (190, 188, 180)
HILLS = (88, 112, 96)
FOG_DISTANCE = 900.0  # [m] e-folding distance of the haze


@dataclass(frozen=True)
class SceneryBatch:
    """Roadside objects of a stretch of road, one row per object.

    Trees: ``tree_s`` [m], ``tree_x`` [m], ``tree_h`` trunk height [m], ``tree_r``
    crown radius [m], ``tree_rgb`` crown colour. Buildings: ``bld_s`` near face [m],
    ``bld_x`` road-facing wall [m], ``bld_len`` along the road [m], ``bld_depth``
    away from the road [m], ``bld_h`` height [m], ``bld_rgb`` wall colour.
    """

    tree_s: np.ndarray
    tree_x: np.ndarray
    tree_h: np.ndarray
    tree_r: np.ndarray
    tree_rgb: np.ndarray
    bld_s: np.ndarray
    bld_x: np.ndarray
    bld_len: np.ndarray
    bld_depth: np.ndarray
    bld_h: np.ndarray
    bld_rgb: np.ndarray


def _tile(seed: int, tile: int) -> SceneryBatch:
    """Generate the scenery of one road tile; depends only on ``(seed, tile)``."""
    rng = np.random.default_rng((seed & 0xFFFFFFFF, tile & 0xFFFFFFFF, 7))
    s0 = tile * TILE_LENGTH
    ts, tx, th, tr, tc = [], [], [], [], []
    bs, bx, bl, bd, bh, bc = [], [], [], [], [], []
    for side in (+1, -1):
        near = CARRIAGEWAY_EDGE_R + SHOULDER_OUTER + 3.0 if side > 0 else ONCOMING_EDGE_OUT - 5.5
        n_trees = int(rng.integers(1, 4))
        for _ in range(n_trees):
            ts.append(s0 + rng.uniform(0.0, TILE_LENGTH))
            tx.append(near + side * rng.uniform(0.0, 9.0))
            th.append(rng.uniform(1.8, 3.2))
            tr.append(rng.uniform(1.6, 3.0))
            g = rng.uniform(0.75, 1.15)
            tc.append((46 * g, 96 * g, 40 * g))
        if rng.random() < 0.55:
            bs.append(s0 + rng.uniform(0.0, TILE_LENGTH - 30.0))
            bx.append(near + side * rng.uniform(14.0, 30.0))
            bl.append(rng.uniform(12.0, 30.0))
            bd.append(rng.uniform(10.0, 20.0))
            bh.append(rng.uniform(6.0, 22.0))
            base = rng.choice(np.array([[196, 180, 150], [170, 160, 150], [150, 150, 165],
                                        [185, 140, 110], [210, 205, 190]], np.float32))
            bc.append(base * rng.uniform(0.85, 1.05))
    f = np.float64
    return SceneryBatch(
        np.array(ts, f), np.array(tx, f), np.array(th, f), np.array(tr, f),
        np.array(tc, f).reshape(-1, 3),
        np.array(bs, f), np.array(bx, f), np.array(bl, f), np.array(bd, f), np.array(bh, f),
        np.array(bc, f).reshape(-1, 3),
    )


class SceneryCache:
    """Seeded scenery for the stretch of road ahead, cached per run of tiles."""

    def __init__(self) -> None:
        self._key: tuple[int, int, int] | None = None
        self._batch: SceneryBatch | None = None
        self._seed: int | None = None
        self._tiles: dict[int, SceneryBatch] = {}

    def window(self, seed: int, s_from: float, s_to: float) -> SceneryBatch:
        """All scenery whose tile overlaps ``[s_from, s_to]`` [m] (may include more)."""
        t0 = int(np.floor((s_from - 40.0) / TILE_LENGTH))  # buildings reach back 30 m
        t1 = int(np.floor(s_to / TILE_LENGTH))
        key = (seed, t0, t1)
        if key != self._key:
            if seed != self._seed:
                self._tiles.clear()
                self._seed = seed
            for t in range(t0, t1 + 1):
                if t not in self._tiles:
                    self._tiles[t] = _tile(seed, t)
            for t in [t for t in self._tiles if t < t0 - 2 or t > t1 + 2]:
                del self._tiles[t]
            tiles = [self._tiles[t] for t in range(t0, t1 + 1)]
            self._batch = SceneryBatch(
                *(np.concatenate([getattr(t, n) for t in tiles]) for n in SceneryBatch.__dataclass_fields__)
            )
            self._key = key
        assert self._batch is not None
        return self._batch


def hills_profile(seed: int, n: int = 64) -> np.ndarray:
    """Angular height of the distant hills [rad] at ``n`` evenly spaced azimuths."""
    rng = np.random.default_rng((seed & 0xFFFFFFFF, 11))
    a = np.zeros(n)
    for k in (1, 2, 3, 5, 8):
        a += rng.uniform(0.2, 1.0) / k * np.sin(k * np.linspace(0, 2 * np.pi, n) + rng.uniform(0, 6.3))
    return 0.004 + 0.012 * (a - a.min()) / max(np.ptp(a), 1e-9)  # [rad] 0.2..1 degrees
