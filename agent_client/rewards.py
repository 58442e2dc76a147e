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
* ``eco`` reward (beyond the paper, its first item of future work): the gap term around a
  speed-dependent desired gap (:func:`eco_desired_gap`: 55 m from 27.5 m/s up, a 2 s time
  gap below it, 5 m at a standstill, so that stopping behind a stopped car earns the
  reward's peak instead of a penalty for ever), minus
  the instantaneous energy of the host (CMEM fuel rate for the ICE car, the eq. 6 battery
  power for the EV, each over its full-throttle value at 30 m/s), minus a comfort term
  (the jerk over one control period, over 4x ISO 15622's 2.5 m/s^3), minus a closing term
  (the speed difference to the lead over :data:`CLOSING_FULL`: it damps the slow cycle
  of the gap about its target that a gap term alone leaves unpunished), weighted by
  :data:`ECO_WEIGHTS` and normalised by their sum so it stays in [-1, 1]. The gap and
  the lead's speed are privileged: they shape training, as the paper's gap term does, and
  never reach the network.
* ``eco-draw`` reward: the eco reward with the EV's energy term over the power drawn only,
  0 while it regenerates (the ICE's is the eco reward): see :data:`REWARDS`.

Every reward takes (gap, u) and, as keywords, the host's speed ``v`` [m/s], its
acceleration ``a`` [m/s^2] over the step, the acceleration ``a_prev`` of the step
before and the lead's speed ``v_lead`` [m/s]; the paper's two ignore them.

Each reward has a twin in :data:`REWARD_TERMS` (:func:`make_reward_terms`) that takes
the same arguments and returns its terms by name, weighted and normalised: their sum is
the reward, to float rounding (the reward itself is computed as it always was, so its
value does not move by a bit). ``gap``: {gap}; ``force``: {gap, force}; ``eco``:
{gap, energy, comfort, closing}, the last three <= 0 (ICE) or the energy > 0 while an EV
regenerates.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import numpy as np

from agent_client.controllers.acc import AccController
from energy.cmem import COROLLA_2022, cmem_rates
from energy.comfort import ISO_JERK_LIMIT_MPS3
from energy.ev import eq6_power_kw
from protocol.constants import CONTROL_PERIOD, DESIRED_GAP

__all__ = [
    "CONTROL_PERIOD", "GAP_POINTS", "FORCE_HALF_WIDTH", "ECO_WEIGHTS", "ECO_TIME_GAP", "gap_term", "eco_desired_gap", "force_term", "energy_term",
    "comfort_term", "closing_term", "check_eco_weights", "EcoTerms", "eco_terms",
    "gap_reward", "force_reward", "eco_reward", "make_reward", "REWARDS", "ECO_REWARDS",
    "gap_reward_terms", "force_reward_terms", "eco_reward_terms", "make_reward_terms", "REWARD_TERMS",
]  # fmt: skip

GAP_POINTS = ((0.0, -10.0), (30.0, 0.0), (55.0, 10.0), (80.0, 0.0), (300.0, -5.0))  # ([m], raw reward)
FORCE_PEAK = 10.0  # raw reward at u = 0
FORCE_HALF_WIDTH = 0.3  # |u| beyond which the force term is 0
_GX = np.array([p[0] for p in GAP_POINTS])
_GY = np.array([p[1] for p in GAP_POINTS])


def gap_term(gap: float, desired: float = DESIRED_GAP) -> float:
    """Raw Table 1 gap reward for a gap [m]; -10 at or below contact.

    ``desired`` [m] moves the peak: the points below it scale with it (the zero at
    30/55 of it), those above shift with it (the zero 25 m beyond it); at 55 m, Table 1.
    """
    if desired == DESIRED_GAP:
        return float(np.interp(gap, _GX, _GY))
    shift = desired - DESIRED_GAP
    x = np.where(_GX <= DESIRED_GAP, _GX * desired / DESIRED_GAP, _GX + shift)
    return float(np.interp(gap, x, _GY))


def eco_desired_gap(v_host: float) -> float:
    """The eco reward's desired gap [m] at host speed [m/s]: a constant time gap of
    :data:`ECO_TIME_GAP`, at least the ACC's standstill distance, at most the paper's 55 m."""
    return float(min(DESIRED_GAP, max(AccController.d_safe, ECO_TIME_GAP * v_host)))


def force_term(u: float) -> float:
    """Raw Table 1 force reward for a normalised force u."""
    return FORCE_PEAK * max(0.0, 1.0 - abs(u) / FORCE_HALF_WIDTH)


FUEL_FULL = 19.1  # [g/s] Corolla CMEM fuel rate at 30 m/s and full throttle (3.5 m/s^2)
POWER_FULL = 246.5  # [kW] Leaf eq. 6 battery power at 30 m/s and full throttle
JERK_FULL = 4.0 * ISO_JERK_LIMIT_MPS3  # [m/s^3] the comfort term's full scale
CLOSING_FULL = 5.0  # [m/s] speed difference to the lead at which the closing term is full
# Weights (gap, energy, comfort, closing); the ablations that chose them: docs/training.md.
ECO_WEIGHTS = (1.0, 0.5, 0.25, 0.5)
ECO_WEIGHT_NAMES = ("gap", "energy", "comfort", "closing")
ECO_TIME_GAP = 2.0  # [s] 55 m at 27.5 m/s, the ICE leads' lower band: the paper's target on its own roads


def energy_term(v: float, a: float, scenario: str, regen: bool = True) -> float:
    """The host's instantaneous energy use over its full-throttle value, in [-1, 1].

    ICE: CMEM fuel rate (>= 0; fuel cut when coasting). EV: eq. 6 battery power, negative
    while regenerating; with ``regen`` False the power drawn only (0 while regenerating).
    """
    va, aa = np.array([v], float), np.array([a], float)
    if scenario == "ice":
        return float(min(1.0, cmem_rates(va, aa, COROLLA_2022).fuel_g_s[0] / FUEL_FULL))
    power = float(np.clip(eq6_power_kw(va, aa)[0] / POWER_FULL, -1.0, 1.0))
    return power if regen else max(0.0, power)


def comfort_term(a: float, a_prev: float, dt: float = CONTROL_PERIOD) -> float:
    """Jerk over one control period, |a - a_prev| / dt, over :data:`JERK_FULL`, at most 1."""
    return min(1.0, abs(a - a_prev) / dt / JERK_FULL)


def closing_term(v: float, v_lead: float) -> float:
    """|v_lead - v| over :data:`CLOSING_FULL`, at most 1."""
    return min(1.0, abs(v_lead - v) / CLOSING_FULL)


def check_eco_weights(weights: tuple[float, ...]) -> str | None:
    """Why ``weights`` cannot weight the eco reward, or None if they can."""
    if len(weights) != len(ECO_WEIGHT_NAMES):
        return f"needs {len(ECO_WEIGHT_NAMES)} weights ({', '.join(ECO_WEIGHT_NAMES)}), got {len(weights)}"
    if any(not np.isfinite(w) or w < 0.0 for w in weights) or weights[0] <= 0.0:
        return f"weights must be finite and >= 0, the gap's > 0; got {weights}"
    return None


class EcoTerms(NamedTuple):
    """The eco reward's four terms at one step, unweighted (see :func:`eco_terms`)."""

    gap: float  # raw Table 1 gap term around eco_desired_gap(v), in [-10, 10]
    energy: float  # energy_term, in [-1, 1]
    comfort: float  # comfort_term, in [0, 1]
    closing: float  # closing_term, in [0, 1]; 0 without the lead's speed


def eco_terms(
    gap: float, *, v: float, a: float, a_prev: float, v_lead: float | None = None, scenario: str = "ice", regen: bool = True,
) -> EcoTerms:
    """The eco reward's terms, unweighted and unsigned, for a gap [m], the host's speed
    ``v`` [m/s] and accelerations ``a``, ``a_prev`` [m/s^2], the lead's speed ``v_lead``
    [m/s] (None: no closing term) and the host of ``scenario`` ("ice" or "ev"); ``regen``
    False: the EV's energy term counts the power drawn only (``eco-draw``).

    The one place they are computed: the eco reward, its named terms and
    ``scripts/reward_ablation.py`` (which scores run logs where no env runs) all read them.
    """
    return EcoTerms(
        gap=gap_term(gap, eco_desired_gap(v)),
        energy=energy_term(v, a, scenario, regen),
        comfort=comfort_term(a, a_prev),
        closing=0.0 if v_lead is None else closing_term(v, v_lead),
    )


def gap_reward(gap: float, u: float, **_: Any) -> float:
    """Gap-based DDQN reward in [-1, 1]; ignores the force."""
    return gap_term(gap) / 10.0


def force_reward(gap: float, u: float, **_: Any) -> float:
    """Force-based DDQN reward in [-1, 1]: gap and force terms together."""
    return (gap_term(gap) + force_term(u)) / 20.0


def eco_reward(
    gap: float, u: float, *, v: float, a: float, a_prev: float, v_lead: float | None = None, scenario: str = "ice",
    weights: tuple[float, ...] = ECO_WEIGHTS, regen: bool = True, **_: Any,
) -> float:
    """Eco reward in [-1, 1]: gap term, minus energy, jerk and closing speed (see the module
    docstring). Without ``v_lead`` the closing term is 0; ``regen`` as :func:`eco_terms`."""
    w_gap, w_energy, w_comfort, w_closing = weights
    t = eco_terms(gap, v=v, a=a, a_prev=a_prev, v_lead=v_lead, scenario=scenario, regen=regen)
    # This expression, in this order, is the reward trained models were paid: keep it bit for bit.
    total = w_gap * t.gap / 10.0 - w_energy * t.energy - w_comfort * t.comfort - w_closing * t.closing
    return total / sum(weights)


def gap_reward_terms(gap: float, u: float, **_: Any) -> dict[str, float]:
    """:func:`gap_reward` by term, weighted: {"gap"}."""
    return {"gap": gap_term(gap) / 10.0}


def force_reward_terms(gap: float, u: float, **_: Any) -> dict[str, float]:
    """:func:`force_reward` by term, weighted: {"gap", "force"}; their sum is the reward."""
    return {"gap": gap_term(gap) / 20.0, "force": force_term(u) / 20.0}


def eco_reward_terms(
    gap: float, u: float, *, v: float, a: float, a_prev: float, v_lead: float | None = None, scenario: str = "ice",
    weights: tuple[float, ...] = ECO_WEIGHTS, regen: bool = True, **_: Any,
) -> dict[str, float]:
    """:func:`eco_reward` by term (:data:`ECO_WEIGHT_NAMES`), each signed, weighted and
    over the weights' sum; their sum is the reward."""
    t = eco_terms(gap, v=v, a=a, a_prev=a_prev, v_lead=v_lead, scenario=scenario, regen=regen)
    signed = (t.gap / 10.0, -t.energy, -t.comfort, -t.closing)
    total = sum(weights)
    return {name: w * x / total for name, w, x in zip(ECO_WEIGHT_NAMES, weights, signed, strict=True)}


# eco-draw: the EV earns nothing while it regenerates, since a discounted return (gamma 0.99,
# ~10 s) values a regenerating brake now over the acceleration it forces later. Tested on the EV
# actor-critic: it drifted as far as on "eco" (docs/training.md). The ICE's term is eco's.
REWARDS: dict[str, Callable[..., float]] = {"gap": gap_reward, "force": force_reward, "eco": eco_reward,
                                            "eco-draw": partial(eco_reward, regen=False)}  # fmt: skip
REWARD_TERMS: dict[str, Callable[..., dict[str, float]]] = {
    "gap": gap_reward_terms, "force": force_reward_terms, "eco": eco_reward_terms, "eco-draw": partial(eco_reward_terms, regen=False),
}  # fmt: skip
ECO_REWARDS = ("eco", "eco-draw")  # weighted by eco_weights
assert REWARD_TERMS.keys() == REWARDS.keys()


def _bind(table: dict[str, Callable[..., Any]], name: str, scenario: str, eco_weights: tuple[float, ...]) -> Callable[..., Any]:
    """``table[name]``, the eco entry bound to ``scenario`` and checked ``eco_weights``.

    Raises:
        ValueError: an unknown name, or eco weights :func:`check_eco_weights` refuses.
    """
    if name not in table:
        raise ValueError(f"reward {name!r} is not one of {sorted(table)}")
    fn = table[name]
    if name not in ECO_REWARDS:
        return fn
    weights = tuple(float(w) for w in eco_weights)
    if (why := check_eco_weights(weights)) is not None:
        raise ValueError(f"eco weights: {why}")
    return lambda gap, u, **kw: fn(gap, u, scenario=scenario, weights=weights, **kw)


def make_reward(name: str, scenario: str, eco_weights: tuple[float, ...] = ECO_WEIGHTS) -> Callable[..., float]:
    """The reward function ``name`` for the host of ``scenario`` ("ice" or "ev"); the eco
    reward weighted by ``eco_weights`` (gap, energy, comfort, closing).

    Raises:
        ValueError: an unknown name, or bad eco weights.
    """
    return _bind(REWARDS, name, scenario, eco_weights)


def make_reward_terms(name: str, scenario: str, eco_weights: tuple[float, ...] = ECO_WEIGHTS) -> Callable[..., dict[str, float]]:
    """The twin of :func:`make_reward`: the same arguments, the reward's weighted terms by name.

    Raises:
        ValueError: an unknown name, or bad eco weights.
    """
    return _bind(REWARD_TERMS, name, scenario, eco_weights)
