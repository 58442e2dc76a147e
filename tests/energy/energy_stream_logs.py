"""Synthetic run logs for the streaming tests: a follower behind a lead that brakes to a
stop, waits, pulls away and weaves, with phantom brakes, collisions and an uneven period.

Only +, -, *, / and comparisons build them (no sin or exp), from a seeded PCG64, so the
same arrays come out on every machine; written with ``repr`` they read back exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

COLUMNS = ("t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision")


def _lead_accel(t: float, rng_kick: float) -> float:
    """The lead's acceleration [m/s^2] at time t [s] of a 4-minute story (repeats after)."""
    s = t % 240.0
    if s < 20.0:
        return 0.0
    if s < 26.0:
        return -4.0  # brakes from cruise to a stop
    if s < 40.0:
        return -0.5  # (held at 0 by the speed floor: a standstill)
    if s < 52.0:
        return 2.0
    if s < 120.0:
        return 1.2 * rng_kick  # weaving
    if s < 124.0:
        return -7.0  # an emergency stop
    return 0.8 if s < 150.0 else 0.3 * rng_kick


def synthetic_log(n: int, dt: float = 0.1, jitter: float = 0.0, seed: int = 0, v0: float = 20.0,
                  crawl: bool = False) -> dict[str, np.ndarray]:
    """Columns of an ``n``-row log: period ``dt`` [s] (each step times 1 + U(-jitter, jitter)),
    ``crawl``: host and lead below the headway's 0.5 m/s (no headway defined)."""
    rng = np.random.default_rng(seed)
    steps = dt * (1.0 + jitter * (2.0 * rng.random(n) - 1.0))
    kicks = 2.0 * rng.random(n) - 1.0
    phantom = rng.random(n) < 0.004
    cols = {c: np.zeros(n) for c in COLUMNS}
    t, v, v_lead, gap, a = 0.0, v0, v0, 40.0, 0.0
    for i in range(n):
        if i:
            h = float(steps[i])
            t += h
            a_lead = 0.05 * kicks[i] if crawl else _lead_accel(t, float(kicks[i]))
            if not crawl and (t - h) % 240.0 < 200.0 <= t % 240.0:  # a slower car cuts in close
                gap, v_lead = 1.5, max(v - 3.0, 0.0)
            v_lead = max(v_lead + a_lead * h, 0.0)
            want = 0.3 * (gap - (5.0 + 1.8 * v)) + 0.9 * (v_lead - v)
            want = -6.5 if phantom[i] else want
            v_new = max(v + max(min(want, 2.0), -8.0) * h, 0.0)
            v_new = 0.0 if v_new < 0.1 and want < 0.0 else v_new  # stops dead
            if crawl:
                v_new = min(max(v_new, 0.05), 0.45)
            a = (v_new - v) / h
            gap += (v_lead - 0.5 * (v + v_new)) * h
            v = v_new
        row = cols
        row["t"][i], row["frame"][i], row["v_host"][i], row["v_lead"][i] = t, i, v, v_lead
        row["gap"][i], row["accel"][i], row["force"][i] = gap, a, max(min(a / 3.0, 1.0), -1.0)
    cols["collision"] = (cols["gap"] < 1.0).astype(float)  # a near miss counts as contact
    return cols


def write_csv(path: Path, cols: dict[str, np.ndarray]) -> Path:
    """Write the columns as a run log, floats by their shortest round-trip repr."""
    text = [c.astype(np.int64).astype(str) if k in ("frame", "collision") else c.astype(str) for k, c in cols.items()]
    with path.open("w") as f:
        f.write(",".join(cols) + "\n")
        f.writelines(",".join(row) + "\n" for row in zip(*text, strict=True))
    return path


def varied_logs() -> dict[str, dict[str, np.ndarray]]:
    """The frozen logs: a long 0.1 s run with stops, a jittered 0.02 s run, a crawl with no
    headway, and a run shorter than a settle."""
    return {
        "stops_0.1s": synthetic_log(3000, 0.1, 0.0, seed=1),
        "jitter_0.02s": synthetic_log(4000, 0.02, 0.3, seed=2, v0=25.0),
        "crawl": synthetic_log(600, 0.1, 0.1, seed=3, v0=0.3, crawl=True),
        "short": synthetic_log(40, 0.1, 0.0, seed=4),
    }
