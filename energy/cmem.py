"""CMEM, the Comprehensive Modal Emissions Model, for light-duty ICE vehicles.

Sources: Barth et al., NCHRP Project 25-11 final report (2000); An, Barth, Norbeck
& Ross, TRR 1587 (1997); Scora & Barth, CMEM v3.01 User's Guide (2006). The
structure, per time step (SI inside; power in kW and fuel in g/s as in CMEM):

1. tractive power ``P_tract = (A v + B v^2 + C v^3 + M v (a + g sin(theta))) / 1000``;
2. engine power ``P = P_tract / eta_tf + P_acc`` when ``P_tract >= 0``; when
   ``P_tract < 0`` the wheels drive the engine (``P = max(P_tract eta_tf + P_acc, 0)``)
   and, for a vehicle with deceleration fuel cut-off, the fuel is cut;
3. engine speed ``N = S (R(L)/R(L_top)) v`` from a speed-based shift schedule
   with kick-down under high load, floored at idle;
4. fuel rate ``FR = phi (k N V + P/eta (1 + b1 (N - N0)^2)) / 43.2`` with
   ``k = k0 (1 + C (N - N0))`` and ``N0 = 30 sqrt(3.0/V)``;
5. enrichment ``phi``: 1 below a torque threshold, rising linearly to ``phi_wot`` at
   wide-open throttle (NCHRP 25-11 eq. 9, with a flat-torque WOT curve);
6. engine-out CO, HC, NOx; 7. catalyst pass fractions; tailpipe = engine-out x CPF;
8. CO2 by carbon balance ``44 (FR/13.85 - CO/28 - HC/13.85)`` on tailpipe CO and HC.

Two parameter sets ship. :data:`COROLLA_2022` is built on one named car's EPA test
data and calibrated (``scripts/calibrate_cmem.py``). :data:`AVERAGE_PAPER_ERA` is
the paper-era "average" category (NCHRP 25-11 Table 4.4 as given in the project
notes, a Tier-1 light-duty truck, unverified) for comparing magnitudes with the
paper's Table 3; its body is assumed.

Per-mile figures of a trace (:func:`per_mile`) are sums over its intervals
(:func:`interval_totals`, which the segments of a long run log add up) over its distance
(:func:`totals_per_mile`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from energy import units
from energy._data import read_params
from energy.trace import intervals, positive_distance

LHV_KJ_PER_G = 43.2  # [kJ/g] lower heating value of gasoline, as in CMEM
G_PER_MOL_FUEL_C = 13.85  # [g/mol C] gasoline as CH1.85
G_PER_MOL_CO = 28.0  # [g/mol]
G_PER_MOL_CO2 = 44.0  # [g/mol]

CALIBRATION_FILE = "corolla_cmem_calibration.csv"


@dataclass(frozen=True)
class CmemVehicle:
    """CMEM parameters of one vehicle. Units are in each field's docstring."""

    name: str
    """Short id, e.g. ``"corolla"``."""
    description: str
    """What the set represents and where its numbers come from."""
    mass_kg: float
    """Test mass M [kg] (EPA equivalent test weight where known)."""
    road_load_a_n: float
    """Road-load A [N]."""
    road_load_b_n_per_mps: float
    """Road-load B [N/(m/s)]."""
    road_load_c_n_per_mps2: float
    """Road-load C [N/(m/s)^2]."""
    displacement_l: float
    """Engine displacement V [L]."""
    nv_ratio_rpm_per_mph: float
    """S, engine speed per vehicle speed in top gear [rpm/mph] (EPA "N/V")."""
    gear_ratios: tuple[float, ...]
    """Transmission ratios R(L), first to top gear [-]."""
    upshift_speeds_mps: tuple[float, ...]
    """Speed above which gear L+1 is used, one per upshift [m/s]."""
    idle_speed_rpm: float
    """Idle engine speed [rpm]; the floor of N."""
    rated_power_kw: float
    """Rated engine power [kW]."""
    rated_speed_rpm: float
    """Engine speed at rated power [rpm]."""
    k0: float
    """Engine friction factor k0 [kJ/(rev L)]."""
    indicated_efficiency: float
    """Indicated efficiency eta [-]."""
    k_speed_coeff: float = 0.00125
    """C in k = k0 (1 + C (N - N0)) [s/rev]."""
    high_speed_loss_b1: float = 1e-4
    """b1 in the loss factor (1 + b1 (N - N0)^2) on P/eta [s^2/rev^2]."""
    drivetrain_efficiency: float = 0.9
    """eta_tf [-]."""
    accessory_power_kw: float = 0.75
    """P_acc [kW]."""
    phi_wot: float = 1.1854
    """Fuel/air equivalence ratio at wide-open throttle [-]."""
    enrichment_torque_fraction: float = 0.9
    """Share of WOT torque above which the mixture is enriched [-] (assumed)."""
    fuel_cut: bool = False
    """Deceleration fuel cut-off: no fuel while the wheels drive the engine."""
    fuel_cut_min_speed_mps: float = 4.0
    """Below this speed the engine idles instead of cutting fuel [m/s]."""
    c_co: float = 3.6
    """C_CO, engine-out CO per unit of (1 - 1/phi) [g CO/g fuel]."""
    a_co: float = 0.1354
    """a_CO, stoichiometric engine-out CO index [g CO/g fuel]."""
    a_hc: float = 0.0148
    """a_HC, engine-out HC index [g HC/g fuel]."""
    r_hc: float = 0.0023
    """r_HC, residual engine-out HC [g/s]."""
    a_nox: float = 0.0293
    """a_NOx, engine-out NOx index [g NOx/g fuel]."""
    fr_nox_threshold_g_s: float = 0.25
    """FR_NOx, fuel rate below which engine-out NOx is 0 [g/s] (assumed)."""
    gamma_co: float = 0.840
    """Catalyst CO parameter gamma [-]."""
    gamma_hc: float = 0.839
    """Catalyst HC parameter gamma [-]."""
    gamma_nox: float = 0.687
    """Catalyst NOx maximum efficiency gamma [-]."""
    b_co: float = 0.1927
    """Catalyst CO b [s/g]."""
    b_hc: float = 0.1165
    """Catalyst HC b [s/g]."""
    b_nox: float = 2.9562
    """Catalyst NOx b [s/g NOx]."""
    c_co_cat: float = 4.6196
    """Catalyst CO c [s/g]."""
    c_hc_cat: float = 2.4246
    """Catalyst HC c [s/g]."""
    c_nox_cat: float = 2.0419
    """Catalyst NOx c [-]."""

    def __post_init__(self) -> None:
        if len(self.upshift_speeds_mps) != len(self.gear_ratios) - 1:
            raise ValueError("need one upshift speed per gear change")
        if not 0 < self.indicated_efficiency < 1 or self.k0 <= 0:
            raise ValueError(f"unphysical k0={self.k0} or eta={self.indicated_efficiency}")

    @property
    def n0_rps(self) -> float:
        """N0 = 30 sqrt(3.0/V) [rev/s], the speed where k = k0."""
        return float(30.0 * np.sqrt(3.0 / self.displacement_l))


