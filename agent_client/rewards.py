"""Rewards of the paper's Table 1 as pure functions, normalised to [-1, 1].

Gap term (piecewise linear in the gap g [m], raw units as in Table 1):

    g [m]     0     30    55    80    300
    r_gap   -10      0   +10     0     -5      (constant beyond 300 m)

The peak at 55 m is the paper's "desired distance which leads to the highest gap
reward"; the zero crossings at 30 m and 80 m make exactly the "encouraged" band of
the text positive; -10 at contact and about -5 at the 300 m termination follow the
figure. Force term: a triangle of +10 at u = 0 falling to 0 at |u| = 0.3.

* ``gap`` reward = r_gap / 10, in [-1, 1].
* ``force`` reward = (r_gap + r_force) / 20, in [-0.5, 1]: the sum, normalised
  by its largest magnitude so it stays in [-1, 1].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["GAP_POINTS", "FORCE_HALF_WIDTH", "gap_term", "force_term", "gap_reward", "force_reward", "REWARDS"]

GAP_POINTS = ((0.0, -10.0), (30.0, 0.0), (55.0, 10.0), (80.0, 0.0), (300.0, -5.0))  # ([m], raw reward)
FORCE_PEAK = 10.0  # raw reward at u = 0
FORCE_HALF_WIDTH = 0.3  # |u| beyond which the force term is 0
_GX = np.array([p[0] for p in GAP_POINTS])
_GY = np.array([p[1] for p in GAP_POINTS])


def gap_term(gap: float) -> float:
    """Raw Table 1 gap reward for a gap [m]; -10 at or below contact."""
    return float(np.interp(gap, _GX, _GY))


def force_term(u: float) -> float:
    """Raw Table 1 force reward for a normalised force u."""
    return FORCE_PEAK * max(0.0, 1.0 - abs(u) / FORCE_HALF_WIDTH)


def gap_reward(gap: float, u: float) -> float:
    """Gap-based DDQN reward in [-1, 1]; ignores the force."""
    return gap_term(gap) / 10.0


def force_reward(gap: float, u: float) -> float:
    """Force-based DDQN reward in [-1, 1]: gap and force terms together."""
    return (gap_term(gap) + force_term(u)) / 20.0


REWARDS: dict[str, Callable[[float, float], float]] = {"gap": gap_reward, "force": force_reward}
