"""Score driven runs under several eco-reward weightings: which controller does each prefer?

    .venv/bin/python scripts/reward_ablation.py runs/eval-ice      # the logs of a `vacc evaluate` run
    .venv/bin/python scripts/reward_ablation.py runs/eval-ev
    .venv/bin/python scripts/reward_ablation.py --scenario ice \
        --group 'student=runs/abl/noaug-*/gates/logs/ddqn-test-*.csv' --group 'ac=runs/abl/base-*/gates/logs/ddqn-test-*.csv'

The eco reward is linear in its four terms (gap, energy, comfort, closing: rewards.py), so
each run's mean terms are computed once from its log and every weighting is a weighted sum
over the weights' total, the reward the trainer would have paid per step. The logs come from
``vacc drive``/``vacc evaluate``, where no env runs and no reward is paid, so the terms are
computed from each row by :func:`agent_client.rewards.eco_terms`: the one function the eco
reward and the env's ``info["reward_terms"]`` are built from. Prints, per
weighting, the mean reward per step of each method over its logs and the methods in order.
``--group NAME=GLOB`` (repeatable) scores any logs as one method instead, such as the test
logs of several ``vacc gates`` folders; ``--scenario`` is for logs without a run card.
A reward-design check, not a training run: it says what a policy that maximised each
weighting would be pushed toward, among behaviours that exist.
"""

from __future__ import annotations

import argparse
import csv
import glob
import sys
from pathlib import Path

import numpy as np

from agent_client.errors import InputFileError
from agent_client.rewards import ECO_WEIGHTS, eco_terms
from agent_client.runlog import read_card

WEIGHTINGS = {
    "shipped (1, 0.5, 0.25, 0.5)": ECO_WEIGHTS,
    "gap only": (1.0, 0.0, 0.0, 0.0),
    "no energy": (1.0, 0.0, 0.25, 0.5),
    "no comfort": (1.0, 0.5, 0.0, 0.5),
    "no closing": (1.0, 0.5, 0.25, 0.0),
    "energy x2": (1.0, 1.0, 0.25, 0.5),
    "comfort x4": (1.0, 0.5, 1.0, 0.5),
}
FOLLOWERS = ("ddqn-gap", "ddqn-force", "ddqn-eco", "acc", "human")


def mean_terms(log: Path, scenario: str) -> np.ndarray:
    """Mean per step of (gap term / 10, -energy, -comfort, -closing) over one run log."""
    rows = list(csv.DictReader(log.open()))
    terms = []
    a_prev = 0.0
    for r in rows[1:]:  # the reward of a step is paid on the row it produced
        a = float(r["accel"])
        t = eco_terms(float(r["gap"]), v=float(r["v_host"]), a=a, a_prev=a_prev, v_lead=float(r["v_lead"]), scenario=scenario)
        terms.append((t.gap / 10.0, -t.energy, -t.comfort, -t.closing))  # signed as the reward pays them
        a_prev = a
    return np.mean(terms, axis=0)


def run_scenario(log: Path, given: str | None = None) -> str:
    """The scenario ("ice" or "ev") a run log's card records, else ``given``; a log with
    neither is refused, and so is one whose card says another than ``given``."""
    try:
        card = read_card(log)
    except InputFileError as exc:
        sys.exit(str(exc))
    scenario = ((card or {}).get("episode") or {}).get("scenario", given)
    if scenario not in ("ice", "ev"):
        sys.exit(f"{log}: its run card does not say the scenario (ice or ev); give --scenario")
    if given is not None and scenario != given:
        sys.exit(f"{log}: its run card says scenario {scenario!r}, not --scenario {given!r}")
    return scenario


def groups_of(specs: list[str]) -> dict[str, list[Path]]:
    """``NAME=GLOB`` specs as {name: the logs the glob matches}; a spec without '=' or one that
    matches nothing is refused."""
    groups = {}
    for spec in specs:
        name, sep, pattern = spec.partition("=")
        if not sep or not name or not pattern:
            sys.exit(f"--group {spec!r}: give NAME=GLOB")
        groups[name] = sorted(Path(p) for p in glob.glob(pattern))
        if not groups[name]:
            sys.exit(f"--group {spec!r}: no file matches {pattern!r}")
    return groups


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", type=Path, nargs="?", help="a `vacc evaluate --out` folder (its logs/)")
    p.add_argument("--group", action="append", default=[], metavar="NAME=GLOB", help="score these logs as method NAME (repeatable), instead of a folder")
    p.add_argument("--scenario", choices=("ice", "ev"), help="the scenario of logs without a run card (vacc gates' logs)")
    a = p.parse_args()
    if (a.run is None) == (not a.group):
        p.error("give a run folder or --group NAME=GLOB, not both")
    if a.group:
        logs = groups_of(a.group)
    else:
        logs = {m: sorted((a.run / "logs").glob(f"{m}-*.csv")) for m in FOLLOWERS}
        if not any(logs.values()):
            sys.exit(f"{a.run / 'logs'}: no run logs of {', '.join(FOLLOWERS)}")
    terms = {m: np.mean([mean_terms(f, run_scenario(f, a.scenario)) for f in fs], axis=0) for m, fs in logs.items() if fs}
    print("mean terms per step (gap/10, -energy, -comfort, -closing):")
    for m, t in terms.items():
        print(f"  {m:11} " + " ".join(f"{x:+.4f}" for x in t))
    for name, w in WEIGHTINGS.items():
        score = {m: float(np.dot(t, w) / sum(w)) for m, t in terms.items()}
        order = sorted(score, key=score.get, reverse=True)
        print(f"{name:28} " + "  ".join(f"{m} {score[m]:+.4f}" for m in order))


if __name__ == "__main__":
    main()