@dataclass(frozen=True)
class CmemRates:
    """Per-step CMEM outputs; every array has the shape of the inputs."""

    fuel_g_s: np.ndarray
    """Fuel rate [g/s]."""
    co2_g_s: np.ndarray
    """Tailpipe CO2 [g/s]."""
    co_g_s: np.ndarray
    """Tailpipe CO [g/s]."""
    hc_g_s: np.ndarray
    """Tailpipe HC [g/s]."""
    nox_g_s: np.ndarray
    """Tailpipe NOx [g/s]."""
    engine_out_co_g_s: np.ndarray
    """Engine-out CO [g/s]."""
    engine_out_hc_g_s: np.ndarray
    """Engine-out HC [g/s]."""
    engine_out_nox_g_s: np.ndarray
    """Engine-out NOx [g/s]."""
    tractive_power_kw: np.ndarray
    """P_tract [kW]."""
    engine_power_kw: np.ndarray
    """P [kW]."""
    engine_speed_rps: np.ndarray
    """N [rev/s]."""
    phi: np.ndarray
    """Fuel/air equivalence ratio [-]."""


@dataclass(frozen=True)
class CmemResult:
    """Per-mile CMEM figures of a trace (g/mi at the reporting edge)."""

    vehicle: str
    distance_mi: float
    duration_s: float
    fuel_g_per_mi: float
    co2_g_per_mi: float
    co_g_per_mi: float
    hc_g_per_mi: float
    nox_g_per_mi: float

    @property
    def mpg(self) -> float:
        """Fuel economy from CO2 with EPA's 8887 g CO2/gal [mi/gal]."""
        return units.mpg_from_co2_g_per_mi(self.co2_g_per_mi)

    def as_dict(self) -> dict[str, float | str]:
        """Fields plus ``mpg`` as a flat dict."""
        return {**asdict(self), "mpg": self.mpg}


