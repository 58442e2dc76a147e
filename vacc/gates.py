"""`vacc gates`: check one checkpoint against its recipe's gates, with a pass/fail table.

The gates (``[gates]`` of ``recipes/<model>.toml``, :mod:`vacc.recipes`) are the checks the
shipped model passes, driven with the evaluation's own runs and scores
(:mod:`vacc.runs`, :mod:`vacc.safety`, :mod:`vacc.random_suite`):

* ``tests``: test-1..test-4 at one seed: the gap RMSE to 55 m of each, and no collision;
* ``safety``: the lead scenarios over seeds: every run passes (:func:`vacc.safety.score_run`);
* ``random``: held-out random leads: the worst seed's gap RMSE, and no collision;
* ``energy``: the mean energy over the tests against the ACC's on the same runs;
* ``comfort``: the mean jerk RMS and ISO 1-s jerk share over the tests, after the settle.

Beside the checks the report holds ``measures``, figures no gate bounds that ``vacc seeds``
summarises over training seeds (issue #54): on the tests and on the random leads, the mean gap
RMSE, the ISO jerk share and the energy against the ACC's on the same runs (the ACC drives both
sets for every recipe); in the safety suite, the closest gap. (The closest gap of the tests and
the random leads is their start gap, so it is not measured there.)

The runs drive on the recipe's CPU kernels (``cpu_path``, :data:`vacc.host.CPU_PATHS`), as the
gates at the end of ``vacc reproduce`` do: a report repeats bit for bit on one kernel path, and a
last-bit difference in a Q-value can move a decision. The report names the path.

``--quick`` (tests only) drives 2 s of each run, the first seed of each set and the
first two safety scenarios: it checks that the gates run, not that a model passes.

``--skip safety`` (or ``random``) leaves a set of runs out, for a comparison that needs only the
others (an ablation over seeds: the safety suite is 100 runs a model). The report names what it
skipped, its verdict is over the checks it ran, and ``vacc seeds`` summarises such reports only
with reports that skipped the same.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any, NamedTuple

import click
import numpy as np

from agent_client.rl.checkpoint import file_sha256
from energy import SETTLE_S
from protocol.scenarios import TEST_TRAJECTORIES
from vacc.host import CPU_PATHS, describe, pinned_path, use_cpu_path
from vacc.measures import CLOSEST_GAP, ENERGY_RATIO, ISO_JERK_SHARE, MEAN_GAP_RMSE
from vacc.paths import MODELS_DEFAULT, models_dir
from vacc.random_suite import ENERGY, random_jobs, score_random_run
from vacc.recipes import Recipe, RecipeError, load_recipe
from vacc.runs import Job, drive_jobs, log_path, parse_seeds, score_runs
from vacc.safety import safety_jobs, score_run

__all__ = ["Check", "Measure", "QUICK_SECONDS", "VEHICLES", "evaluate_gates", "gate_table", "gates"]

QUICK_SECONDS = 2.0  # [s] each run of --quick
QUICK_SCENARIOS = 2  # safety scenarios --quick drives
PARTS = ("tests", "safety", "random")  # the sets of runs; energy and comfort are scored on the tests' runs
VEHICLES = {"ice": "corolla", "ev": "leaf"}  # the energy model of each scenario, as vacc evaluate's default


class Check(NamedTuple):
    """One line of the gate report."""

    gate: str
    what: str  # the same words for every checkpoint checked against the recipe (vacc seeds groups by it)
    figure: float
    bound: float
    passed: bool
    detail: str = ""  # what this run adds, e.g. the closest gap of a safety scenario


class Measure(NamedTuple):
    """A figure of the report that no gate bounds."""

    gate: str  # where it was measured: tests, safety or random
    what: str
    figure: float


def _mean(metrics: list[dict[str, Any]], key: str) -> float:
    """The mean of one metric over runs; NaN if a run has none (a run that ended before the
    settle has no comfort figure), so that its check fails and vacc seeds leaves it out."""
    return float(np.mean([np.nan if m[key] is None else float(m[key]) for m in metrics]))


def _measures(gate: str, model: list[dict[str, Any]], acc: list[dict[str, Any]], energy_key: str) -> list[Measure]:
    """The measures of one set of runs (each a dict of metrics): mean gap RMSE, mean ISO jerk
    share and, where the ACC drove the same runs, the energy against its."""
    out = [Measure(gate, MEAN_GAP_RMSE, _mean(model, "gap_rmse_55m_m")), Measure(gate, ISO_JERK_SHARE, _mean(model, "iso_jerk_window_share"))]
    if acc:
        out.append(Measure(gate, ENERGY_RATIO, _mean(model, energy_key) / _mean(acc, energy_key)))
    return out


def _comfort_checks(gate: dict[str, Any], model: list[dict[str, Any]]) -> list[Check]:
    """The comfort gate over the model's runs (each a dict of metrics): the mean jerk RMS and
    ISO jerk share within their bounds; a figure a run lacks fails it, said in the detail."""
    checks = []
    for key, name in (("jerk_rms_mps3", "max_jerk_rms_mps3"), ("iso_jerk_window_share", "max_iso_jerk_share")):
        figure, bound = _mean(model, key), float(gate[name])
        missing = sum(m[key] is None for m in model)
        detail = f"{missing} run(s) ended before the settle: no figure" if missing else ""
        checks.append(Check("comfort", f"mean {key}", figure, bound, math.isfinite(figure) and figure <= bound, detail))
    return checks


def _seeds(text: str, quick: bool) -> list[int]:
    seeds = parse_seeds(text)
    return seeds[:1] if quick else seeds


def _test_checks(recipe: Recipe, ckpt: Path, out: Path, quick: bool, jobs: int) -> tuple[list[Check], list[Measure]]:
    """The tests, energy and comfort gates and the tests' measures: test-1..test-4 driven by
    the model and the ACC."""
    g = recipe.gates
    if not {"tests", "energy", "comfort"} & set(g):
        return [], []
    seed = g.get("tests", {}).get("seed", 0)
    duration = QUICK_SECONDS if quick else None
    settle = 0.0 if quick else SETTLE_S
    methods = ["ddqn", "acc"]
    (out / "logs").mkdir(parents=True, exist_ok=True)
    work = [Job(m, t, recipe.scenario, seed, str(log_path(out, m, t)), duration, str(ckpt) if m == "ddqn" else None)
            for m in methods for t in TEST_TRAJECTORIES]  # fmt: skip
    drive_jobs(work, jobs, f"gates {recipe.name}: tests")
    runs = score_runs(out, methods, VEHICLES[recipe.scenario], settle)
    model = [r for r in runs if r.method == "ddqn"]
    acc = [r for r in runs if r.method == "acc"]
    checks = []
    if "tests" in g:
        bound = float(g["tests"]["max_gap_rmse_m"])
        for r in model:
            rmse = float(r.metrics["gap_rmse_55m_m"])  # type: ignore[arg-type]  # a float in every scored run
            checks.append(Check("tests", f"{r.trajectory} gap RMSE (m)", rmse, bound, rmse <= bound))
        collisions = float(sum(int(r.metrics["collisions"] or 0) for r in model))
        checks.append(Check("tests", "collisions", collisions, 0.0, collisions == 0))
    if "energy" in g:
        key = ENERGY[recipe.scenario][0]
        ratio = _mean([r.metrics for r in model], key) / _mean([r.metrics for r in acc], key)
        bound = float(g["energy"]["max_ratio_to_acc"])
        checks.append(Check("energy", f"{key} / the ACC's", ratio, bound, math.isfinite(ratio) and ratio <= bound))
    if "comfort" in g:
        checks += _comfort_checks(g["comfort"], [r.metrics for r in model])
    return checks, _measures("tests", [r.metrics for r in model], [r.metrics for r in acc], ENERGY[recipe.scenario][0])


def _safety_checks(recipe: Recipe, ckpt: Path, out: Path, quick: bool, jobs: int) -> tuple[list[Check], list[Measure]]:
    """The safety gate: each scenario's runs over the seeds must all pass; the closest gap."""
    if "safety" not in recipe.gates:
        return [], []
    g = recipe.gates["safety"]
    scenarios = g["scenarios"][:QUICK_SCENARIOS] if quick else g["scenarios"]
    (out / "logs").mkdir(parents=True, exist_ok=True)
    work = safety_jobs(out, {recipe.name: str(ckpt)}, _seeds(g["seeds"], quick), scenarios, vehicles=(recipe.scenario,), acc=False)
    if quick:
        work = [dataclasses.replace(j, duration=QUICK_SECONDS) for j in work]
    drive_jobs(work, jobs, f"gates {recipe.name}: safety")
    checks, closest = [], math.inf
    for scenario in scenarios:
        scores = [score_run(j.log) for j in work if j.trajectory == scenario]
        passed, low = sum(s["passed"] for s in scores), min(s["min_gap_m"] for s in scores)
        closest = min(closest, low)
        checks.append(Check("safety", f"{scenario}: runs passed", float(passed), float(len(scores)), passed == len(scores), f"min gap {low:.1f} m"))
    return checks, [Measure("safety", CLOSEST_GAP, float(closest))]


