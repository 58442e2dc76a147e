#!/usr/bin/env python
"""Fit the paper's eq. 6 (nine coefficients) to VT-CPEM over the EPA cycles.

The question: how closely can the paper's EV energy equation stand in for a physical
model of the Leaf, on the cycles it was fitted to and on one held out?

The paper's coefficients (Qi et al. 2018, Table 4) are not public. This script
samples the VT-CPEM Nissan Leaf model (:mod:`energy.ev`, P_aux = 700 W) on every
1 s interval of the EPA UDDS, HWFET and US06 cycles (mean speed, constant
acceleration), fits l0..l8 by ordinary least squares on battery power [kW], and
prints the coefficients, the fit quality and the Wh/mi of both models on every
shipped cycle (WLTC 3b is held out of the fit). With ``--write`` it stores the
coefficients in ``energy/data/leaf_eq6_fit.csv``, which :mod:`energy.ev` loads,
labelled as a fit to VT-CPEM.

Run: ``python scripts/fit_ev_model.py [--write]``.
"""

from __future__ import annotations

import argparse

import numpy as np

from energy import ev, write_params
from energy.cycles import CYCLES, load_cycle
from energy.trace import intervals

FIT_CYCLES = ("udds", "hwfet", "us06")
UNITS = (
    "kW",
    "kW s/m",
    "kW s^3/m^3",
    "kW s^3/m^2",
    "kW s^2/m^2",
    "kW s^4/m^4",
    "kW s^4/m^3",
    "kW s^5/m^4",
    "kW s^5/m^3",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"write energy/data/{ev.EQ6_FIT_FILE}")
    args = parser.parse_args()

    xs, ys = [], []
    for name in FIT_CYCLES:
        c = load_cycle(name)
        iv = intervals(c.t, c.v)
        xs.append(ev.eq6_design(iv.v, iv.a))
        ys.append(ev.vtcpem_power_w(iv.v, iv.a) / 1000.0)
    x, y = np.concatenate(xs), np.concatenate(ys)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    r2 = 1.0 - float(resid @ resid) / float(((y - y.mean()) ** 2).sum())
    rmse = float(np.sqrt(np.mean(resid**2)))

    print(f"eq. 6 fitted to VT-CPEM on {', '.join(FIT_CYCLES)}: {y.size} samples")
    for name, value, unit in zip(ev.EQ6_TERMS, coef, UNITS, strict=True):
        print(f"  {name} = {value: .6e} {unit}")
    print(f"R^2 = {r2:.5f}   RMSE = {rmse:.3f} kW")
    print(f"{'cycle':10s} {'VT-CPEM':>9s} {'eq.6 fit':>9s} {'regen':>7s}   (Wh/mi at the battery)")
    for name in CYCLES:
        c = load_cycle(name)
        phys = ev.vtcpem_per_mile(c.t, c.v)
        fit = ev.eq6_per_mile(c.t, c.v, coef)
        print(
            f"{name:10s} {phys.energy_wh_per_mi:9.1f} {fit.energy_wh_per_mi:9.1f} "
            f"{phys.regen_kj_per_mi / 3.6:7.1f}{'' if name in FIT_CYCLES else '   (held out)'}"
        )
    if args.write:
        note = f"fit to VT-CPEM (P_aux 700 W) on {'+'.join(FIT_CYCLES)}, R2 {r2:.4f}; NOT the UCR values"
        path = write_params(
            ev.EQ6_FIT_FILE,
            [(n, float(v), u, note) for n, v, u in zip(ev.EQ6_TERMS, coef, UNITS, strict=True)],
        )
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