def tractive_power_kw(
    v: np.ndarray, a: np.ndarray, vehicle: CmemVehicle, grade_rad: float = 0.0
) -> np.ndarray:
    """Tractive power at the wheels [kW] for speed v [m/s] and acceleration a [m/s^2]."""
    v = np.asarray(v, dtype=float)
    a = np.asarray(a, dtype=float)
    road = (
        vehicle.road_load_a_n * v
        + vehicle.road_load_b_n_per_mps * v**2
        + vehicle.road_load_c_n_per_mps2 * v**3
    )
    return (road + vehicle.mass_kg * v * (a + units.GRAVITY * np.sin(grade_rad))) / 1000.0


def wot_power_kw(n_rps: np.ndarray, vehicle: CmemVehicle) -> np.ndarray:
    """Wide-open-throttle power [kW] at engine speed N [rev/s], for a flat torque curve."""
    return np.minimum(
        vehicle.rated_power_kw * n_rps / (vehicle.rated_speed_rpm / 60.0), vehicle.rated_power_kw
    )


def engine_speed_rps(
    v: np.ndarray, vehicle: CmemVehicle, engine_power_kw: np.ndarray | None = None
) -> np.ndarray:
    """Engine speed N [rev/s] from the shift schedule, floored at idle.

    The gear is the speed schedule's, except that with ``engine_power_kw`` given the
    driver shifts down (kick-down, never above rated speed) to the highest gear whose
    WOT power leaves the demand below the enrichment threshold, or else to the gear
    with the most power. Without kick-down a hard pull in top gear would sit at
    wide-open throttle far below rated speed, which no driver or gearbox does.
    """
    v = np.asarray(v, dtype=float)
    sched = np.searchsorted(np.asarray(vehicle.upshift_speeds_mps), v, side="right")  # [n]
    ratio = np.asarray(vehicle.gear_ratios) / vehicle.gear_ratios[-1]  # [G]
    rpm = vehicle.nv_ratio_rpm_per_mph * ratio[None, :] * units.mps_to_mph(v)[..., None]  # [n, G]
    n_g = np.maximum(rpm, vehicle.idle_speed_rpm) / 60.0  # [n, G]
    rows = np.arange(v.size).reshape(v.shape)
    if engine_power_kw is None:
        return n_g[rows, sched]
    gears = np.arange(ratio.size)
    ok = (gears <= sched[..., None]) & (n_g <= vehicle.rated_speed_rpm / 60.0)  # [n, G]
    ok[rows, sched] = True
    p_wot = wot_power_kw(n_g, vehicle)
    fits = ok & (
        np.asarray(engine_power_kw)[..., None] <= vehicle.enrichment_torque_fraction * p_wot
    )
    highest_fit = ratio.size - 1 - np.argmax(fits[..., ::-1], axis=-1)
    most_power = np.argmax(np.where(ok, p_wot, -np.inf), axis=-1)
    gear = np.where(fits.any(axis=-1), highest_fit, most_power)
    return n_g[rows, gear]


