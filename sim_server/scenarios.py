"""Lead scenarios beyond the paper's test set: seeded speed profiles and initial conditions.

Names, ranges and descriptions live in :mod:`protocol.scenarios` (shared with the
clients); this module turns a name and the episode's generator into the lead's
speed, one per physics step, and the host's initial speed and gap. Every
parameter is drawn uniformly within its documented range, in the order the
registry lists them, so the same seed gives the same episode.

The profiles are piecewise linear in speed (constant acceleration phases), as the
standard tests define their targets. They are not held inside Table 2's lead bands.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from protocol.scenarios import DEFAULT_SET_SPEED, LEAD_SCENARIOS, LeadScenario, stopping_gap
from sim_server.errors import TrajectoryError

__all__ = ["LeadEpisode", "build", "ramp_profile"]


class LeadEpisode(NamedTuple):
    """What a lead scenario draws for one episode."""

    v_lead: np.ndarray  # [m/s] one per physics step, duration / dt + 1 of them
    v_host: float  # [m/s] host's initial speed
    gap: float  # [m] initial gap
    params: dict[str, float]  # the drawn parameters, SI units (stop-and-go: its first cycle's)


def ramp_profile(v0: float, phases: Sequence[tuple[float, float, float]], dt: float, duration: float) -> np.ndarray:
    """Speeds [m/s] every ``dt`` [s] for ``duration`` [s]: constant-acceleration phases.

    Args:
        v0: speed at t = 0 [m/s].
        phases: ``(target speed [m/s], rate [m/s^2] > 0, hold [s])``: ramp from the
            current speed to the target at the rate, then hold it.
        dt: physics step [s].
        duration: length [s]; past the last phase the last speed is held.

    Returns:
        ``round(duration / dt) + 1`` speeds, ``v[0] == v0``.
    """
    n = int(round(duration / dt)) + 1
    parts = [np.array([v0], dtype=float)]
    v = v0
    total = 1
    for target, rate, hold in phases:
        if total >= n:
            break
        if target != v:
            k = int(np.ceil(abs(target - v) / (rate * dt) - 1e-9))
            step = np.sign(target - v) * rate * dt
            ramp = v + step * np.arange(1, k + 1)
            # The last ramp step lands exactly on the target, never past it.
            ramp = np.minimum(ramp, target) if step > 0 else np.maximum(ramp, target)
            parts.append(ramp)
            total += k
        hold_steps = int(round(hold / dt))
        parts.append(np.full(hold_steps, float(target)))
        total += hold_steps
        v = target
    out = np.concatenate(parts)
    if len(out) < n:
        out = np.concatenate([out, np.full(n - len(out), out[-1])])
    return out[:n]


def _draw(spec: LeadScenario, rng: np.random.Generator, name: str, low: float | None = None) -> float:
    p = spec.param(name)
    return float(rng.uniform(p.low if low is None else max(low, p.low), p.high))


def build(name: str, rng: np.random.Generator, dt: float) -> LeadEpisode:
    """Draw one episode of the lead scenario ``name``.

    Args:
        name: a key of :data:`protocol.scenarios.LEAD_SCENARIOS`.
        rng: the episode's generator; parameters are drawn first, in registry order.
        dt: physics step [s].

    Raises:
        TrajectoryError: unknown name.
    """
    spec = LEAD_SCENARIOS.get(name)
    if spec is None:
        raise TrajectoryError(f"unknown lead scenario {name!r}; expected one of {', '.join(LEAD_SCENARIOS)}")
    T = spec.duration
    if name == "stopped":
        v_host = _draw(spec, rng, "v_host")
        # Drawn above the stopping distance at the braking limit: stopping is possible.
        gap = _draw(spec, rng, "gap", low=stopping_gap(v_host))
        return LeadEpisode(ramp_profile(0.0, (), dt, T), v_host, gap, {"v_host": v_host, "gap": gap})
    if name == "brake-stop":
        p = {k: _draw(spec, rng, k) for k in ("v_cruise", "gap", "t_brake", "decel")}
        v = ramp_profile(p["v_cruise"], [(p["v_cruise"], 1.0, p["t_brake"]), (0.0, p["decel"], T)], dt, T)
        return LeadEpisode(v, p["v_cruise"], p["gap"], p)
    if name == "brake-hard":
        p = {k: _draw(spec, rng, k) for k in ("v_cruise", "gap", "t_brake", "decel", "speed_drop")}
        low = p["v_cruise"] - p["speed_drop"]
        v = ramp_profile(p["v_cruise"], [(p["v_cruise"], 1.0, p["t_brake"]), (low, p["decel"], T)], dt, T)
        return LeadEpisode(v, p["v_cruise"], p["gap"], p)
    if name == "slow-lead":
        v_lead, v_host = _draw(spec, rng, "v_lead"), _draw(spec, rng, "v_host")
        gap = _draw(spec, rng, "gap", low=stopping_gap(v_host - v_lead))
        return LeadEpisode(ramp_profile(v_lead, (), dt, T), v_host, gap, {"v_lead": v_lead, "v_host": v_host, "gap": gap})
    if name == "cut-in":
        v_host, deficit = _draw(spec, rng, "v_host"), _draw(spec, rng, "speed_deficit")
        gap = _draw(spec, rng, "gap", low=stopping_gap(deficit))
        p = {"v_host": v_host, "speed_deficit": deficit, "gap": gap}
        return LeadEpisode(ramp_profile(v_host - deficit, (), dt, T), v_host, gap, p)
    if name == "closing":
        p = {k: _draw(spec, rng, k) for k in ("v_lead", "closing_speed", "margin")}
        gap = p["margin"] * stopping_gap(p["closing_speed"])
        return LeadEpisode(ramp_profile(p["v_lead"], (), dt, T), p["v_lead"] + p["closing_speed"], gap, p)
    if name == "catch-up":
        p = {k: _draw(spec, rng, k) for k in ("v_lead", "speed_deficit", "gap")}
        return LeadEpisode(ramp_profile(p["v_lead"], (), dt, T), p["v_lead"] - p["speed_deficit"], p["gap"], p)
    if name == "stop-and-go":
        return _stop_and_go(spec, rng, dt)
    if name == "distant-stop":
        # The host starts at the default set speed (a lower set speed caps it at reset).
        p = {k: _draw(spec, rng, k) for k in ("v_cruise", "gap", "t_brake", "decel")}
        v = ramp_profile(p["v_cruise"], [(p["v_cruise"], 1.0, p["t_brake"]), (0.0, p["decel"], T)], dt, T)
        return LeadEpisode(v, DEFAULT_SET_SPEED, p["gap"], p)
    if name == "constant":
        p = {k: _draw(spec, rng, k) for k in ("v_lead", "speed_offset", "gap")}
        return LeadEpisode(ramp_profile(p["v_lead"], (), dt, T), max(0.0, p["v_lead"] + p["speed_offset"]), p["gap"], p)
    raise AssertionError(f"lead scenario {name!r} is registered but has no builder")


def _stop_and_go(spec: LeadScenario, rng: np.random.Generator, dt: float) -> LeadEpisode:
    # One cycle: cruise at v_go, brake to 0, stand, pull away to the next v_go.
    # Every cycle draws its own values, so no two stops are alike.
    gap = _draw(spec, rng, "gap")
    v_go = _draw(spec, rng, "v_go")
    params = {"gap": gap, "v_go": v_go}
    phases: list[tuple[float, float, float]] = []
    t = 0.0
    v = v_go
    while t < spec.duration:
        t_cruise, decel = _draw(spec, rng, "t_cruise"), _draw(spec, rng, "decel")
        t_stand, accel = _draw(spec, rng, "t_stand"), _draw(spec, rng, "accel")
        v_next = _draw(spec, rng, "v_go")
        if not phases:  # the first cycle's values stand for the episode in its params
            params.update(t_cruise=t_cruise, decel=decel, t_stand=t_stand, accel=accel)
        phases += [(v, 1.0, t_cruise), (0.0, decel, t_stand), (v_next, accel, 0.0)]
        t += t_cruise + v / decel + t_stand + v_next / accel
        v = v_next
    return LeadEpisode(ramp_profile(v_go, phases, dt, spec.duration), v_go, gap, params)
