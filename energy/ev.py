"""EV energy: the VT-CPEM physics model of the Nissan Leaf and the paper's eq. 6.

VT-CPEM (Fiori, Ahn & Rakha, "Power-based electric vehicle energy consumption
model", Applied Energy 168 (2016) 257-268) gives the battery power of a 2011-12
Nissan Leaf from speed and acceleration, with regenerative braking:

* wheel power ``P_w = (m a + m g (C_r/1000)(c1 v_kmh + c2) + rho A_f C_d v^2 / 2) v``;
* traction (``P_w >= 0``): ``P_bat = P_w / (eta_dl eta_em) + P_aux``;
* braking (``P_w < 0``): ``P_bat = P_w eta_dl eta_em eta_rb + P_aux`` with
  ``eta_rb = exp(-0.0411/|a|)`` when decelerating, else 0.

The paper (Wei et al. 2019, eq. 6) uses the UCR "Type II" energy rate model
``P = l0 + l1 v + l2 v^3 + l3 v a + l4 v^2 + l5 v^4 + l6 v^2 a + l7 v^3 a + l8 v a^2``
[kW] with coefficients from Qi et al. 2018, which are not public. The coefficients
shipped here (``energy/data/leaf_eq6_fit.csv``) are a least-squares FIT TO VT-CPEM
over the EPA cycles, made by ``scripts/fit_ev_model.py``. They are not the UCR values.
Regeneration is counted as negative energy in both models.

Per-mile figures of a trace are sums over its intervals (:func:`vtcpem_totals`,
:func:`eq6_totals`, which the segments of a long run log add up) over its distance
(:func:`totals_per_mile`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, fields

import numpy as np

from energy import units
from energy._data import read_params
from energy.trace import intervals, positive_distance

EQ6_FIT_FILE = "leaf_eq6_fit.csv"
VTCPEM = "vt-cpem"
"""The model name of VT-CPEM's results."""
EQ6 = "eq6-fit-to-vt-cpem"
"""The model name of eq. 6's results (coefficients fitted to VT-CPEM)."""
EQ6_TERMS = ("l0", "l1", "l2", "l3", "l4", "l5", "l6", "l7", "l8")
"""Coefficient names of eq. 6, in order."""


@dataclass(frozen=True)
class LeafVtCpem:
    """VT-CPEM parameters of the Nissan Leaf (Fiori et al. 2016)."""

    mass_kg: float = 1521.0
    """Vehicle mass m [kg]."""
    air_density_kg_m3: float = 1.2256
    """rho [kg/m^3]."""
    frontal_area_m2: float = 2.3316
    """A_f [m^2]."""
    drag_coefficient: float = 0.28
    """C_d [-]."""
    rolling_cr: float = 1.75
    """C_r [-], rolling resistance constant (divided by 1000 in the force)."""
    rolling_c1: float = 0.0328
    """c1 [1/(km/h)]."""
    rolling_c2: float = 4.575
    """c2 [-]."""
    driveline_efficiency: float = 0.92
    """eta_dl [-]."""
    motor_efficiency: float = 0.91
    """eta_em [-]."""
    regen_alpha: float = 0.0411
    """alpha in eta_rb = exp(-alpha/|a|) [m/s^2]."""
    aux_power_w: float = 700.0
    """P_aux [W]; the paper gives 700 W in one version and 1500 W in another; 700 W here."""


LEAF = LeafVtCpem()
"""The Nissan Leaf as published in VT-CPEM, with 700 W auxiliaries."""


@dataclass(frozen=True)
class EvResult:
    """Per-mile battery energy of a trace; regeneration counts as negative."""

    model: str
    distance_mi: float
    duration_s: float
    energy_kj_per_mi: float
    """Net battery energy [kJ/mi]."""
    regen_kj_per_mi: float
    """Energy into the battery while it charges (net power < 0) [kJ/mi], >= 0; already
    subtracted in the net."""

    @property
    def energy_wh_per_mi(self) -> float:
        """Net battery energy [Wh/mi]."""
        return units.kj_to_wh(self.energy_kj_per_mi)

    def as_dict(self) -> dict[str, float | str]:
        """Fields plus ``energy_wh_per_mi`` as a flat dict."""
        return {**asdict(self), "energy_wh_per_mi": self.energy_wh_per_mi}


def vtcpem_power_w(
    v: np.ndarray, a: np.ndarray, leaf: LeafVtCpem = LEAF, grade_rad: float = 0.0
) -> np.ndarray:
    """Battery power [W] (negative while regenerating).

    Args:
        v: speed [m/s].
        a: acceleration [m/s^2].
        leaf: model parameters.
        grade_rad: road grade [rad].
    """
    v = np.asarray(v, dtype=float)
    a = np.broadcast_to(np.asarray(a, dtype=float), v.shape)
    m = leaf.mass_kg
    f_roll = (
        m
        * units.GRAVITY
        * np.cos(grade_rad)
        * (leaf.rolling_cr / 1000.0)
        * (leaf.rolling_c1 * units.mps_to_kmh(v) + leaf.rolling_c2)
    )
    f_aero = 0.5 * leaf.air_density_kg_m3 * leaf.frontal_area_m2 * leaf.drag_coefficient * v**2
    p_wheel = (m * a + m * units.GRAVITY * np.sin(grade_rad) + f_roll + f_aero) * v
    eta = leaf.driveline_efficiency * leaf.motor_efficiency
    with np.errstate(divide="ignore"):
        eta_rb = np.where(a < 0.0, np.exp(-leaf.regen_alpha / np.abs(a)), 0.0)
    p_motor = np.where(p_wheel >= 0.0, p_wheel / eta, p_wheel * eta * eta_rb)
    return p_motor + leaf.aux_power_w