def _random_checks(recipe: Recipe, ckpt: Path, out: Path, quick: bool, jobs: int) -> tuple[list[Check], list[Measure]]:
    """The held-out random leads: the worst gap RMSE, and no collision; their measures (the
    ACC drives the same leads)."""
    if "random" not in recipe.gates:
        return [], []
    g = recipe.gates["random"]
    out = out / "random"
    (out / "logs").mkdir(parents=True, exist_ok=True)
    work = random_jobs(out, {recipe.name: str(ckpt)}, recipe.scenario, _seeds(g["seeds"], quick), acc=True,
                       duration=QUICK_SECONDS if quick else None)  # fmt: skip
    drive_jobs(work, jobs, f"gates {recipe.name}: random")
    settle = 0.0 if quick else SETTLE_S
    scores = [score_random_run(j, VEHICLES[recipe.scenario], settle) for j in work if j.method != "acc"]
    acc = [score_random_run(j, VEHICLES[recipe.scenario], settle) for j in work if j.method == "acc"]
    worst = max(float(s["gap_rmse_55m_m"]) for s in scores)
    collisions = float(sum(s["collisions"] for s in scores))
    bound = float(g["max_gap_rmse_m"])
    checks = [Check("random", "worst gap RMSE (m)", worst, bound, worst <= bound), Check("random", "collisions", collisions, 0.0, collisions == 0)]
    return checks, _measures("random", scores, acc, ENERGY[recipe.scenario][0])


