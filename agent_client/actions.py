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
* ``ramp`` (beyond the paper): action ``a`` picks the paper's level ``-1 + 0.1 a`` as a
  *target*; the held force moves toward it by at most :data:`RAMP_RATE` per step (1.4 m/s^3
  of throttle, 2.2 m/s^3 of brake, inside ISO 15622's 2.5), except the full brake, which acts
  at once (the emergency a stopped car ahead needs). The policy keeps a proportional
  mapping from what it sees to the force it wants, as the paper's does, so it need not
  integrate (the "steps" type's slow limit cycle); the actuator makes it smooth. It
  observes the held force and the set speed as ``controls``, with the same anti-windup.
* ``ramp-fine`` (beyond the paper): the ramp with :data:`FINE_LEVELS` as its 21 targets,
  dense near zero. The paper's levels are 0.1 apart (0.35 m/s^2 of throttle, 0.55 of
  brake), and a ramp can hold only a level: a student of the ACC, whose steady following
  needs forces of 0.01-0.06, pulsed between -0.1, 0 and +0.1 (jerk and fuel the ACC does
  not spend). Holding 0.02 or 0.05 lets it follow as gently as its teacher.
* ``continuous`` (beyond the paper; the actor-critic's, :mod:`agent_client.rl.actor_critic`):
  the action is itself the target force in [-1, 1], and the held force ramps toward it at
  the ramp's :data:`RAMP_RATE`, so comfort holds by construction as for ``ramp``; a target
  at or below :data:`FULL_BRAKE_TARGET` is the full brake, which acts at once as the ramp's
  does. It observes the held force and the set speed as ``controls``, with the same anti-windup.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from protocol.constants import A_MAX, A_MIN, FORCE_LEVELS, FORCES, N_ACTIONS
from protocol.force import accel_of_force

__all__ = ["ACTION_TYPES", "RAMP_ACTIONS", "CONTINUOUS_ACTIONS", "FULL_BRAKE_TARGET", "ContinuousRamp", "is_continuous", "FORCE_STEPS", "CONTROLS", "force_of_accel", "ActionType", "ForceLevels", "ForceSteps", "ForceRamp", "FineRamp", "FINE_LEVELS", "make_action_type"]

ACTION_TYPES = ("levels", "steps", "ramp", "ramp-fine", "continuous")
RAMP_ACTIONS = ("ramp", "ramp-fine")  # the types whose actions are target levels of a rate-limited force
CONTINUOUS_ACTIONS = ("continuous",)  # the types whose action is a float (a Box), not an index
# Force increments of the "steps" type: fine near zero, one hard brake (a stopped car
# ahead needs -4 m/s^2 within about 0.3 s), and no hard throttle, which comfort never needs.
FORCE_STEPS = (-0.5, -0.1, -0.02, 0.0, 0.02, 0.1)
# The "steps" type's controls, per stacked frame: the force held when the frame was taken
# (the agent's own last output) and the cruise set speed [m/s] (the driver's input).
CONTROLS = ("force", "set_speed")
# The "ramp" type's largest change of the held force per step, toward the chosen level.
RAMP_RATE = 0.04
EMERGENCY_LEVEL = 0  # the "ramp" level that acts at once: the full brake
# The "ramp-fine" targets: 21 levels as the paper's, from the full brake to full throttle,
# dense near zero where steady following lives (0.02 of force is 0.07-0.11 m/s^2).
FINE_LEVELS = (-1.0, -0.8, -0.6, -0.45, -0.3, -0.2, -0.14, -0.09, -0.05, -0.02, 0.0, 0.02, 0.05, 0.09, 0.14, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)
# The "continuous" type's targets at or below this are the full brake, at once: the actor's
# tanh output reaches -1 only in the limit, and a target this low asks for it anyway.
FULL_BRAKE_TARGET = -0.95
FORCE_GRID = 0.02  # every force the "steps" type holds is a multiple of this
WINDUP_TOLERANCE = 1e-3  # [m/s^2] achieved acceleration this far short of the command: limited


def force_of_accel(a: float) -> float:
    """Invert the simulator's force map: acceleration [m/s^2] to u in [-1, 1]."""
    u = a / A_MAX if a >= 0.0 else -a / A_MIN
    return _clip(u, -1.0, 1.0)


def _clip(x: float, lo: float, hi: float) -> float:
    """``x`` within [lo, hi]: np.clip's number for a float, at a tenth of its cost per decision."""
    return min(hi, max(lo, x))


class ActionType(Protocol):
    """What the env, the trainer and the driving controller need of an action type."""

    name: str
    n: int  # discrete actions
    n_controls: int  # controls observed per stacked frame (0: none)

    def reset(self) -> None: ...

    def force(self, action: int) -> float: ...

    def observe(self, accel: float) -> None: ...

    def imitate(self, u: float, hard_brake: float = 0.0) -> int: ...

    def controls(self, set_speed: float) -> np.ndarray | None: ...


class ForceLevels:
    """The paper's 21 absolute force levels; observes nothing but frames and speeds."""

    name, n, n_controls = "levels", N_ACTIONS, 0

    def reset(self) -> None:
        pass

    def force(self, action: int) -> float:
        return float(FORCES[action])

    def imitate(self, u: float, hard_brake: float = 0.0) -> int:
        """The level nearest a teacher's force ``u``."""
        return _nearest(FORCE_LEVELS, FORCE_LEVELS, u)

    def observe(self, accel: float) -> None:
        pass

    def controls(self, set_speed: float) -> None:
        return None


class HeldForce:
    """A force held from step to step, which starts each episode at 0 (coasting at constant
    speed); the base of the "steps" and "ramp" types, which observe it with the set speed."""

    n_controls = len(CONTROLS)

    def __init__(self) -> None:
        self.u = 0.0

    def reset(self) -> None:
        self.u = 0.0

    def observe(self, accel: float) -> None:
        """Anti-windup: the acceleration [m/s^2] the last step achieved; where it fell short
        of the held force's, hold the achieved force instead (rounded toward zero, on the grid)."""
        commanded = accel_of_force(self.u)
        if abs(accel) < abs(commanded) - WINDUP_TOLERANCE:
            self.u = round(math.trunc(round(force_of_accel(accel) / FORCE_GRID, 6)) * FORCE_GRID, 2)

    def controls(self, set_speed: float) -> np.ndarray:
        """The controls of the frame the last force produced: (force, set speed)."""
        return np.array([self.u, set_speed], np.float32)


class ForceSteps(HeldForce):
    """Increments of the held force."""

    name, n = "steps", len(FORCE_STEPS)

    def imitate(self, u: float, hard_brake: float = 0.0) -> int:
        """The step that brings the held force nearest a teacher's force ``u``."""
        nominal = [self.u + d for d in FORCE_STEPS]
        return _nearest([_clip(f, -1.0, 1.0) for f in nominal], nominal, u)

    def force(self, action: int) -> float:
        # rounded to the 0.02 grid, so that a long run of steps never drifts off it
        self.u = _clip(round(self.u + FORCE_STEPS[action], 2), -1.0, 1.0)
        return self.u


class ForceRamp(HeldForce):
    """The paper's 21 levels as targets of a rate-limited held force."""

    name, n = "ramp", N_ACTIONS
    levels: Sequence[float] = FORCE_LEVELS

    def _toward(self, target: float) -> float:
        """The force one ramp step gives toward ``target`` from the one held now (rounded to
        0.01, so that a long run of ramps never drifts off the levels)."""
        return round(self.u + _clip(target - self.u, -RAMP_RATE, RAMP_RATE), 2)

    def _next(self, action: int) -> float:
        """The force ``action`` gives from the one held now."""
        target = float(self.levels[action])
        return target if action == EMERGENCY_LEVEL else self._toward(target)

    def force(self, action: int) -> float:
        self.u = self._next(action)
        return self.u

    def force_toward(self, target: float) -> float:
        """Ramp the held force toward a target between the levels (the mean decision,
        :mod:`agent_client.rl.policy`); never an emergency brake, which only its level gives."""
        self.u = self._toward(_clip(float(target), -1.0, 1.0))
        return self.u

    def imitate(self, u: float, hard_brake: float = 0.0) -> int:
        """The level whose ramp brings the held force nearest a teacher's force ``u`` (of
        several that do, the level nearest ``u``); the full brake only where it is nearer
        than any ramp and the teacher decelerates at ``hard_brake`` [m/s^2] or more (0: any
        braking), since the full brake is released only at the ramp's rate."""
        reach = [self._next(a) for a in range(self.n)]
        if -accel_of_force(u) < hard_brake:
            reach[EMERGENCY_LEVEL] = math.inf  # not a candidate
        return _nearest(reach, self.levels, u)


class FineRamp(ForceRamp):
    """The ramp with :data:`FINE_LEVELS` as its targets."""

    name = "ramp-fine"
    levels = FINE_LEVELS


class ContinuousRamp(ForceRamp):
    """A force target in [-1, 1] as the action; the held force ramps toward it as the
    ramp's does (the same :data:`RAMP_RATE`), but for the full brake, at once."""

    name, n = "continuous", 1  # n: the action's dimension (a Box of one force)
    levels: Sequence[float] = ()  # no levels: any target

    def _toward(self, target: float) -> float:
        """One ramp step toward ``target``, unrounded: there are no levels to stay on, and
        rounding to 0.01 would flip between the two forces either side of a target."""
        return self.u + _clip(target - self.u, -RAMP_RATE, RAMP_RATE)

    def force(self, action: float) -> float:  # type: ignore[override]
        """Apply a target force ``action`` (clipped to [-1, 1]); returns the force held."""
        target = _clip(float(action), -1.0, 1.0)
        self.u = -1.0 if target <= FULL_BRAKE_TARGET else self._toward(target)
        return self.u

    def imitate(self, u: float, hard_brake: float = 0.0) -> float:  # type: ignore[override]
        """A teacher's force ``u`` as the target that asks for it: ``u`` itself, but the full
        brake only where the teacher decelerates at ``hard_brake`` [m/s^2] or more (0: any)."""
        u = _clip(float(u), -1.0, 1.0)
        if u <= FULL_BRAKE_TARGET and -accel_of_force(u) < hard_brake:
            return FULL_BRAKE_TARGET + 0.01  # the ramp's hardest, not the emergency
        return u


def is_continuous(name: str) -> bool:
    """Whether the action type ``name`` takes a float target (a ``Box``), not an index."""
    return name in CONTINUOUS_ACTIONS


def _nearest(forces: Sequence[float], nominal: Sequence[float], u: float) -> int:
    """The action whose force is nearest ``u``; ties go to the nominal force nearest ``u``."""
    return min(range(len(forces)), key=lambda a: (round(abs(forces[a] - u), 9), abs(nominal[a] - u)))


def make_action_type(name: str) -> ActionType:
    """A fresh action type by name (one of :data:`ACTION_TYPES`).

    Raises:
        ValueError: an unknown name.
    """
    if name == "levels":
        return ForceLevels()
    if name == "steps":
        return ForceSteps()
    if name == "ramp":
        return ForceRamp()
    if name == "ramp-fine":
        return FineRamp()
    if name == "continuous":
        return ContinuousRamp()  # type: ignore[return-value]  # its actions are floats: the protocol's discrete signatures, overridden
    raise ValueError(f"action type {name!r} is not one of {ACTION_TYPES}")
