"""The two standard figures of a platoon, as the traffic-flow literature draws them.

* :func:`plot_time_space`: a time-space diagram, one trajectory per car (position of its
  front bumper against time), coloured by speed, so a wave that grows down the platoon
  shows as a darkening band that travels backwards.
* :func:`plot_amplification`: amplification of speed deviation and acceleration by
  position in the platoon, lead to car i (RMS and peak), with the string-stable
  line at 1.

Both write ``<name>.png`` and ``<name>.pdf`` with the style of :mod:`vacc.figures`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from energy.string_stability import SKIP_FRACTION, amplification
from vacc.figures import Written, _plt, _save

__all__ = ["positions", "plot_time_space", "plot_amplification"]


def positions(t: np.ndarray, v_lead: np.ndarray, gaps: np.ndarray, car_length: float) -> np.ndarray:
    """Front-bumper positions [m] of every car, [n_cars, N]: the lead's integrated speed
    (trapezoid, from 0), each follower a gap and a car length behind the car ahead.

    Used where a platoon's record has speeds and gaps but no positions (OpenACC)."""
    x0 = np.concatenate([[0.0], np.cumsum(0.5 * (v_lead[1:] + v_lead[:-1]) * np.diff(t))])
    behind = np.cumsum(gaps + car_length, axis=0)  # [n_cars - 1, N]
    return np.vstack([x0, x0 - behind])


def plot_time_space(out: Path, t: np.ndarray, x: np.ndarray, v: np.ndarray, name: str = "time_space", title: str = "") -> Written:
    """A time-space diagram: each car's position [m] against time [s], coloured by speed [m/s]."""
    plt = _plt()
    from matplotlib.collections import LineCollection

    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    finite = np.isfinite(v)
    lo, hi = float(np.min(v[finite])), float(np.max(v[finite]))
    norm = plt.Normalize(lo, hi if hi > lo else lo + 1.0)
    for xi, vi in zip(x, v, strict=True):
        pts = np.stack([t, xi], axis=1)
        seg = np.stack([pts[:-1], pts[1:]], axis=1)  # [N - 1, 2, 2]
        lc = LineCollection(list(seg), cmap="viridis", norm=norm, linewidths=0.8)
        lc.set_array(0.5 * (vi[1:] + vi[:-1]))
        ax.add_collection(lc)
    ax.set_xlim(float(t[0]), float(t[-1]))
    ax.set_ylim(float(np.nanmin(x)), float(np.nanmax(x)))
    fig.colorbar(lc, ax=ax, label="speed [m/s]")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position [m]")
    ax.set_title(title or f"time-space diagram, {x.shape[0]} cars")
    return _save(fig, out, name)


def plot_amplification(
    out: Path, t: np.ndarray, v: np.ndarray, name: str = "amplification", title: str = "", skip_fraction: float = SKIP_FRACTION,
) -> Written:
    """Amplification from the lead to each car i, by position, in RMS and peak, for speed deviation and acceleration."""
    plt = _plt()
    pos = np.arange(1, v.shape[0])
    rows = [amplification(t, v[[0, int(i)]], skip_fraction=skip_fraction).lead_to_last for i in pos]
    fig, axes = plt.subplots(1, 2, figsize=(6.5, 2.8), sharex=True)
    for ax, signal in zip(axes, ("speed", "accel"), strict=True):
        for norm, marker in (("rms", "o"), ("peak", "s")):
            ax.plot(pos, [getattr(r, f"{signal}_{norm}") for r in rows], marker=marker, label=norm.upper())
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xlabel("position behind the lead")
        ax.set_ylabel(f"{'speed deviation' if signal == 'speed' else 'acceleration'} / lead's")
        ax.set_xticks(pos)
    axes[0].legend()
    fig.suptitle(title or f"amplification by position (after the first {skip_fraction:.0%})")
    return _save(fig, out, name)
