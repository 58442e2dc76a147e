"""`vacc evaluate --suite safety`: every method through every lead scenario over many seeds.

A run passes when it has no collision, its minimum gap is at least
:data:`MIN_GAP` and its speed never exceeds the set speed by more than
:data:`SPEED_MARGIN` (ISO 15622 stopping on a stopped or stopping target, Euro NCAP
CCRs/CCRm/CCRb shapes; ``docs/scenarios.md``). Each row also counts the unprompted hard
brakes (phantom brakes), beside the verdict. Each DDQN model drives the scenario it
was trained for (ice-* the ICE car, ev-* the EV); the ACC drives both.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import click

from agent_client.launcher import DEFAULT_ROAD, Road
from energy import RunLogError, comfort, read_run_log
from energy.metrics import comfort_metrics
from protocol.constants import MIN_GAP
from protocol.scenarios import DEFAULT_SET_SPEED, LEAD_SCENARIOS, SCENARIOS
from vacc.runs import Job, drive_jobs

__all__ = ["MIN_GAP", "SPEED_MARGIN", "safety_jobs", "score_run", "run_suite", "safety_table"]

SPEED_MARGIN = 0.5  # [m/s] a passing run stays at or below the set speed plus this


def safety_jobs(
    out: Path,
    models: dict[str, str],
    seeds: Iterable[int],
    scenarios: Iterable[str] = tuple(LEAD_SCENARIOS),
    cold_start: bool = False,
    vehicles: Iterable[str] = SCENARIOS,
    acc: bool = True,
    road: Road = DEFAULT_ROAD,
    model_vehicles: dict[str, str] | None = None,
) -> list[Job]:
    """The runs of the suite: (method, vehicle) x lead scenario x seed.

    Args:
        out: the output folder (logs go to ``out/logs``).
        models: method name ("ice-gap", ...) to checkpoint path; the vehicle is the prefix,
            or the model's in ``model_vehicles``.
        seeds: episode seeds.
        scenarios: lead scenario names.
        cold_start: engage the models at frame 0, without the camera's pre-roll.
        vehicles: whose ACC drives (the models drive their own vehicle).
        acc: whether the ACC drives at all (``--methods`` without acc: the models alone).
        road: every run's traffic and sun (the servers' ``--traffic`` and ``--sun-elevation``).
        model_vehicles: the vehicle of a model whose name does not begin with it (``--model NAME=PATH``).
    """
    own = model_vehicles or {}
    drivers = [("acc", vehicle, None) for vehicle in vehicles if acc] + [(name, own.get(name) or name.split("-")[0], path) for name, path in sorted(models.items())]
    return [
        Job(method if path is None else "ddqn", trajectory, vehicle, seed,
            str(out / "logs" / f"{method}-{vehicle}-{trajectory}-{seed}.csv"), None, path, None, cold_start, road)  # fmt: skip
        for method, vehicle, path in drivers
        for trajectory in scenarios
        for seed in seeds
    ]


def score_run(log: str | Path, set_speed: float = DEFAULT_SET_SPEED) -> dict[str, Any]:
    """Collision, minimum gap [m] and maximum speed [m/s] of one run log, and whether it
    passes; and, not part of the verdict, its unprompted hard brakes from engagement on
    (:func:`energy.comfort.unprompted_hard_brakes`: phantom brakes the minima cannot show).

    Raises:
        click.ClickException: the log is not a valid run log (the file, the row, the problem).
    """
    try:
        run = read_run_log(log)
    except RunLogError as e:
        raise click.ClickException(str(e)) from None
    collision = bool(run.collision.any())
    min_gap, max_speed = float(run.gap.min()), float(run.v_host.max())
    ok = not collision and min_gap >= MIN_GAP and max_speed <= set_speed + SPEED_MARGIN
    brakes = comfort_metrics(run)["unprompted_hard_brakes"] or 0
    return {"collision": collision, "min_gap_m": min_gap, "max_speed_mps": max_speed, "passed": ok, "unprompted_hard_brakes": brakes}


def safety_table(jobs: list[Job], scores: list[dict[str, Any]]) -> tuple[str, list[dict[str, Any]]]:
    """A markdown pass/fail table (one row per driver and scenario) and its rows."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for job, score in zip(jobs, scores, strict=True):
        driver = job.method if job.checkpoint is None else Path(job.log).stem.removesuffix(f"-{job.scenario}-{job.trajectory}-{job.seed}")
        groups.setdefault((f"{driver} ({job.scenario})", job.trajectory), []).append(score)
    rows = []
    for (driver, scenario), runs in groups.items():
        rows.append({
            "driver": driver, "scenario": scenario, "runs": len(runs), "passed": sum(r["passed"] for r in runs),
            "collisions": sum(r["collision"] for r in runs), "min_gap_m": min(r["min_gap_m"] for r in runs),
            "max_speed_mps": max(r["max_speed_mps"] for r in runs),
            "unprompted_hard_brakes": sum(r["unprompted_hard_brakes"] for r in runs),
            "runs_with_unprompted": sum(r["unprompted_hard_brakes"] > 0 for r in runs),
        })  # fmt: skip
    lines = [
        f"Pass: no collision, minimum gap >= {MIN_GAP:g} m, speed <= set speed ({DEFAULT_SET_SPEED:g} m/s) + {SPEED_MARGIN:g} m/s.",
        "Unprompted hard brakes (from engagement; not part of the verdict): decelerations past",
        f"{comfort.ISO_DECEL_LIMIT_MPS2:g} m/s^2 with no threat in the {comfort.PROMPT_WINDOW_S:g} s before (energy.comfort.unprompted_hard_brakes).",
        "",
        "| driver | scenario | passed | collisions | min gap (m) | max speed (m/s) | unprompted hard brakes | verdict |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    totals: dict[str, list[int]] = {}
    for r in rows:
        verdict = "PASS" if r["passed"] == r["runs"] else "FAIL"
        lines.append(f"| {r['driver']} | {r['scenario']} | {r['passed']}/{r['runs']} | {r['collisions']} | {r['min_gap_m']:.2f} | {r['max_speed_mps']:.2f} "
                     f"| {r['unprompted_hard_brakes']} | {verdict} |")  # fmt: skip
        total = totals.setdefault(r["driver"], [0, 0, 0, 0])
        for i, key in enumerate(("passed", "runs", "unprompted_hard_brakes", "runs_with_unprompted")):
            total[i] += r[key]
    lines += ["", "| driver | passed | unprompted hard brakes (runs with any) |", "| --- | --- | --- |"]
    lines += [f"| {d} | {p}/{n} | {u} ({k}) |" for d, (p, n, u, k) in totals.items()]
    return "\n".join(lines) + "\n", rows


def run_suite(
    out: Path, models: dict[str, str], seeds: list[int], jobs: int, cold_start: bool = False,
    vehicles: Iterable[str] = SCENARIOS, scenarios: Iterable[str] = tuple(LEAD_SCENARIOS), acc: bool = True,
    road: Road = DEFAULT_ROAD, model_vehicles: dict[str, str] | None = None,
) -> str:  # fmt: skip
    """Drive every run (``jobs`` at a time, each with its own server), write safety.md/.csv.

    Returns:
        The markdown table.
    """
    (out / "logs").mkdir(parents=True, exist_ok=True)
    work = safety_jobs(out, models, seeds, scenarios, cold_start=cold_start, vehicles=vehicles, acc=acc, road=road, model_vehicles=model_vehicles)
    drive_jobs(work, jobs, "safety suite")
    table, rows = safety_table(work, [score_run(j.log) for j in work])
    (out / "safety.md").write_text(f"# Safety suite{road.note()}\n\n" + table)
    with open(out / "safety.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return table
