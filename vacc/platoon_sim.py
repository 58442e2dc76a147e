"""An in-process kinematic platoon: a lead on a speed profile and followers in one lane.

No camera, no server, no traffic: each follower is the simulator's longitudinal model
(:func:`sim_server.vehicle.advance_speed` under :func:`protocol.force.accel_of_force`,
:data:`~protocol.constants.SUBSTEPS` physics steps of :data:`~protocol.constants.PHYSICS_DT`
per control step) driven by a controller that reads the observation a session gives
(``t``, ``gap``, ``v_host``, ``accel``, ``v_lead``, ``a_lead``, ``set_speed``) about
itself and the car directly ahead. Positions advance as the world's pymunk bodies do (velocity first, then
x += v dt), so one follower behind a lead here drives as the host of a world does.

It is fast enough to test the string-stability figures against the ACC's linear theory
and to calibrate the ACC to real platoons (:mod:`vacc.acc_calibration`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocol.constants import PHYSICS_DT, SUBSTEPS
from protocol.force import accel_of_force
from protocol.scenarios import DEFAULT_SET_SPEED
from sim_server.scene import CAR_LENGTH
from sim_server.vehicle import advance_speed

__all__ = ["PlatoonRun", "simulate_platoon", "lead_profile", "Lagged"]

Policy = Callable[[dict[str, Any]], float]  # observation -> force u in [-1, 1]


class Lagged:
    """A controller that sees the car ahead (``gap``, ``v_lead``, ``a_lead``) ``steps``
    control steps late and itself now: a bound on what a camera policy, whose view of the
    lead's motion lags, can do with the same law."""

    def __init__(self, policy: Policy, steps: int):
        self.policy, self.steps = policy, steps
        self._seen: deque[dict[str, Any]] = deque(maxlen=steps + 1)
        self.reference_gap = getattr(policy, "reference_gap", None)

    def __call__(self, obs: dict[str, Any]) -> float:
        self._seen.append({k: obs[k] for k in ("gap", "v_lead", "a_lead") if k in obs})
        return float(self.policy({**obs, **self._seen[0]}))


@dataclass(frozen=True)
class PlatoonRun:
    """A platoon's states at every control frame (frame 0 the start), lead first."""

    t: np.ndarray  # [s] [F]
    v: np.ndarray  # [m/s] [n_cars, F]
    x: np.ndarray  # [m] [n_cars, F] centre positions, the lead starting at 0
    gaps: np.ndarray  # [m] [n_cars - 1, F] bumper to bumper, row i: car i + 1 behind car i
    force: np.ndarray  # [-] [n_cars - 1, F] the force each follower applied up to the frame
    collided: int | None  # the first follower (1-based) that touched the car ahead, or None


def lead_profile(t: np.ndarray, v: np.ndarray, duration: float, physics_dt: float = PHYSICS_DT) -> np.ndarray:
    """A lead's speed [m/s] at every physics step over ``duration`` [s], linear between samples.

    Raises:
        ValueError: times not increasing, or a negative speed.
    """
    t, v = np.asarray(t, float), np.asarray(v, float)
    if t.ndim != 1 or t.shape != v.shape or t.size < 2 or not np.all(np.diff(t) > 0.0):
        raise ValueError("a lead trace needs increasing times and one speed per time")
    if not np.all(np.isfinite(v)) or np.any(v < 0.0):
        raise ValueError("a lead trace's speeds must be finite and >= 0")
    steps = int(round(duration / physics_dt))
    return np.interp(t[0] + physics_dt * np.arange(steps + 1), t, v)


def simulate_platoon(
    v_lead: np.ndarray,
    controllers: Sequence[Policy],
    gap0: float | Sequence[float],
    *,
    v0: float | Sequence[float] | None = None,
    set_speed: float = DEFAULT_SET_SPEED,
    physics_dt: float = PHYSICS_DT,
    substeps: int = SUBSTEPS,
) -> PlatoonRun:
    """Drive followers behind a lead on ``v_lead`` (one speed per physics step).

    Args:
        v_lead: the lead's speed [m/s] per physics step, from the start.
        controllers: one per follower, nearest the lead first; each maps an observation
            to a force u (its ``reset`` is not called here).
        gap0: initial gap(s) [m] of each follower to the car ahead.
        v0: initial speed(s) [m/s] of the followers; default the lead's first speed.
        set_speed: the followers' cruise set speed [m/s], which their limiter holds.
        physics_dt, substeps: the world's timing.

    Returns:
        The run up to the profile's end, or to the control frame of the first collision.

    Raises:
        ValueError: no follower, or initial values of the wrong count.
    """
    n = len(controllers)
    if n < 1:
        raise ValueError("a platoon needs at least one follower")
    gaps0 = np.broadcast_to(np.asarray(gap0, float), (n,))
    speeds0 = np.broadcast_to(np.asarray(v_lead[0] if v0 is None else v0, float), (n,))
    frames = (len(v_lead) - 1) // substeps
    v = np.zeros((n + 1, frames + 1))
    x = np.zeros((n + 1, frames + 1))
    force = np.zeros((n, frames + 1))
    v[:, 0] = [v_lead[0], *speeds0]
    x[1:, 0] = -np.cumsum(gaps0 + CAR_LENGTH)
    a_prev = np.zeros(n + 1)  # [m/s^2] each car's acceleration over the last control period
    collided = None
    vk, xk, step = v[:, 0].copy(), x[:, 0].copy(), 0
    for k in range(1, frames + 1):
        us = [_decide(controllers[i], xk, vk, a_prev, i + 1, set_speed, (k - 1) * substeps * physics_dt) for i in range(n)]
        a_cmd = np.array([accel_of_force(u) for u in us])
        v_start = vk.copy()
        for _ in range(substeps):
            step += 1
            for i in range(n):
                vk[i + 1] = advance_speed(float(vk[i + 1]), float(a_cmd[i]), physics_dt, set_speed)
            vk[0] = v_lead[step]
            xk += vk * physics_dt
        a_prev = (vk - v_start) / (substeps * physics_dt)
        v[:, k], x[:, k], force[:, k] = vk, xk, us
        gap = xk[:-1] - xk[1:] - CAR_LENGTH
        if np.any(gap <= 0.0):
            collided = int(np.argmax(gap <= 0.0)) + 1
            v, x, force = v[:, : k + 1], x[:, : k + 1], force[:, : k + 1]
            break
    t = np.arange(v.shape[1]) * substeps * physics_dt
    return PlatoonRun(t, v, x, x[:-1] - x[1:] - CAR_LENGTH, force, collided)


def _decide(policy: Policy, x: np.ndarray, v: np.ndarray, a: np.ndarray, i: int, set_speed: float, t: float) -> float:
    """Car i's force from what a session would show it of the car ahead (and of itself)."""
    obs = {
        "t": t,
        "accel": float(a[i]),
        "gap": float(x[i - 1] - x[i] - CAR_LENGTH),
        "v_host": float(v[i]),
        "v_lead": float(v[i - 1]),
        "a_lead": float(a[i - 1]),
        "set_speed": set_speed,
    }
    return float(policy(obs))