def cmem_rates(
    v: np.ndarray, a: np.ndarray, vehicle: CmemVehicle, grade_rad: float = 0.0
) -> CmemRates:
    """Fuel and tailpipe emission rates for each (speed, acceleration) pair.

    Args:
        v: speed [m/s], >= 0.
        a: acceleration [m/s^2].
        vehicle: the parameter set.
        grade_rad: road grade [rad].

    Returns:
        The rates, arrays shaped like ``v``.
    """
    veh = vehicle
    v = np.asarray(v, dtype=float)
    a = np.broadcast_to(np.asarray(a, dtype=float), v.shape)
    p_tract = tractive_power_kw(v, a, veh, grade_rad)
    driving = p_tract >= 0.0
    p_eng = np.where(
        driving,
        p_tract / veh.drivetrain_efficiency + veh.accessory_power_kw,
        np.maximum(p_tract * veh.drivetrain_efficiency + veh.accessory_power_kw, 0.0),
    )
    n = engine_speed_rps(v, veh, p_eng)
    n0 = veh.n0_rps

    # Enrichment against a flat WOT torque curve (NCHRP 25-11 eq. 9 with a simple Q_wot).
    p_wot = wot_power_kw(n, veh)
    p_th = veh.enrichment_torque_fraction * p_wot
    enr = np.clip((p_eng - p_th) / (p_wot - p_th), 0.0, 1.0)
    phi = 1.0 + (veh.phi_wot - 1.0) * enr

    k = veh.k0 * (1.0 + veh.k_speed_coeff * (n - n0))
    loss = 1.0 + veh.high_speed_loss_b1 * (n - n0) ** 2
    fuel = (
        phi * (k * n * veh.displacement_l + p_eng / veh.indicated_efficiency * loss) / LHV_KJ_PER_G
    )
    if veh.fuel_cut:
        fuel = np.where(~driving & (v > veh.fuel_cut_min_speed_mps), 0.0, fuel)
    fuel = np.maximum(fuel, 0.0)

    rich = 1.0 - 1.0 / phi
    eo_co = (veh.c_co * rich + veh.a_co) * fuel
    eo_hc = veh.a_hc * fuel + veh.r_hc
    eo_nox = veh.a_nox * np.maximum(fuel - veh.fr_nox_threshold_g_s, 0.0)
    cpf_co = 1.0 - veh.gamma_co * np.exp((-veh.b_co - veh.c_co_cat * rich) * fuel)
    cpf_hc = 1.0 - veh.gamma_hc * np.exp((-veh.b_hc - veh.c_hc_cat * rich) * fuel)
    # NOx conversion improves when rich; the form follows the open CMEM port and is uncertain.
    eff_nox = veh.gamma_nox * (1.0 - veh.b_nox * (1.0 - veh.c_nox_cat * rich) * eo_nox)
    cpf_nox = 1.0 - np.clip(eff_nox, 0.0, 1.0)
    co = eo_co * np.clip(cpf_co, 0.0, 1.0)
    hc = eo_hc * np.clip(cpf_hc, 0.0, 1.0)
    nox = eo_nox * cpf_nox
    co2 = G_PER_MOL_CO2 * (fuel / G_PER_MOL_FUEL_C - co / G_PER_MOL_CO - hc / G_PER_MOL_FUEL_C)
    return CmemRates(
        fuel_g_s=fuel,
        co2_g_s=np.maximum(co2, 0.0),
        co_g_s=co,
        hc_g_s=hc,
        nox_g_s=nox,
        engine_out_co_g_s=eo_co,
        engine_out_hc_g_s=eo_hc,
        engine_out_nox_g_s=eo_nox,
        tractive_power_kw=p_tract,
        engine_power_kw=p_eng,
        engine_speed_rps=n,
        phi=phi,
    )


