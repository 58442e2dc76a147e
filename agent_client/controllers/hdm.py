"""The Human Driver Model (Treiber, Kesting & Helbing 2006): a model of a human driver.

Treiber, M., Kesting, A. & Helbing, D. (2006). Delays, inaccuracies and
anticipation in microscopic traffic models. Physica A 360, 71-88.

The HDM takes the Intelligent Driver Model (IDM) and adds what makes a driver
human:

* **Reaction time** T': the driver acts now on what they saw T' ago. The stimuli
  (gap s, own speed v, approach rate dv = v - v_lead, own acceleration) are kept in
  a history and read back at t - T', interpolated linearly between control steps
  (the paper's interpolation for T' not a multiple of the update time).
* **Estimation errors** as Wiener processes with correlation time tau~: the
  perceived gap is ``s * exp(V_s * w_s)`` and the perceived approach rate is
  ``dv - s * sigma_r * w_l``, with ``w(t+dt) = exp(-dt/tau~) w(t) + sqrt(2 dt/tau~) N(0,1)``
  (an Ornstein-Uhlenbeck process of unit variance; the paper's eq. for w).
* **Temporal anticipation**: the driver knows they are late and extrapolates the
  delayed stimuli over T' at constant acceleration (own speed) and constant speed
  difference (gap): ``v' = v(t-T') + T' a(t-T')``, ``s' = s(t-T') - T' dv(t-T')``.
* Spatial (multi-vehicle) anticipation is left out: the host sees one lead car
  (n_a = 1).

IDM parameters: s0, a, b and delta are Treiber & Kesting's freeway set (*Traffic
Flow Dynamics*, Springer 2013, Table 11.2: v0 = 120 km/h, T = 1.0 s, s0 = 2 m,
a = 1.0 m/s^2, b = 1.5 m/s^2, delta = 4). v0 and T are re-chosen for this task, as
the paper's drivers were told to keep a safe distance at freeway speed and the
ICE lead drives 27-33 m/s, close to the book's v0 = 33.3 m/s, where the IDM's
free-road term would make the host fall far back (equilibrium gap 177 m at
33 m/s). With v0 = 45 m/s (162 km/h, a desire the lead always limits) and
T = 1.6 s the equilibrium gap at 30 m/s is 55 m, the paper's desired gap. See
docs/human.md for the measured gaps.

Human-error parameters are the HDM paper's: V_s = 0.1, sigma_r = 0.01 1/s,
tau~ = 20 s. The reaction time T' = 1.0 s lies in the paper's range of stable
driving with anticipation (the paper studies T' up to about 2 s).

Unlike the DDQN agent, the HDM is given the gap and the lead speed from the
observation: it stands for a human with eyes, not for a camera policy. It is a
model, never "human data".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent_client.controllers.acc import force_of_accel

__all__ = ["HdmParams", "HumanDriverModel", "NAME", "idm_accel"]

NAME = "Human Driver Model (Treiber et al. 2006)"
SEED_STREAM = 0x48444D  # "HDM": keeps this generator apart from the world's streams
MIN_GAP = 0.1  # [m] floor of the perceived gap, so the IDM interaction term stays finite


@dataclass(frozen=True)
class HdmParams:
    """Parameters of the Human Driver Model, SI units."""

    v0: float = 45.0
    """[m/s] desired speed (book: 33.3 m/s; raised so the lead, not v0, limits speed)."""
    t_gap: float = 1.6
    """[s] desired time gap T (book: 1.0 s; 1.6 s gives 55 m at 30 m/s with v0 = 45 m/s)."""
    s0: float = 2.0
    """[m] minimum (jam) distance (book, freeway)."""
    a_max: float = 1.0
    """[m/s^2] maximum acceleration a (book, freeway)."""
    b_comf: float = 1.5
    """[m/s^2] comfortable deceleration b (book, freeway)."""
    delta: float = 4.0
    """Free-road acceleration exponent (book)."""
    reaction_time: float = 1.0
    """[s] reaction time T' (HDM paper: stable with anticipation up to ~2 s)."""
    v_s: float = 0.1
    """Variation coefficient of the gap estimation error V_s (HDM paper)."""
    sigma_r: float = 0.01
    """[1/s] standard deviation of the inverse time-to-collision error (HDM paper)."""
    tau_error: float = 20.0
    """[s] correlation time of the estimation errors tau~ (HDM paper)."""
    anticipation: bool = True
    """Extrapolate the delayed stimuli over the reaction time (HDM paper Sec. 2.3)."""
    errors: bool = True
    """Apply the estimation errors (off: a deterministic delayed IDM)."""


