"""Write a shipped model's training curve (``models/<model>.curve.csv``, which fig_training plots)
from a training run's ``scalars.csv``: the average reward per step of the episodes that ended in
each 5,000-step bin, its steps counted on from those of the chain before the run (``--offset``).

    python scripts/model_curve.py RUN_DIR --offset 455323 --note "..." --out models/ev-gap.curve.csv
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import defaultdict
from pathlib import Path

BIN_STEPS = 5_000


def curve(scalars: Path, offset: int) -> list[tuple[int, float]]:
    """(bin start + offset, reward per step) for each bin in which an episode ended."""
    returns: dict[int, float] = defaultdict(float)
    lengths: dict[int, float] = defaultdict(float)
    with scalars.open() as f:
        for row in csv.DictReader(f):
            bin_start = int(row["step"]) // BIN_STEPS * BIN_STEPS
            if row["name"] == "charts/episodic_return":
                returns[bin_start] += float(row["value"])
            elif row["name"] == "charts/episodic_length":
                lengths[bin_start] += float(row["value"])
    return [(b + offset, returns[b] / lengths[b]) for b in sorted(lengths) if lengths[b] > 0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a training run's folder (it holds scalars.csv)")
    parser.add_argument("--offset", type=int, default=0, help="steps of the chain before this run")
    parser.add_argument("--note", default="", help="what the run is, written into the file's comment line")
    parser.add_argument("--out", type=Path, required=True, help="the curve file to write")
    args = parser.parse_args(argv)
    scalars = args.run / "scalars.csv"
    if not scalars.is_file():
        print(f"{scalars}: no such file (give a training run's folder)", file=sys.stderr)
        return 1
    rows = curve(scalars, args.offset)
    if not rows:
        print(f"{scalars}: no finished episode to bin", file=sys.stderr)
        return 1
    note = f"; {args.note}" if args.note else ""
    lines = [f"# average reward per step of training episodes, in {BIN_STEPS:,}-step bins; from the run's scalars.csv{note}", "step,avg_reward"]
    args.out.write_text("\n".join(lines + [f"{s},{v:.4f}" for s, v in rows]) + "\n")
    print(f"wrote {args.out}: {len(rows)} bins, steps {rows[0][0]:,}-{rows[-1][0]:,}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
