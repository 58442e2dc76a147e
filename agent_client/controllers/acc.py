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

**String stability.** Linearised about steady following (d_ref = v t_gap, no limit
active), with gap' = v_lead - v and v' = a_ref, eq. 1-3 give the speed-to-speed
transfer function (:func:`speed_transfer`)

    H(s) = V(s) / V_lead(s) = (gamma s + beta) / (s^2 + (gamma + beta t_gap) s + beta)

|H(j w)| <= 1 at every w (string stability) iff (gamma + beta t_gap)^2 >= gamma^2 + 2 beta.
The shipped gains miss it (0.234 < 0.465): the peak gain (:func:`peak_speed_gain`) is
1.154 at 0.054 Hz, so each car amplifies the lead's slow speed waves by up to 15 %.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agent_client.actions import force_of_accel
from protocol.scenarios import DEFAULT_SET_SPEED

__all__ = ["AccController", "LateClosing", "force_of_accel", "speed_transfer", "peak_speed_gain"]

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

    def __call__(self, obs: dict[str, Any], seen_closing: float | None = None) -> float:
        """The force u for an observation with ``gap``, ``v_host``, ``v_lead``, ``a_lead`` and ``set_speed``.

        An observation without ``set_speed`` (a hand-made one) cruises at the
        default 33.5 m/s. ``seen_closing`` [m/s]: the closing speed the law's following term
        reads instead of the true one (:class:`LateClosing`); the collision-avoidance limit
        always reads the true speeds.
        """
        gap, v, v_lead = obs["gap"], obs["v_host"], obs["v_lead"]
        v_followed = v_lead if seen_closing is None else v - seen_closing
        a_ref = max(self.beta * (gap - self.reference_gap(v)) + self.gamma * (v_followed - v), -self.decel_cap)
        a_ref = min(a_ref, self.cruise_accel(v, obs.get("set_speed", DEFAULT_SET_SPEED)))
        closing = v - v_lead  # [m/s]
        d_aim = self.d_safe if v_lead < V_STANDING else self.d_min
        if closing > 0.0 and gap - d_aim < self.ttc_engage * closing:
            a_safe = min(obs.get("a_lead", 0.0), 0.0) - closing**2 / (2.0 * max(gap - d_aim, 0.1))
            a_ref = min(a_ref, a_safe)
        return force_of_accel(a_ref)


def speed_transfer(law: AccController, omega: float) -> complex:
    """H(j omega) = V/V_lead of the linearised law at angular frequency ``omega`` [rad/s] (module docstring)."""
    s = 1j * omega
    return (law.gamma * s + law.beta) / (s * s + (law.gamma + law.beta * law.t_gap) * s + law.beta)


def peak_speed_gain(law: AccController) -> tuple[float, float]:
    """(omega [rad/s], |H|) at the peak of |H(j omega)| over omega > 0; (0, 1) when string-stable.

    With x = omega^2, d|H|^2/dx = 0 at gamma^2 x^2 + 2 beta^2 x - beta^2 c = 0, where
    c = gamma^2 + 2 beta - (gamma + beta t_gap)^2; a positive root exists iff c > 0.
    """
    b, g = law.beta, law.gamma
    c = g * g + 2.0 * b - (g + b * law.t_gap) ** 2
    if c <= 0.0:
        return 0.0, 1.0  # |H| falls from 1 at omega = 0
    # The quadratic's positive root; without gamma it degenerates to 2 beta^2 x = beta^2 c.
    x = c / 2.0 if g == 0.0 else b * (-b + (b * b + g * g * c) ** 0.5) / (g * g)
    omega = x**0.5
    return omega, abs(speed_transfer(law, omega))


@dataclass
class LateClosing:
    """An ACC law whose following term sees the closing speed (host minus lead speed)
    through a first-order lag of ``lag`` seconds, as a student that reads it from the
    camera's frame stack does (about half a second late: docs/training.md); its
    collision-avoidance limit still reads the true speeds. As a DAgger teacher its
    following labels are ones a camera student can reproduce, not ones that need the lead's
    speed at once; ``scripts/energy_frontier.py --lag`` replays the same law.
    """

    law: AccController
    lag: float  # [s] the lag's time constant (> 0)
    dt: float  # [s] the control period, one update per call
    _seen: float | None = field(default=None, init=False, repr=False)  # [m/s] the closing speed as seen

    def __post_init__(self) -> None:
        if not self.lag > 0.0 or not self.dt > 0.0:
            raise ValueError(f"LateClosing: lag and dt must be > 0 s, got lag {self.lag!r}, dt {self.dt!r}")

    def reset(self) -> None:
        """A new episode: the next call sees its closing speed as it is."""
        self._seen = None

    def __call__(self, obs: dict[str, Any]) -> float:
        """The law's force, its following term on the closing speed as seen."""
        closing = obs["v_host"] - obs["v_lead"]
        self._seen = closing if self._seen is None else self._seen + min(self.dt / self.lag, 1.0) * (closing - self._seen)
        return self.law(obs, seen_closing=self._seen)