def eq6_design(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The nine eq. 6 regressors [1, v, v^3, v a, v^2, v^4, v^2 a, v^3 a, v a^2], shape [n, 9]."""
    v = np.asarray(v, dtype=float)
    a = np.broadcast_to(np.asarray(a, dtype=float), v.shape)
    return np.stack(
        [np.ones_like(v), v, v**3, v * a, v**2, v**4, v**2 * a, v**3 * a, v * a**2], axis=-1
    )


def load_eq6_coefficients() -> np.ndarray:
    """The shipped eq. 6 coefficients l0..l8 [kW with v in m/s, a in m/s^2], a fit to VT-CPEM."""
    p = read_params(EQ6_FIT_FILE)
    return np.array([p[k] for k in EQ6_TERMS])


EQ6_COEFFICIENTS = load_eq6_coefficients()
"""l0..l8 fitted to VT-CPEM by ``scripts/fit_ev_model.py`` (not the UCR values)."""


def eq6_power_kw(
    v: np.ndarray, a: np.ndarray, coefficients: np.ndarray | None = None
) -> np.ndarray:
    """Battery power by the paper's eq. 6 [kW].

    Args:
        v: speed [m/s].
        a: acceleration [m/s^2].
        coefficients: l0..l8; defaults to the shipped fit to VT-CPEM.
    """
    coef = EQ6_COEFFICIENTS if coefficients is None else np.asarray(coefficients, dtype=float)
    return eq6_design(v, a) @ coef


@dataclass(frozen=True)
class EvTotals:
    """Sums over the intervals of a trace, which the segments of a long trace add up (in
    order) before :func:`totals_per_mile` divides them by the distance."""

    distance_m: float
    """Distance [m]."""
    duration_s: float
    """Duration [s]."""
    energy_j: float
    """Net battery energy [J]."""
    charge_j: float
    """Energy of the intervals that charge the battery [J], <= 0."""

    def __add__(self, other: EvTotals) -> EvTotals:
        return EvTotals(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))


def _totals(
    t: np.ndarray, v: np.ndarray, power_w_fn: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> EvTotals:
    iv = intervals(t, v)
    e_j = power_w_fn(iv.v, iv.a) * iv.dt
    return EvTotals(
        distance_m=np.sum(iv.v * iv.dt),
        duration_s=np.sum(iv.dt),
        energy_j=np.sum(e_j),
        charge_j=np.sum(np.minimum(e_j, 0.0)),
    )


def vtcpem_totals(t: np.ndarray, v: np.ndarray, leaf: LeafVtCpem = LEAF) -> EvTotals:
    """VT-CPEM battery energy summed over the intervals of a speed trace (each at its mean
    speed and constant acceleration).

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], >= 0.
        leaf: model parameters.

    Raises:
        TraceError: bad trace.
    """
    return _totals(t, v, lambda vv, aa: vtcpem_power_w(vv, aa, leaf))


def eq6_totals(t: np.ndarray, v: np.ndarray, coefficients: np.ndarray | None = None) -> EvTotals:
    """Eq. 6 battery energy summed over the intervals of a speed trace.

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], >= 0.
        coefficients: l0..l8; defaults to the shipped fit to VT-CPEM.

    Raises:
        TraceError: bad trace.
    """
    return _totals(t, v, lambda vv, aa: 1000.0 * eq6_power_kw(vv, aa, coefficients))


def totals_per_mile(model: str, totals: EvTotals) -> EvResult:
    """The per-mile figures of a trace's :class:`EvTotals` (``model``: :data:`VTCPEM` or
    :data:`EQ6`).

    Raises:
        TraceError: the trace covers no distance.
    """
    miles = units.m_to_mi(positive_distance(float(totals.distance_m)))
    return EvResult(
        model=model,
        distance_mi=miles,
        duration_s=float(totals.duration_s),
        energy_kj_per_mi=float(totals.energy_j) / units.J_PER_KJ / miles,
        regen_kj_per_mi=float(-totals.charge_j) / units.J_PER_KJ / miles,
    )


def vtcpem_per_mile(t: np.ndarray, v: np.ndarray, leaf: LeafVtCpem = LEAF) -> EvResult:
    """Net battery energy per mile by VT-CPEM over a speed trace.

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], >= 0.
        leaf: model parameters.

    Raises:
        TraceError: bad trace or zero distance.
    """
    return totals_per_mile(VTCPEM, vtcpem_totals(t, v, leaf))


def eq6_per_mile(t: np.ndarray, v: np.ndarray, coefficients: np.ndarray | None = None) -> EvResult:
    """Net battery energy per mile by eq. 6 over a speed trace.

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], >= 0.
        coefficients: l0..l8; defaults to the shipped fit to VT-CPEM.

    Raises:
        TraceError: bad trace or zero distance.
    """
    return totals_per_mile(EQ6, eq6_totals(t, v, coefficients))
