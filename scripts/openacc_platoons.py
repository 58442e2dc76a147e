"""Real OpenACC platoons beside simulated ones, and the ACC calibrated to real followers.

    .venv/bin/python scripts/openacc_platoons.py                # amplification table
    .venv/bin/python scripts/openacc_platoons.py --calibrate    # and the per-follower fit (minutes)
    .venv/bin/python scripts/openacc_platoons.py --figures DIR  # and each file's two figures
    .venv/bin/python scripts/openacc_platoons.py --files long_setting_dynamic_part19.csv --calibrate --followers 3  # one file, its first three followers

For each of the nine files: the real platoon's lead-to-last RMS speed-deviation ratio over
the whole run and after the first fifth (energy.string_stability), the lead's own RMS
deviation after the first fifth, and the same ratio for a platoon of the shipped ACC of
the same length behind the recorded lead (vacc.platoon_sim, starting at equilibrium).
``--calibrate`` fits beta, gamma and t_gap to every real follower (vacc.acc_calibration)
and prints one CSV row per follower.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from energy.openacc import OPENACC_FILES, read_openacc
from energy.string_stability import amplification
from vacc.acc_calibration import fit_follower
from vacc.openacc_suite import simulated_row
from vacc.platoon_figures import plot_amplification, plot_time_space, positions

CAR_LENGTH_M = 4.6  # [m] drawn in the real time-space diagrams (OpenACC gives bumper gaps only)


def simulated_ratio(name: str) -> tuple[float, float]:
    """(lead-to-last ratio, last car's RMS deviation [m/s]) of an all-ACC platoon behind the file's lead."""
    row = simulated_row(read_openacc(name), "acc")
    return (float("nan"), float("nan")) if row.collided else (row.speed_rms, row.last_dev_rms)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calibrate", action="store_true", help="fit the ACC to every real follower")
    ap.add_argument("--figures", type=Path, help="write each real platoon's two figures here")
    ap.add_argument("--files", nargs="+", choices=OPENACC_FILES, default=OPENACC_FILES, help="only these files")
    ap.add_argument("--followers", type=int, default=None, metavar="N", help="(--calibrate) fit only the first N followers of each file")
    args = ap.parse_args()
    if args.followers is not None and args.followers < 1:
        ap.error(f"--followers {args.followers}: give at least 1")
    print("file,cars,real_ratio_whole,real_ratio_after_fifth,lead_dev_rms_mps,last_dev_rms_mps,acc_sim_ratio,acc_sim_last_dev_rms_mps")
    for name in args.files:
        run = read_openacc(name)
        whole = amplification(run.t, run.speed, skip_fraction=0.0).lead_to_last.speed_rms
        amp = amplification(run.t, run.speed)
        sim, sim_last = simulated_ratio(name)
        print(f"{name},{run.n_cars},{whole:.2f},{amp.lead_to_last.speed_rms:.2f},{amp.lead_speed_dev_rms:.3f},{amp.last_speed_dev_rms:.3f},{sim:.2f},{sim_last:.3f}", flush=True)
        if args.figures:
            args.figures.mkdir(parents=True, exist_ok=True)
            stem = name.removesuffix(".csv")
            x = positions(run.t, run.speed[0], run.ivs, CAR_LENGTH_M)
            plot_time_space(args.figures, run.t, x, run.speed, f"{stem}_time_space", f"{stem}: time-space")
            plot_amplification(args.figures, run.t, run.speed, f"{stem}_amplification", f"{stem}: amplification by position")
    if args.calibrate:
        print("file,follower,vehicle,beta_per_s2,gamma_per_s,t_gap_s,rmse_m,samples")
        for name in args.files:
            run = read_openacc(name)
            for i in range(1, run.n_cars if args.followers is None else min(run.n_cars, args.followers + 1)):
                f = fit_follower(run, i)
                print(f"{name},{i},{f.vehicle},{f.beta:.4f},{f.gamma:.4f},{f.t_gap:.3f},{f.rmse_m:.3f},{f.samples}", flush=True)


if __name__ == "__main__":
    main()