def idm_accel(p: HdmParams, gap: float, v: float, dv: float) -> float:
    """IDM acceleration [m/s^2] at gap [m], own speed v [m/s], approach rate dv = v - v_lead [m/s]."""
    s_star = p.s0 + max(0.0, v * p.t_gap + v * dv / (2.0 * math.sqrt(p.a_max * p.b_comf)))
    free = (max(v, 0.0) / p.v0) ** p.delta
    return p.a_max * (1.0 - free - (s_star / max(gap, MIN_GAP)) ** 2)


@dataclass
class HumanDriverModel:
    """The Human Driver Model as a controller: observation -> force u in [-1, 1].

    Args:
        params: model parameters.
        seed: seeds the estimation errors; the CLI passes the episode seed, so a run
            is reproducible. Every ``reset()`` starts the same error realisation.
    """

    params: HdmParams = field(default_factory=HdmParams)
    seed: int = 0

    name = NAME

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the history and restart the error processes from the seed."""
        self._rng = np.random.default_rng([SEED_STREAM, self.seed & 0xFFFFFFFFFFFFFFFF])
        # Start in the stationary distribution (unit variance) of the OU processes.
        self._w_s = float(self._rng.standard_normal())
        self._w_l = float(self._rng.standard_normal())
        self._t: list[float] = []
        self._hist: list[tuple[float, float, float, float]] = []  # gap, v, dv, accel
        self.last_accel = 0.0  # [m/s^2] the IDM's desired acceleration, for traces

    def _advance_errors(self, dt: float) -> None:
        if dt <= 0.0:
            return
        decay = math.exp(-dt / self.params.tau_error)
        kick = math.sqrt(2.0 * dt / self.params.tau_error)
        self._w_s = decay * self._w_s + kick * float(self._rng.standard_normal())
        self._w_l = decay * self._w_l + kick * float(self._rng.standard_normal())

    def _delayed(self, t: float) -> tuple[float, float, float, float]:
        """Stimuli at time t [s], linearly interpolated; before the first frame, the first."""
        times = self._t
        if t <= times[0]:
            return self._hist[0]
        i = int(np.searchsorted(times, t))  # times[i-1] < t <= times[i]
        if i >= len(times):
            return self._hist[-1]
        w = (t - times[i - 1]) / (times[i] - times[i - 1])
        h0, h1 = self._hist[i - 1], self._hist[i]
        return tuple((1.0 - w) * x0 + w * x1 for x0, x1 in zip(h0, h1, strict=True))  # type: ignore[return-value]

    def __call__(self, obs: dict[str, Any]) -> float:
        """The force u for an observation with ``t``, ``gap``, ``v_host``, ``v_lead``, ``accel``."""
        p = self.params
        t = float(obs["t"])
        if self._t:
            self._advance_errors(t - self._t[-1])
        v = float(obs["v_host"])
        self._t.append(t)
        self._hist.append((float(obs["gap"]), v, v - float(obs["v_lead"]), float(obs["accel"])))
        # Keep only what the delay can reach (plus one step to interpolate from).
        horizon = t - p.reaction_time
        while len(self._t) > 2 and self._t[1] < horizon:
            del self._t[0], self._hist[0]

        gap, v_seen, dv, accel = self._delayed(horizon)
        if p.anticipation:
            gap = gap - p.reaction_time * dv
            v_seen = v_seen + p.reaction_time * accel
        if p.errors:
            dv = dv - gap * p.sigma_r * self._w_l
            gap = gap * math.exp(p.v_s * self._w_s)
        self.last_accel = idm_accel(p, gap, max(v_seen, 0.0), dv)
        return force_of_accel(self.last_accel)