@dataclass(frozen=True)
class CmemTotals:
    """Sums over the intervals of a trace, which the segments of a long trace add up (in
    order) before :func:`totals_per_mile` divides them by the distance."""

    distance_m: float
    """Distance [m]."""
    duration_s: float
    """Duration [s]."""
    fuel_g: float
    """Fuel [g]."""
    co2_g: float
    """Tailpipe CO2 [g]."""
    co_g: float
    """Tailpipe CO [g]."""
    hc_g: float
    """Tailpipe HC [g]."""
    nox_g: float
    """Tailpipe NOx [g]."""

    def __add__(self, other: CmemTotals) -> CmemTotals:
        return CmemTotals(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))


def interval_totals(t: np.ndarray, v: np.ndarray, vehicle: CmemVehicle) -> CmemTotals:
    """Fuel and tailpipe emissions summed over the intervals of a speed trace.

    Each interval between samples is evaluated at its mean speed and its constant
    acceleration, then integrated over its duration.

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], >= 0.
        vehicle: the parameter set.

    Raises:
        TraceError: bad trace (NaN, negative speed, time not increasing).
    """
    iv = intervals(t, v)
    r = cmem_rates(iv.v, iv.a, vehicle)
    return CmemTotals(
        distance_m=np.sum(iv.v * iv.dt),
        duration_s=np.sum(iv.dt),
        fuel_g=np.sum(r.fuel_g_s * iv.dt),
        co2_g=np.sum(r.co2_g_s * iv.dt),
        co_g=np.sum(r.co_g_s * iv.dt),
        hc_g=np.sum(r.hc_g_s * iv.dt),
        nox_g=np.sum(r.nox_g_s * iv.dt),
    )


def totals_per_mile(totals: CmemTotals, vehicle_name: str) -> CmemResult:
    """The per-mile figures of a trace's :class:`CmemTotals`.

    Raises:
        TraceError: the trace covers no distance.
    """
    miles = units.m_to_mi(positive_distance(float(totals.distance_m)))
    return CmemResult(
        vehicle=vehicle_name,
        distance_mi=miles,
        duration_s=float(totals.duration_s),
        fuel_g_per_mi=float(totals.fuel_g) / miles,
        co2_g_per_mi=float(totals.co2_g) / miles,
        co_g_per_mi=float(totals.co_g) / miles,
        hc_g_per_mi=float(totals.hc_g) / miles,
        nox_g_per_mi=float(totals.nox_g) / miles,
    )


def per_mile(t: np.ndarray, v: np.ndarray, vehicle: CmemVehicle) -> CmemResult:
    """Fuel and tailpipe emissions per mile over a speed trace (:func:`interval_totals`
    over the distance).

    Args:
        t: sample times [s], strictly increasing.
        v: speeds [m/s], >= 0.
        vehicle: the parameter set.

    Raises:
        TraceError: bad trace (NaN, negative speed, time not increasing) or zero distance.
    """
    return totals_per_mile(interval_totals(t, v, vehicle), vehicle.name)


# --- 2022 Toyota Corolla 1.987 L, 6-speed manual -------------------------------------
# EPA 2022 test car list (energy/data/epa_2022_test_cars_subset.csv), test LTYX10055779.
_COROLLA_A_N, _COROLLA_B, _COROLLA_C = units.road_load_to_si(27.071, 0.26485, 0.017466)
_COROLLA_GEARS = (
    3.166,
    1.904,
    1.392,
    1.031,
    0.815,
    0.725,
)  # typical 6MT ratios (assumed; top fits N/V)
_COROLLA_UPSHIFT_MPH = (15.0, 25.0, 35.0, 43.0, 50.0)  # [mph] assumed manual shift schedule

