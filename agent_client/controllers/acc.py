"""The traditional ACC (paper eq. 1-3): a constant-time-gap law on radar gap and speeds.

    a_ref = beta * (gap - d_ref) + gamma * (v_lead - v_host)
    d_ref = max(v_host * t_gap, d_safe)

beta and gamma are the published gains of this law (SUMO's ACC model after Milanes &
Shladover). t_gap = 1.8 s puts d_ref at 54 m at the ICE lead's mean 30 m/s, next to
the paper's 55 m target; d_safe = 5 m keeps a standstill distance in stop-and-go.
Unlike the DDQN agent, this controller is given the gap: it stands for a radar ACC.

The linear law alone brakes too gently when a lead stops in traffic: on the EV
test windows it touched the lead in all four runs. Like production ACCs (and SUMO's
collision-avoidance mode), a kinematic limit caps the command while closing in:

    a <= min(a_lead, 0) - (v_host - v_lead)^2 / (2 (gap - d_min))

the constant deceleration that matches the lead's speed d_min before it. It engages
only when the time to reach d_min at the current closing speed is under
``ttc_engage`` (6 s), so ordinary following, and all of the ICE runs, follow
eq. 1-3 alone. Behind a standing lead the limit aims at d_safe instead of d_min:
matching a standing car's speed means stopping, and the ACC's standstill
distance is d_safe (aiming at d_min left it 1.9 m behind a stopped car). d_min is
3 m: at 2 m the 10 Hz control undershot it (1.98 m behind a slow lead), under the
2 m minimum gap of the safety suite; 3 m moves the EV test RMSEs by < 0.12 m.

**Set speed.** Like a production ACC, it cruises at the driver's set speed when
the lead is far, in speed-control mode, and never commands more:

    a_cmd = min(a_ref, k_speed * (v_set - v_host))

k_speed = 0.4 1/s is SUMO's ACC speed-control gain (``speedControlGain``, after
Milanes & Shladover). The set speed comes with every observation; the vehicle's
own limiter holds it as well.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from agent_client.actions import force_of_accel
from protocol.scenarios import DEFAULT_SET_SPEED

__all__ = ["AccController", "force_of_accel"]

V_STANDING = 0.1  # [m/s] a lead slower than this stands: stop d_safe behind it


@dataclass(frozen=True)
class AccController:
    """Constant-time-gap ACC."""

    beta: float = 0.23  # [1/s^2] gap gain
    gamma: float = 0.07  # [1/s] speed-difference gain
    t_gap: float = 1.8  # [s] desired time gap
    d_safe: float = 5.0  # [m] minimum desired gap
    d_min: float = 3.0  # [m] closest approach the collision-avoidance limit aims for (1 m above the 2 m safety floor)
    ttc_engage: float = 6.0  # [s] the limit engages below this time to reach d_min
    k_speed: float = 0.4  # [1/s] speed-control gain toward the set speed (SUMO's ACC)

    name = "acc"

    fixed_gap: float | None = None  # [m] a constant d_ref instead of the time gap (the paper's 55 m target)
    max_gap: float = float("inf")  # [m] a cap on the time-gap d_ref (the eco teacher's 55 m)
    decel_cap: float = float("inf")  # [m/s^2] a cap on the law's braking; the collision-avoidance limit may brake harder

    def reference_gap(self, v_host: float) -> float:
        """d_ref [m] at host speed ``v_host`` [m/s] (eq. 2, capped at ``max_gap``; or ``fixed_gap``)."""
        if self.fixed_gap is not None:
            return self.fixed_gap
        return min(max(v_host * self.t_gap, self.d_safe), self.max_gap)

    def reset(self) -> None:
        """Nothing to forget between episodes."""

    def cruise_accel(self, v_host: float, set_speed: float) -> float:
        """Speed-control acceleration [m/s^2] toward the set speed [m/s]."""
        return self.k_speed * (set_speed - v_host)

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force u for an observation with ``gap``, ``v_host``, ``v_lead``, ``a_lead`` and ``set_speed``.

        An observation without ``set_speed`` (a hand-made one) cruises at the
        default 33.5 m/s.
        """
        gap, v, v_lead = obs["gap"], obs["v_host"], obs["v_lead"]
        a_ref = max(self.beta * (gap - self.reference_gap(v)) + self.gamma * (v_lead - v), -self.decel_cap)
        a_ref = min(a_ref, self.cruise_accel(v, obs.get("set_speed", DEFAULT_SET_SPEED)))
        closing = v - v_lead  # [m/s]
        d_aim = self.d_safe if v_lead < V_STANDING else self.d_min
        if closing > 0.0 and gap - d_aim < self.ttc_engage * closing:
            a_safe = min(obs.get("a_lead", 0.0), 0.0) - closing**2 / (2.0 * max(gap - d_aim, 0.1))
            a_ref = min(a_ref, a_safe)
        return force_of_accel(a_ref)
