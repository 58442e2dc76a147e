"""Unit conversions. Everything inside :mod:`energy` is SI.

g/mi, kJ/mi, Wh/mi, mph, lbf and lb appear only at the edges: when reading EPA data
and when reporting.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

M_PER_MI = 1609.344  # [m/mi], exact
MPS_PER_MPH = 0.44704  # [(m/s)/mph], exact
N_PER_LBF = 4.4482216152605  # [N/lbf], exact
KG_PER_LB = 0.45359237  # [kg/lb], exact
J_PER_WH = 3600.0  # [J/Wh]
J_PER_KJ = 1000.0  # [J/kJ]
J_PER_KWH = 3.6e6  # [J/kWh]
KWH_PER_GALLON_EQUIVALENT = 33.7  # [kWh/gal], EPA MPGe definition
G_CO2_PER_GALLON = 8887.0  # [g/gal], EPA-420-F-11-041
GRAVITY = 9.81  # [m/s^2]

F = TypeVar("F", float, np.ndarray)


def mph_to_mps(mph: F) -> F:
    """Speed: mph -> m/s."""
    return mph * MPS_PER_MPH


def mps_to_mph(mps: F) -> F:
    """Speed: m/s -> mph."""
    return mps / MPS_PER_MPH


def mps_to_kmh(mps: F) -> F:
    """Speed: m/s -> km/h."""
    return mps * 3.6


def lbf_to_n(lbf: float) -> float:
    """Force: lbf -> N."""
    return lbf * N_PER_LBF


def lb_to_kg(lb: float) -> float:
    """Mass: lb -> kg."""
    return lb * KG_PER_LB


def road_load_to_si(
    a_lbf: float, b_lbf_per_mph: float, c_lbf_per_mph2: float
) -> tuple[float, float, float]:
    """EPA target coefficients -> SI road-load coefficients.

    Args:
        a_lbf: constant term [lbf].
        b_lbf_per_mph: linear term [lbf/mph].
        c_lbf_per_mph2: quadratic term [lbf/mph^2].

    Returns:
        (A [N], B [N/(m/s)], C [N/(m/s)^2]) such that F = A + B v + C v^2 with v in m/s.
    """
    return (
        a_lbf * N_PER_LBF,
        b_lbf_per_mph * N_PER_LBF / MPS_PER_MPH,
        c_lbf_per_mph2 * N_PER_LBF / MPS_PER_MPH**2,
    )


def m_to_mi(m: float) -> float:
    """Distance: m -> mi."""
    return m / M_PER_MI


def g_per_m_to_g_per_mi(g_per_m: float) -> float:
    """Specific mass: g/m -> g/mi."""
    return g_per_m * M_PER_MI


def j_per_m_to_kj_per_mi(j_per_m: float) -> float:
    """Specific energy: J/m -> kJ/mi."""
    return j_per_m * M_PER_MI / J_PER_KJ


def j_per_m_to_wh_per_mi(j_per_m: float) -> float:
    """Specific energy: J/m -> Wh/mi."""
    return j_per_m * M_PER_MI / J_PER_WH


def kj_to_wh(kj: float) -> float:
    """Energy: kJ -> Wh (1 Wh = 3.6 kJ)."""
    return kj * J_PER_KJ / J_PER_WH


def wh_per_mi_to_mpge(wh_per_mi: float) -> float:
    """EV consumption: Wh/mi -> MPGe (33.7 kWh per gallon equivalent)."""
    return KWH_PER_GALLON_EQUIVALENT * 1000.0 / wh_per_mi


def mpg_from_co2_g_per_mi(co2_g_per_mi: float) -> float:
    """Fuel economy from tailpipe CO2, with the EPA's 8887 g CO2 per gallon (inf for none:
    a short run spent braking or coasting burns nothing)."""
    return G_CO2_PER_GALLON / co2_g_per_mi if co2_g_per_mi > 0 else math.inf
