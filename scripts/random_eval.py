"""Drive the shipped ICE models and the ACC on held-out random trajectories over UDP.

    .venv/bin/python scripts/random_eval.py 100 108      # episode seeds 100..107 -> runs/random-eval/

Each run is `vacc drive --trajectory random --seed S`: a random eq. 7 lead, start,
traffic and light that no model was selected on. Prints gap RMSE to 55 m per seed.
"""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

CONTROLLERS = {
    "ice-gap": ["--controller", "ddqn", "--checkpoint", "models/ice-gap.pt"],
    "ice-force": ["--controller", "ddqn", "--checkpoint", "models/ice-force.pt"],
    "acc": ["--controller", "acc"],
}


def main(first: int, stop: int, out: Path = Path("runs/random-eval")) -> None:
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict]] = {}
    for name, args in CONTROLLERS.items():
        for seed in range(first, stop):
            log = out / f"{name}-seed{seed}.csv"
            cmd = [sys.executable, "-m", "vacc", "drive", *args, "--scenario", "ice", "--trajectory", "random", "--seed", str(seed), "--log", str(log), "--quiet"]
            subprocess.run(cmd, check=True)
            rows = list(csv.DictReader(open(log)))
            gap = np.array([float(r["gap"]) for r in rows])
            t = np.array([float(r["t"]) for r in rows])
            results.setdefault(name, []).append({
                "seed": seed,
                "rmse_m": float(np.sqrt(np.mean((gap - 55.0) ** 2))),
                "rmse_after_15s_m": float(np.sqrt(np.mean((gap[t >= 15.0] - 55.0) ** 2))),
                "collision": any(r["collision"] in ("1", "True") for r in rows),
                "end_s": float(t[-1]),
            })  # fmt: skip
    (out / "summary.json").write_text(json.dumps(results, indent=1) + "\n")
    for name, runs in results.items():
        rmse = np.array([r["rmse_m"] for r in runs])
        print(f"{name}: gap RMSE mean {rmse.mean():.2f} m, worst {rmse.max():.2f} m, collisions {sum(r['collision'] for r in runs)}")
        print("   ", " ".join(f"{x:.2f}" for x in rmse))


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))
