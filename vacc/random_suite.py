"""`vacc evaluate --suite random`: the ACC and the models on held-out random episodes.

Each run is `vacc drive --trajectory random --seed S`: a random lead (eq. 7 for the ICE
car, a real-trace window for the EV), start, traffic and light that no model was
selected on (training draws its seeds from [0, 2^31); selection used random:1..4; the
suite's default seeds are :data:`RANDOM_SEEDS`). Writes the logs (``logs/<driver>-seed<S>.csv``),
``summary.json`` (per driver, each run's road and figures) and ``random.md``: per driver,
the mean and worst gap RMSE to 55 m, the mean energy, and the comfort figures after the
settle.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import click
import numpy as np

from agent_client.launcher import DEFAULT_ROAD, Road
from energy import SETTLE_S, RunLogError, evaluate_run
from protocol.scenarios import RANDOM
from vacc.runs import Job, drive_jobs

__all__ = ["RANDOM_SEEDS", "ENERGY", "random_jobs", "driver_name", "score_random_run", "random_table", "run_random"]

RANDOM_SEEDS = "100-107"
"""The suite's held-out episode seeds when neither --seed nor --seeds is given."""

ENERGY = {"ice": ("fuel_g_per_mi", "g/mi"), "ev": ("energy_kj_per_mi", "kJ/mi")}
"""Each scenario's energy metric of :func:`energy.evaluate_run` and its unit."""


def random_jobs(
    out: Path, models: dict[str, str], scenario: str, seeds: Iterable[int], acc: bool = True,
    duration: float | None = None, cold_start: bool = False, road: Road = DEFAULT_ROAD,
) -> list[Job]:  # fmt: skip
    """The runs of the suite: (the ACC and) each model on the random episode of each seed.

    Args:
        out: the output folder (logs go to ``out/logs``).
        models: driver name ("ice-gap", ...) to checkpoint path.
        scenario: the vehicle every driver drives ("ice" or "ev").
        seeds: episode seeds.
        acc: whether the ACC drives beside the models.
        duration: drive only this many seconds of each episode [s]; None: all of it.
        cold_start: engage the models at frame 0, without the camera's pre-roll.
        road: every run's traffic and sun (the servers' ``--traffic`` and ``--sun-elevation``).
    """
    drivers = [("acc", None)] * acc + sorted(models.items())
    seeds = list(seeds)
    return [
        Job("acc" if path is None else "ddqn", RANDOM, scenario, seed, str(out / "logs" / f"{name}-seed{seed}.csv"),
            duration, path, None, cold_start, road)  # fmt: skip
        for name, path in drivers
        for seed in seeds
    ]


def driver_name(job: Job) -> str:
    """The driver of a job: "acc", or its model's name ("ice-gap", or a --model NAME), as its log is named."""
    return job.method if job.checkpoint is None else Path(job.log).stem.removesuffix(f"-seed{job.seed}")


def score_random_run(job: Job, vehicle: str, settle: float = SETTLE_S) -> dict[str, Any]:
    """One run's seed, road and figures (gap, collisions, energy, comfort after ``settle`` [s]).

    Raises:
        click.ClickException: the log is not a valid run log (the file, the row, the problem).
    """
    try:
        m = evaluate_run(job.log, vehicle, settle_s=settle)
    except RunLogError as exc:
        raise click.ClickException(str(exc)) from None
    keys = ("gap_rmse_55m_m", "collisions", "gap_min_m", ENERGY[job.scenario][0], "jerk_rms_mps3", "iso_jerk_window_share", "speed_max_mps")
    return {"seed": job.seed, "traffic": job.road.traffic, "sun_elevation": list(job.road.sun_elevation), **{k: m[k] for k in keys}}


def _figures(runs: list[dict[str, Any]], key: str) -> np.ndarray:
    """One metric over runs, NaN where a run has none (it ended before the settle): a mean or
    a worst over them is then NaN, printed as such, never a figure of the other runs alone."""
    return np.array([np.nan if r[key] is None else float(r[key]) for r in runs])


def random_table(results: dict[str, list[dict[str, Any]]], scenario: str, road: Road = DEFAULT_ROAD) -> list[str]:
    """Per driver, the mean and worst gap RMSE, the mean energy, comfort and safety; then the RMSE per seed."""
    key, unit = ENERGY[scenario]
    lines = [f"the road: {road.note()[2:]}"] if road.note() else []
    for name, runs in results.items():
        rmse = np.array([r["gap_rmse_55m_m"] for r in runs])
        lines.append(
            f"{name}: gap RMSE mean {rmse.mean():.2f} m, worst {rmse.max():.2f} m; "
            f"energy {_figures(runs, key).mean():.1f} {unit}; jerk RMS {_figures(runs, 'jerk_rms_mps3').mean():.2f} m/s^3, "
            f"worst ISO jerk share {100 * _figures(runs, 'iso_jerk_window_share').max():.1f} %; "
            f"collisions {sum(r['collisions'] for r in runs)}, min gap {min(r['gap_min_m'] for r in runs):.1f} m"
        )
        lines.append("    RMSE per seed: " + " ".join(f"{x:.2f}" for x in rmse))
    return lines


def run_random(
    out: Path, models: dict[str, str], scenario: str, seeds: list[int], jobs: int, vehicle: str,
    settle: float = SETTLE_S, acc: bool = True, duration: float | None = None, cold_start: bool = False,
    road: Road = DEFAULT_ROAD,
) -> str:  # fmt: skip
    """Drive every run (``jobs`` at a time, each with its own server), write summary.json and random.md.

    Args:
        vehicle: the energy model of ``scenario`` ("corolla", "average" or "leaf").
        settle: seconds at the start of each run left out of the comfort figures [s].

    Returns:
        The table, as random.md holds it.

    Raises:
        click.ClickException: a run failed, or its log is not a valid run log.
    """
    (out / "logs").mkdir(parents=True, exist_ok=True)
    work = random_jobs(out, models, scenario, seeds, acc, duration, cold_start, road)
    drive_jobs(work, jobs, f"random suite, {scenario}")
    results: dict[str, list[dict[str, Any]]] = {}
    for job in work:
        results.setdefault(driver_name(job), []).append(score_random_run(job, vehicle, settle))
    (out / "summary.json").write_text(json.dumps(results, indent=1) + "\n")
    table = "\n".join(random_table(results, scenario, road)) + "\n"
    (out / "random.md").write_text(table)
    return table