def evaluate_gates(recipe: Recipe, checkpoint: Path, out: Path, *, quick: bool = False, jobs: int = 1,
                   skip: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """Drive ``checkpoint`` through every gate of ``recipe`` but the sets of runs in ``skip``
    (:data:`PARTS`); write ``out/gates.json``.

    Returns:
        The report: recipe, its digest, the checkpoint and its SHA-256, each check, and
        whether all passed.

    Raises:
        click.ClickException: a run failed or its log is invalid.
    """
    out.mkdir(parents=True, exist_ok=True)
    checks: list[Check] = []
    measures: list[Measure] = []
    unknown = sorted(set(skip) - set(PARTS))
    if unknown or set(skip) >= set(PARTS):
        raise ValueError(f"skip: {unknown or list(skip)}: give some of {', '.join(PARTS)}, not all")
    for name, part in zip(PARTS, (_test_checks, _safety_checks, _random_checks), strict=True):
        if name in skip:
            continue
        c, m = part(recipe, checkpoint, out, quick, jobs)
        checks += c
        measures += m
    report = {
        "recipe": recipe.name, "recipe_digest": recipe.digest, "checkpoint": str(checkpoint), "sha256": file_sha256(checkpoint),
        "quick": quick, "skipped": [p for p in PARTS if p in skip], "checks": [c._asdict() for c in checks], "passed": all(c.passed for c in checks),
        "measures": [m._asdict() for m in measures], "cpu_path": pinned_path(),
        "kernels": describe(with_gpu=False).get("kernels"),  # torch's name for them; the run workers fork from here
    }  # fmt: skip
    (out / "gates.json").write_text(json.dumps(report, indent=1) + "\n")
    return report


def gate_table(report: dict[str, Any]) -> str:
    """The report as a markdown table, one row per check, and a verdict line."""
    lines = ["| gate | check | figure | bound | verdict |", "| --- | --- | --- | --- | --- |"]
    for c in report["checks"]:
        what = c["what"] + (f" ({c['detail']})" if c.get("detail") else "")
        lines.append(f"| {c['gate']} | {what} | {c['figure']:.3f} | {c['bound']:g} | {'PASS' if c['passed'] else 'FAIL'} |")
    n = sum(c["passed"] for c in report["checks"])
    verdict = "PASS" if report["passed"] else "FAIL"
    note = " (--quick: short runs, figures not meaningful)" if report["quick"] else ""
    note += f" on {report['cpu_path']} kernels" if "cpu_path" in report else ""
    note += "".join(f"; {p} not checked (--skip)" for p in report.get("skipped", []))
    lines.append(f"\n{report['recipe']}: {verdict}, {n}/{len(report['checks'])} checks passed{note}")
    return "\n".join(lines)


@click.command("gates")
@click.argument("model_or_recipe")
@click.option("--checkpoint", default=None, type=click.Path(dir_okay=False, exists=True), help="The checkpoint to check. Default: the shipped <models>/<name>.pt (" + MODELS_DEFAULT + ").")
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder for gates.json and the run logs.")
@click.option("--quick", is_flag=True, help="Short runs, one seed, two safety scenarios: checks the gates run (tests), not the model.")
@click.option("--skip", multiple=True, type=click.Choice(PARTS[1:]), help="Leave out this set of runs (repeatable): the verdict is over the checks run, and the report says so.")
@click.option("--jobs", default=os.cpu_count() or 1, show_default=True, type=click.IntRange(1, 64), help="Runs in parallel.")
@click.option("--cpu-path", type=click.Choice(list(CPU_PATHS)), default=None,
              help="The CPU kernels the runs drive on. Default: the recipe's, as `vacc reproduce` checks its model (a last-bit difference can move a decision).")  # fmt: skip
def gates(model_or_recipe: str, checkpoint: str | None, out: str, quick: bool, skip: tuple[str, ...], jobs: int, cpu_path: str | None) -> None:
    """Check a checkpoint against the gates of a recipe (a model name, or recipes/NAME.toml):
    print a pass/fail table with the figures and write OUT/gates.json. Exits 1 if a gate fails."""
    try:
        recipe = load_recipe(model_or_recipe)
    except RecipeError as exc:
        raise click.ClickException(str(exc)) from None
    try:
        use_cpu_path(cpu_path or recipe.cpu_path)  # before torch computes: the runs' worker processes inherit it
    except RuntimeError as exc:
        raise click.ClickException(str(exc)) from None
    ckpt = Path(checkpoint) if checkpoint else models_dir() / f"{recipe.name}.pt"
    if not ckpt.is_file():
        raise click.ClickException(f"{ckpt}: no such checkpoint; give --checkpoint")
    report = evaluate_gates(recipe, ckpt, Path(out), quick=quick, jobs=jobs, skip=skip)
    click.echo(gate_table(report))
    click.echo(f"Wrote {out}/gates.json")
    if not report["passed"]:
        raise SystemExit(1)
