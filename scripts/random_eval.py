"""Drive models and the ACC on held-out random episodes over UDP; score gap, energy and comfort.

    .venv/bin/python scripts/random_eval.py --seeds 100-107 ice-eco=models/ice-eco.pt ice-gap=models/ice-gap.pt
    .venv/bin/python scripts/random_eval.py --scenario ev --seeds 100-107 ev-eco=models/ev-eco.pt

Each run is `vacc drive --trajectory random --seed S`: a random lead (eq. 7 for the ICE
car, a real-trace window for the EV), start, traffic and light that no model was
selected on (training draws its seeds from [0, 2^31); selection used random:1..4). The
ACC drives alongside unless --no-acc; --traffic sets the neighbours (cars in each adjacent
lane, as `vacc drive --traffic`) and --sun-elevation the range of the sun's height (as
`vacc drive --sun-elevation`), both recorded with each run. Writes the logs and summary.json to --out (default
runs/random-eval-<scenario>; give each evaluation its own to keep earlier ones) and
prints, per controller, the mean and worst gap RMSE to 55 m, the mean energy, and the
comfort figures after the first 15 s.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from agent_client.launcher import Road
from energy import SETTLE_S, evaluate_run
from protocol.constants import SUN_ELEVATION, TRAFFIC_PER_LANE, TRAFFIC_PER_LANE_RANGE
from protocol.scenarios import parse_sun_elevation
from vacc.safety import parse_seeds

VEHICLE = {"ice": "corolla", "ev": "leaf"}
ENERGY = {"ice": ("fuel_g_per_mi", "g/mi"), "ev": ("energy_kj_per_mi", "kJ/mi")}


def _drive(scenario: str, name: str, args: list[str], seed: int, road: Road, out: Path) -> dict:
    log = out / f"{name}-seed{seed}.csv"
    cmd = [sys.executable, "-m", "vacc", "drive", *args, "--scenario", scenario, "--trajectory", "random", "--seed", str(seed),
           *road.server_args(), "--log", str(log), "--quiet"]  # fmt: skip
    subprocess.run(cmd, check=True)
    m = evaluate_run(log, VEHICLE[scenario], settle_s=SETTLE_S)
    keys = ("gap_rmse_55m_m", "collisions", "gap_min_m", ENERGY[scenario][0], "jerk_rms_mps3", "iso_jerk_window_share", "speed_max_mps")
    return {"seed": seed, "traffic": road.traffic, "sun_elevation": list(road.sun_elevation), **{k: m[k] for k in keys}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", choices=("ice", "ev"), default="ice")
    p.add_argument("--seeds", default="100-107", help="episode seeds, e.g. 100-107")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", type=Path, default=None, help="folder for the logs and summary.json (default: runs/random-eval-<scenario>)")
    p.add_argument("--no-acc", action="store_true", help="drive the models only, not the ACC beside them")
    p.add_argument("--traffic", type=int, default=TRAFFIC_PER_LANE, help=f"cars in each adjacent lane, twice as many oncoming (default {TRAFFIC_PER_LANE})")
    p.add_argument(
        "--sun-elevation", default=",".join(map(str, SUN_ELEVATION)), metavar="LOW,HIGH",
        help="range [rad] of each run's sun height (default %(default)s); a low sun throws shadows across the lane",
    )  # fmt: skip
    p.add_argument("models", nargs="*", metavar="NAME=CHECKPOINT")
    a = p.parse_args()
    controllers = {} if a.no_acc else {"acc": ["--controller", "acc"]}
    for item in a.models:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            p.error(f"{item!r} is not NAME=CHECKPOINT")
        if name in controllers:
            p.error(f"{name!r} is named twice (the ACC is 'acc')")
        if not Path(path).is_file():
            p.error(f"{name}: no checkpoint file at {path}")
        controllers[name] = ["--controller", "ddqn", "--checkpoint", path]
    if not controllers:
        p.error("nothing to drive: give NAME=CHECKPOINT or leave out --no-acc")
    try:
        seeds = parse_seeds(a.seeds)
    except ValueError as e:
        p.error(f"--seeds: {e}")
    low, high = TRAFFIC_PER_LANE_RANGE
    if not low <= a.traffic <= high:
        p.error(f"--traffic: {a.traffic} is not in {low}..{high}")
    try:
        road = Road(a.traffic, parse_sun_elevation(a.sun_elevation))
    except ValueError as e:
        p.error(f"--sun-elevation: {e}")
    out = a.out if a.out is not None else Path(f"runs/random-eval-{a.scenario}")
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(name, args, s) for name, args in controllers.items() for s in seeds]
    with ThreadPoolExecutor(a.jobs) as pool:  # each job is its own server and client processes
        done = list(pool.map(lambda j: _drive(a.scenario, j[0], j[1], j[2], road, out), jobs))
    results: dict[str, list[dict]] = {}
    for (name, _, _), r in zip(jobs, done, strict=True):
        results.setdefault(name, []).append(r)
    (out / "summary.json").write_text(json.dumps(results, indent=1) + "\n")
    key, unit = ENERGY[a.scenario]
    if road.note():
        print(f"the road: {road.note()[2:]}")
    for name, runs in results.items():
        rmse = np.array([r["gap_rmse_55m_m"] for r in runs])
        print(
            f"{name}: gap RMSE mean {rmse.mean():.2f} m, worst {rmse.max():.2f} m; "
            f"energy {np.mean([r[key] for r in runs]):.1f} {unit}; jerk RMS {np.mean([r['jerk_rms_mps3'] for r in runs]):.2f} m/s^3, "
            f"worst ISO jerk share {100 * max(r['iso_jerk_window_share'] for r in runs):.1f} %; "
            f"collisions {sum(r['collisions'] for r in runs)}, min gap {min(r['gap_min_m'] for r in runs):.1f} m"
        )
        print("    RMSE per seed:", " ".join(f"{x:.2f}" for x in rmse))


if __name__ == "__main__":
    main()