COROLLA_2022_UNCALIBRATED = CmemVehicle(
    name="corolla",
    description=(
        "2022 Toyota Corolla 1.987 L 6-speed manual, Tier-2-cert gasoline. Body from the EPA 2022 "
        "test car list: ETW 3375 lb, target coefficients A 27.071 lbf, B 0.26485 lbf/mph, "
        "C 0.017466 lbf/mph^2, N/V 37.3, 169 hp. Gear ratios and shift speeds assumed. Engine-out "
        "emission indices from the NCHRP 25-11 average set; k0, eta and the catalyst gammas are "
        "calibrated to the car's measured HWFET (scripts/calibrate_cmem.py). Catalyst b set to 0: "
        "a modern warm catalyst does not lose efficiency with flow at these loads."
    ),
    mass_kg=units.lb_to_kg(3375.0),
    road_load_a_n=_COROLLA_A_N,
    road_load_b_n_per_mps=_COROLLA_B,
    road_load_c_n_per_mps2=_COROLLA_C,
    displacement_l=1.987,
    nv_ratio_rpm_per_mph=37.3,
    gear_ratios=_COROLLA_GEARS,
    upshift_speeds_mps=tuple(units.mph_to_mps(s) for s in _COROLLA_UPSHIFT_MPH),
    idle_speed_rpm=700.0,
    rated_power_kw=169.0 * 0.745699872,
    rated_speed_rpm=6600.0,
    k0=0.215,
    indicated_efficiency=0.40,
    fuel_cut=True,
    b_co=0.0,
    b_hc=0.0,
    b_nox=0.0,
)
"""The Corolla before calibration (NCHRP k0, eta = 0.40); the scripts start from it."""


def _calibrated_corolla() -> CmemVehicle:
    p = read_params(CALIBRATION_FILE)
    return replace(
        COROLLA_2022_UNCALIBRATED,
        k0=p["k0"],
        indicated_efficiency=p["indicated_efficiency"],
        gamma_co=p["gamma_co"],
        gamma_hc=p["gamma_hc"],
        gamma_nox=p["gamma_nox"],
    )


COROLLA_2022 = _calibrated_corolla()
"""2022 Toyota Corolla, calibrated to its EPA HWFET test (see the uncalibrated set's
description and ``energy/data/corolla_cmem_calibration.csv``)."""

# --- Paper-era "average" category -------------------------------------------------------
AVERAGE_PAPER_ERA = CmemVehicle(
    name="average",
    description=(
        "Paper-era CMEM 'average' category: engine and catalyst parameters labelled NCHRP 25-11 "
        "Table 4.4 in the project notes, a Tier-1 light-duty truck (unverified), used uncalibrated "
        "(k0 0.215, eta 0.45, V 3.42 L). Body, gearing, power and FR_NOx are assumed for a 1990s "
        "LDT: ETW 4250 lb, C_r 0.011, C_d A 1.18 m^2, 4-speed automatic, N/V 32. No fuel cut. "
        "Use it to compare magnitudes with the paper's Table 3, not as a real vehicle."
    ),
    mass_kg=units.lb_to_kg(4250.0),
    road_load_a_n=0.011 * units.lb_to_kg(4250.0) * units.GRAVITY,
    road_load_b_n_per_mps=0.0,
    road_load_c_n_per_mps2=0.5 * 1.2 * 1.18,
    displacement_l=3.42,
    nv_ratio_rpm_per_mph=32.0,
    gear_ratios=(2.80, 1.55, 1.00, 0.70),
    upshift_speeds_mps=tuple(units.mph_to_mps(s) for s in (15.0, 25.0, 40.0)),
    idle_speed_rpm=750.0,
    rated_power_kw=120.0,
    rated_speed_rpm=4800.0,
    k0=0.215,
    indicated_efficiency=0.45,
)
"""Paper-era "average" category (see its description)."""

VEHICLES: dict[str, CmemVehicle] = {v.name: v for v in (COROLLA_2022, AVERAGE_PAPER_ERA)}
"""The shipped ICE parameter sets by name."""
