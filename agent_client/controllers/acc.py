"""The traditional ACC (paper eq. 1-3): a constant-time-gap law on radar gap and speeds.

    a_ref = beta * (gap - d_ref) + gamma * (v_lead - v_host)
    d_ref = max(v_host * t_gap, d_safe)

beta and gamma are the published gains of this law (SUMO's ACC model after Milanes &
Shladover). t_gap = 1.8 s puts d_ref at 54 m at the ICE lead's mean 30 m/s, next to
the paper's 55 m target; d_safe = 5 m keeps a standstill distance in stop-and-go.
Unlike the DDQN agent, this controller is given the gap: it stands for a radar ACC.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["AccController", "force_of_accel"]

A_MIN = -5.5  # [m/s^2] acceleration at u = -1 (the simulator's force map)
A_MAX = 3.5  # [m/s^2] acceleration at u = +1


def force_of_accel(a: float) -> float:
    """Invert the simulator's force map: acceleration [m/s^2] to u in [-1, 1]."""
    u = a / A_MAX if a >= 0.0 else -a / A_MIN
    return min(1.0, max(-1.0, u))


@dataclass(frozen=True)
class AccController:
    """Constant-time-gap ACC."""

    beta: float = 0.23  # [1/s^2] gap gain
    gamma: float = 0.07  # [1/s] speed-difference gain
    t_gap: float = 1.8  # [s] desired time gap
    d_safe: float = 5.0  # [m] minimum desired gap

    name = "acc"

    def reference_gap(self, v_host: float) -> float:
        """d_ref [m] at host speed ``v_host`` [m/s] (eq. 2)."""
        return max(v_host * self.t_gap, self.d_safe)

    def reset(self) -> None:
        """Nothing to forget between episodes."""

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force u for an observation with ``gap``, ``v_host`` and ``v_lead``."""
        a_ref = self.beta * (obs["gap"] - self.reference_gap(obs["v_host"])) + self.gamma * (obs["v_lead"] - obs["v_host"])
        return force_of_accel(a_ref)
