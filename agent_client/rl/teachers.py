"""Who labels the states of a teacher (DAgger) run: one registry entry per ``--teacher``.

Every name ``vacc train --teacher`` accepts, :data:`~agent_client.rl.config.TEACHERS`
and the learner's teacher laws come from :data:`REGISTRY`. A law is the ACC of
:class:`~agent_client.controllers.acc.AccController` on one of three desired gaps with
its own gains; a "-margin" entry is its law stopping 3 m further back. Why each law has
the gains it has is in docs/training.md ("Options: the evidence behind the defaults").

``python -m agent_client.rl.teachers`` prints the table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from agent_client.controllers.acc import AccController
from agent_client.rewards import ECO_TIME_GAP
from protocol.constants import DESIRED_GAP

__all__ = ["MARGIN_GAPS", "REGISTRY", "TEACHERS", "Teacher", "teacher_law"]

# (standstill distance d_safe, closest approach d_min) [m] of the "-margin" teachers: 3 m
# more than the ACC's (5 m, 3 m), about what a student seeing the danger a few frames late
# overran its teacher by.
MARGIN_GAPS = (8.0, 6.0)


@dataclass(frozen=True)
class Teacher:
    """One ``--teacher``: its name, its law (None: not a law) and a one-line description.

    Attributes:
        name: the option's value.
        about: one line for ``--help`` tables and docs.
        gap: the law's desired gap: "time" (the ACC's 1.8 s time gap), "55" (the paper's
            55 m at every speed) or "eco" (the eco reward's clip(2 s x speed, 5 m, 55 m));
            None for "none" and "policy", which are no law.
        beta: [1/s^2] gap gain; None: the ACC's.
        gamma: [1/s] speed-difference gain; None: the ACC's.
        decel_cap: [m/s^2] cap on the law's braking (the collision-avoidance limit may brake harder).
        margin: stop :data:`MARGIN_GAPS` behind a car instead of the ACC's gaps.
    """

    name: str
    about: str
    gap: str | None = "time"
    beta: float | None = None
    gamma: float | None = None
    decel_cap: float = math.inf
    margin: bool = False

    def law(self) -> AccController:
        """The ACC law this teacher labels with.

        Raises:
            ValueError: "none" or "policy", which are no law.
        """
        if self.gap is None:
            raise ValueError(f"teacher {self.name!r} is not an ACC law")
        kw: dict[str, Any] = dict(zip(("d_safe", "d_min"), MARGIN_GAPS, strict=True)) if self.margin else {}
        if self.gap == "55":
            kw.update(fixed_gap=DESIRED_GAP)
        elif self.gap == "eco":
            kw.update(t_gap=ECO_TIME_GAP, max_gap=DESIRED_GAP)
        if self.beta is not None:
            kw.update(beta=self.beta, gamma=self.gamma)
        if math.isfinite(self.decel_cap):
            kw.update(decel_cap=self.decel_cap)
        return AccController(**kw)


def _with_margin(t: Teacher) -> Teacher:
    """``t`` stopping :data:`MARGIN_GAPS` behind a car: the "-margin" entry."""
    return Teacher(f"{t.name}-margin", f"{t.about}, stopping 3 m further back", t.gap, t.beta, t.gamma, t.decel_cap, margin=True)


_GENTLE = Teacher("acc-55-gentle", "55 m law, beta 0.4, gamma 2.0, braking capped at 3 m/s^2", "55", 0.4, 2.0, 3.0)
_ECO_55 = Teacher("acc-55-eco", "the gentle law with gamma 3.0, matching the lead's speed harder", "55", 0.4, 3.0, 3.0)
_CALM = Teacher("acc-55-calm", "the gentle law with beta 0.3, gamma 1.5, for a student seeing late", "55", 0.3, 1.5, 3.0)
_CALMER = Teacher("acc-55-calmer", "the gentle law with beta 0.25, gamma 1.5", "55", 0.25, 1.5, 3.0)
_ECO = Teacher("eco", "ACC law on the eco reward's desired gap, beta 0.1, gamma 0.3", "eco", 0.1, 0.3)
_ECO_MID = Teacher("eco-mid", "the eco law with beta 0.125", "eco", 0.125, 0.3)
_ECO_FIRM = Teacher("eco-firm", "the eco law with beta 0.15, opening a short gap faster", "eco", 0.15, 0.3)
# A 10-car platoon of it stays string-stable behind every OpenACC lead when it sees the car
# ahead 0.5 s late, as a camera does; eco-firm's does not (docs/platoons.md).
_PLATOON = Teacher("platoon", "the eco gap with beta 0.2, gamma 0.8: string-stable seeing the car ahead 0.5 s late", "eco", 0.2, 0.8)
# The same, calmer on the gap: a camera's slow error in the gap (about 0.6 m at 15 m) moves
# each car's speed a quarter as much, and the platoon stays string-stable 0.8 s late.
_PLATOON_CALM = Teacher("platoon-calm", "the eco gap with beta 0.05, gamma 1.0: the platoon law, calm on a noisy gap", "eco", 0.05, 1.0)

REGISTRY: dict[str, Teacher] = {t.name: t for t in (
    Teacher("none", "no teacher: Double DQN on the reward", gap=None),
    Teacher("policy", "a trained network (--teacher-policy) seeing the same frames: distillation", gap=None),
    Teacher("acc", "the traditional ACC: 1.8 s time gap, its own gains"),
    Teacher("acc-55", "ACC law aiming at the paper's 55 m at every speed, beta 0.3, gamma 1.0", "55", 0.3, 1.0),
    _GENTLE, _with_margin(_GENTLE),
    _ECO_55, _with_margin(_ECO_55),
    _CALM, _with_margin(_CALM),
    _CALMER, _with_margin(_CALMER),
    _ECO, _with_margin(_ECO),
    _ECO_MID, _with_margin(_ECO_MID),
    _ECO_FIRM, _with_margin(_ECO_FIRM),
    _PLATOON, _PLATOON_CALM,
)}  # fmt: skip

TEACHERS = tuple(REGISTRY)  # who labels the states in teacher (DAgger) runs


def teacher_law(name: str) -> AccController:
    """The ACC law of teacher ``name``.

    Raises:
        ValueError: an unknown name, or one that is no law ("none", "policy").
    """
    if name not in REGISTRY:
        raise ValueError(f"{name!r} is not one of {TEACHERS}")
    return REGISTRY[name].law()


if __name__ == "__main__":
    for t in REGISTRY.values():
        print(f"{t.name:22s} {t.about}")
