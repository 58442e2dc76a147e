"""Action types: how a discrete action becomes the normalised force u in [-1, 1].

Kept apart from the env and the network, as highway-env keeps ``action.py``.

* ``levels`` (the paper): action ``a`` is the force level ``-1 + 0.1 a`` (21 levels).
  Any level may follow any other, so one step can swing the acceleration by 9 m/s^2:
  a DQN that flips between neighbouring argmaxes drives bang-bang.
* ``steps`` (beyond the paper): action ``a`` adds :data:`FORCE_STEPS` ``[a]`` to the
  force held since the last step. Comfortable driving is a run of small steps
  (0.02 of force is 0.07-0.11 m/s^2 per 0.1 s, about 1 m/s^3); one large brake step
  stays for emergencies. Since the force is then part of the state, the policy
  observes its own previous outputs, with the driver's set speed, as ``controls``.
  Anti-windup: where the vehicle could not follow the held force (the speed limiter at
  the set speed, or a standstill under the brake), the held force drops to the one the
  vehicle achieved, as a production controller's integrator does; else a policy could
  sit at full throttle on the limiter and need a second to come off it.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from protocol.constants import A_MAX, A_MIN, FORCES, N_ACTIONS
from sim_server.vehicle import accel_of_force

__all__ = ["ACTION_TYPES", "FORCE_STEPS", "CONTROLS", "force_of_accel", "ActionType", "ForceLevels", "ForceSteps", "make_action_type"]

ACTION_TYPES = ("levels", "steps")
# Force increments of the "steps" type: fine near zero, one hard brake (a stopped car
# ahead needs -4 m/s^2 within about 0.3 s), and no hard throttle, which comfort never needs.
FORCE_STEPS = (-0.5, -0.1, -0.02, 0.0, 0.02, 0.1)
# The "steps" type's controls, per stacked frame: the force held when the frame was taken
# (the agent's own last output) and the cruise set speed [m/s] (the driver's input).
CONTROLS = ("force", "set_speed")
FORCE_GRID = 0.02  # every force the "steps" type holds is a multiple of this
WINDUP_TOLERANCE = 1e-3  # [m/s^2] achieved acceleration this far short of the command: limited


def force_of_accel(a: float) -> float:
    """Invert the simulator's force map: acceleration [m/s^2] to u in [-1, 1]."""
    u = a / A_MAX if a >= 0.0 else -a / A_MIN
    return min(1.0, max(-1.0, u))


class ActionType(Protocol):
    """What the env, the trainer and the driving controller need of an action type."""

    name: str
    n: int  # discrete actions
    n_controls: int  # controls observed per stacked frame (0: none)

    def reset(self) -> None: ...

    def force(self, action: int) -> float: ...

    def observe(self, accel: float) -> None: ...

    def controls(self, set_speed: float) -> np.ndarray | None: ...


class ForceLevels:
    """The paper's 21 absolute force levels; observes nothing but frames and speeds."""

    name, n, n_controls = "levels", N_ACTIONS, 0

    def reset(self) -> None:
        pass

    def force(self, action: int) -> float:
        return float(FORCES[action])

    def observe(self, accel: float) -> None:
        pass

    def controls(self, set_speed: float) -> None:
        return None


class ForceSteps:
    """Increments of a held force, which starts each episode at 0 (coasting at constant speed)."""

    name, n, n_controls = "steps", len(FORCE_STEPS), len(CONTROLS)

    def __init__(self) -> None:
        self.u = 0.0

    def reset(self) -> None:
        self.u = 0.0

    def force(self, action: int) -> float:
        # rounded to the 0.02 grid, so that a long run of steps never drifts off it
        self.u = float(np.clip(round(self.u + FORCE_STEPS[action], 2), -1.0, 1.0))
        return self.u

    def observe(self, accel: float) -> None:
        """Anti-windup: the acceleration [m/s^2] the last step achieved; where it fell short
        of the held force's, hold the achieved force instead (rounded toward zero, on the grid)."""
        commanded = accel_of_force(self.u)
        if abs(accel) < abs(commanded) - WINDUP_TOLERANCE:
            self.u = round(math.trunc(round(force_of_accel(accel) / FORCE_GRID, 6)) * FORCE_GRID, 2)

    def controls(self, set_speed: float) -> np.ndarray:
        """The controls of the frame the last force produced: (force, set speed)."""
        return np.array([self.u, set_speed], np.float32)


def make_action_type(name: str) -> ActionType:
    """A fresh action type by name ("levels" or "steps").

    Raises:
        ValueError: an unknown name.
    """
    if name == "levels":
        return ForceLevels()
    if name == "steps":
        return ForceSteps()
    raise ValueError(f"action type {name!r} is not one of {ACTION_TYPES}")
