#!/usr/bin/env python
"""Calibrate the 2022 Toyota Corolla's CMEM parameters to its EPA tests.

The question: which fuel and catalyst parameters make the modelled car match what the EPA
measured of it, and how far is it then off on the cycles it was not fitted to?

Fits two fuel parameters and three catalyst parameters, then prints the result and
the model's figures on every shipped cycle. With ``--write`` it stores them in
``energy/data/corolla_cmem_calibration.csv``, which :mod:`energy.cmem` loads.

* k0 and eta (the fuel equation's friction and efficiency terms) are fitted to two
  hot-engine measurements of the car (tests LTYX10055779 / LTYX10055778 in
  ``energy/data/epa_2022_test_cars_subset.csv``): k0 makes the model's HWFET CO2
  equal the measured 164.6 g/mi; eta, searched within the physical range 0.40-0.45,
  minimises the error on the FTP's hot-stabilised bag 2 (UDDS from 505 s on). Bag 2
  is given only as fuel economy (37.3 mpg); it is turned into CO2 with the HWFET's
  own CO2 x mpg product (same fuel). CMEM models hot-stabilised operation, so the
  cold-start bag 1 is not used.
* The catalyst gammas for CO, HC and NOx are set so that the tailpipe HWFET g/mi
  equal the measured ones. With the catalyst b set to 0 the tailpipe total is linear
  in gamma, so each has a closed form.

Run: ``python scripts/calibrate_cmem.py [--write]``.
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import replace

import numpy as np

from energy import cmem, data_path, write_params
from energy.cycles import CYCLES, UDDS_BAG2_START_S, Cycle, load_cycle
from energy.trace import intervals

EPA_FILE = "epa_2022_test_cars_subset.csv"


def epa_targets() -> dict[str, float]:
    """Measured Corolla figures from the EPA rows (not the analytically derived ones)."""
    with data_path(EPA_FILE).open(newline="", encoding="utf-8-sig") as f:
        rows = [
            r
            for r in csv.DictReader(f)
            if r["Represented Test Veh Model"] == "COROLLA"
            and r["Analytically Derived FE?"] == "No"
        ]
    hwy = next(r for r in rows if r["Test Procedure Description"] == "HWFE")
    ftp = next(r for r in rows if r["Test Category"] == "FTP")
    co2_x_mpg = float(hwy["CO2 (g/mi)"]) * float(hwy["RND_ADJ_FE"])  # [g CO2/gal] of this test fuel
    return {
        "hwfet_co2": float(hwy["CO2 (g/mi)"]),
        "hwfet_co": float(hwy["CO (g/mi)"]),
        "hwfet_hc": float(hwy["THC (g/mi)"]),
        "hwfet_nox": float(hwy["NOx (g/mi)"]),
        "bag2_co2": co2_x_mpg / float(ftp["FE Bag 2"]),
        "bag3_co2": co2_x_mpg / float(ftp["FE Bag 3"]),
    }


ETA_RANGE = (0.40, 0.45)  # physical indicated efficiency of a gasoline engine (project notes)


def solve_k0(veh: cmem.CmemVehicle, target_co2: float, trace: Cycle) -> cmem.CmemVehicle:
    """Bisect k0 so that the CO2 per mile on ``trace`` equals ``target_co2`` (it rises with k0)."""
    lo, hi = 1e-4, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        co2 = cmem.per_mile(trace.t, trace.v, replace(veh, k0=mid)).co2_g_per_mi
        lo, hi = (mid, hi) if co2 < target_co2 else (lo, mid)
    return replace(veh, k0=0.5 * (lo + hi))


def fit_fuel(
    veh: cmem.CmemVehicle, t: dict[str, float], hwfet: Cycle, bag2: Cycle
) -> cmem.CmemVehicle:
    """k0 matches HWFET CO2 exactly; eta, kept in ETA_RANGE, minimises the bag-2 CO2 error.

    Left free, the two targets want eta = 0.60, beyond any real engine, so eta ends on
    the range's upper bound and bag 2 keeps a residual (reported).
    """
    best: cmem.CmemVehicle | None = None
    best_err = np.inf
    for eta in np.linspace(*ETA_RANGE, 11):
        cand = solve_k0(replace(veh, indicated_efficiency=float(eta)), t["hwfet_co2"], hwfet)
        err = abs(cmem.per_mile(bag2.t, bag2.v, cand).co2_g_per_mi - t["bag2_co2"])
        if err < best_err:
            best, best_err = cand, err
    assert best is not None
    return best


def fit_gammas(veh: cmem.CmemVehicle, t: dict[str, float]) -> cmem.CmemVehicle:
    """Catalyst gammas from HWFET tailpipe CO, HC, NOx (needs b_j = 0)."""
    assert veh.b_co == veh.b_hc == veh.b_nox == 0.0
    cyc = load_cycle("hwfet")
    iv = intervals(cyc.t, cyc.v)
    r = cmem.cmem_rates(iv.v, iv.a, veh)
    miles = iv.distance_m / 1609.344
    rich = 1.0 - 1.0 / r.phi

    def total(x: np.ndarray) -> float:
        return float(np.sum(x * iv.dt)) / miles  # [g/mi]

    # tailpipe = sum(EO (1 - gamma w)) -> gamma = (EO - target) / sum(EO w)
    w_co = np.exp(-veh.c_co_cat * rich * r.fuel_g_s)
    w_hc = np.exp(-veh.c_hc_cat * rich * r.fuel_g_s)
    w_nox = 1.0 - veh.c_nox_cat * 0.0 * rich  # with b_NOx = 0 the NOx efficiency is gamma
    g_co = (total(r.engine_out_co_g_s) - t["hwfet_co"]) / total(r.engine_out_co_g_s * w_co)
    g_hc = (total(r.engine_out_hc_g_s) - t["hwfet_hc"]) / total(r.engine_out_hc_g_s * w_hc)
    g_nox = (total(r.engine_out_nox_g_s) - t["hwfet_nox"]) / total(r.engine_out_nox_g_s * w_nox)
    return replace(veh, gamma_co=g_co, gamma_hc=g_hc, gamma_nox=g_nox)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--write", action="store_true", help=f"write energy/data/{cmem.CALIBRATION_FILE}"
    )
    args = parser.parse_args()

    t = epa_targets()
    hwfet = load_cycle("hwfet")
    bag2 = load_cycle("udds").window(UDDS_BAG2_START_S)
    veh = cmem.COROLLA_2022_UNCALIBRATED
    for _ in range(3):  # CO2 depends weakly on the gammas through tailpipe CO/HC
        veh = fit_fuel(veh, t, hwfet, bag2)
        veh = fit_gammas(veh, t)

    print("EPA targets (g/mi):", {k: round(v, 4) for k, v in t.items()})
    print(f"k0 = {veh.k0:.6f} kJ/(rev L)   eta = {veh.indicated_efficiency:.6f}")
    print(
        f"gamma_co = {veh.gamma_co:.6f}  gamma_hc = {veh.gamma_hc:.6f}  gamma_nox = {veh.gamma_nox:.6f}"
    )
    print(
        f"{'cycle':16s} {'fuel':>7s} {'CO2':>7s} {'CO':>7s} {'HC':>7s} {'NOx':>7s} {'mpg':>6s}   (g/mi)"
    )
    for name in (*CYCLES, "udds_bag2"):
        c = bag2 if name == "udds_bag2" else load_cycle(name)
        r = cmem.per_mile(c.t, c.v, veh)
        print(
            f"{name:16s} {r.fuel_g_per_mi:7.2f} {r.co2_g_per_mi:7.2f} {r.co_g_per_mi:7.4f} "
            f"{r.hc_g_per_mi:7.4f} {r.nox_g_per_mi:7.4f} {r.mpg:6.2f}"
        )
    if args.write:
        src = "scripts/calibrate_cmem.py"
        path = write_params(
            cmem.CALIBRATION_FILE,
            [
                ("k0", veh.k0, "kJ/(rev L)", f"{src}: matches HWFET CO2"),
                (
                    "indicated_efficiency",
                    veh.indicated_efficiency,
                    "-",
                    f"{src}: in 0.40-0.45, best FTP bag-2 CO2",
                ),
                ("gamma_co", veh.gamma_co, "-", f"{src}: HWFET tailpipe CO"),
                ("gamma_hc", veh.gamma_hc, "-", f"{src}: HWFET tailpipe THC"),
                ("gamma_nox", veh.gamma_nox, "-", f"{src}: HWFET tailpipe NOx"),
            ],
        )
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
