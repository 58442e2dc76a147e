"""`vacc evaluate`: every method on the same trajectories, scored as the paper's Tables 3 and 4.

Each run is a real simulator process and a client over UDP. The lead vehicle is
scored on its own trajectory (as in the paper); its logs carry the lead's speed as
``v_host`` and a 55 m placeholder gap, so gap rows are blank for it.

Besides the paper's rows, every table has the safety minima and the comfort rows
(ISO 15622 windows, jerk RMS, sign changes; ``docs/results.md``, "Comfort metrics").
The comfort rows leave out the first ``--settle`` seconds of each run.
"""

from __future__ import annotations

import csv
import math
import os
import subprocess
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import click
import numpy as np

from agent_client.drive import COLD_START_HELP
from agent_client.launcher import DEFAULT_ROAD, Road
from agent_client.outputs import writable_dir_option
from agent_client.progress import progress_bar
from energy import SETTLE_S, RunLog, RunLogError, evaluate_run, read_run_log
from energy.comfort import ISO_DECEL_LIMIT_MPS2, ISO_JERK_LIMIT_MPS3
from energy.metrics import Metrics
from protocol.constants import SUN_ELEVATION, TRAFFIC_PER_LANE, TRAFFIC_PER_LANE_RANGE
from protocol.options import SunElevation
from protocol.scenarios import (
    DEFAULT_SET_SPEED,
    LEAD_SCENARIOS,
    SCENARIOS,
    TEST_TRAJECTORIES,
)
from vacc import stats
from vacc.metrics_cmd import finite_non_negative
from vacc.paths import MODELS_DEFAULT, models_dir

TRAJECTORIES = TEST_TRAJECTORIES  # the tables are over the paper's test set
METHODS = ("lead", "ddqn-gap", "ddqn-force", "ddqn-eco", "acc", "human")
SUITE_METHODS = ("acc", "ddqn-gap", "ddqn-force", "ddqn-eco")  # what --suite safety drives
LABELS = {
    "lead": "Lead vehicle",
    "ddqn-gap": "Gap-based DDQN",
    "ddqn-force": "Force-based DDQN",
    "ddqn-eco": "Eco DDQN",
    "acc": "Traditional ACC",
}
OPTIONAL = ("ddqn-eco",)  # beyond the paper: in the default methods only where its model is shipped
HDM_LABEL = "Human Driver Model (Treiber et al. 2006)"
DEFAULT_VEHICLE = {"ice": "corolla", "ev": "leaf"}


class Row(NamedTuple):
    """One row of a results table: a metric of :func:`energy.evaluate_run`, as shown."""

    label: str
    key: str
    unit: str
    decimals: int
    combine: str = "mean"
    """How the runs of one method combine: mean, sum, min or max."""
    scale: float = 1.0
    """Display factor (a share as %); evaluate_run's value is SI or a fraction."""
    follower_only: bool = False
    """Blank for the lead: its log has a 55 m placeholder gap."""
    better: str = "lower"
    """Which way is better, as the tables say it: lower, higher, or a bound."""


ICE_ROWS = [
    Row("Fuel", "fuel_g_per_mi", "g/mi", 1),
    Row("CO2", "co2_g_per_mi", "g/mi", 1),
    Row("CO", "co_g_per_mi", "g/mi", 3),
    Row("HC", "hc_g_per_mi", "g/mi", 4),
    Row("NOx", "nox_g_per_mi", "g/mi", 4),
]
EV_ROWS = [Row("Energy", "energy_kj_per_mi", "kJ/mi", 1)]
DRIVING_ROWS = [
    Row("Gap RMSE to 55 m", "gap_rmse_55m_m", "m", 3, follower_only=True),
    Row("Collisions", "collisions", "", 0, "sum", follower_only=True),
    Row("Min gap", "gap_min_m", "m", 2, "min", follower_only=True, better="higher"),
    Row("Min time-to-collision", "ttc_min_s", "s", 2, "min", follower_only=True, better="higher"),
    Row("Min time headway", "headway_min_s", "s", 2, "min", follower_only=True, better="higher"),
    Row("Max speed", "speed_max_mps", "m/s", 2, "max", better=f"≤ {DEFAULT_SET_SPEED:g}"),
    # from engagement, as the safety figures: a phantom brake at the start is still one
    Row(f"Unprompted hard brakes (past {ISO_DECEL_LIMIT_MPS2:g} m/s^2, no threat ahead)", "unprompted_hard_brakes", "", 0, "sum",
        follower_only=True),
]
# After --settle (energy.metrics): the ride, judged by ISO 15622 (energy.comfort).
COMFORT_ROWS = [
    Row("Jerk RMS", "jerk_rms_mps3", "m/s^3", 3),
    Row(f"ISO jerk: 1-s windows over {ISO_JERK_LIMIT_MPS3:g} m/s^3", "iso_jerk_window_share",
        "%", 1, scale=100.0),
    Row(f"ISO decel: 2-s windows over {ISO_DECEL_LIMIT_MPS2:g} m/s^2", "iso_decel_window_share",
        "%", 1, scale=100.0),
    Row("Accel sign changes", "accel_sign_changes_per_min", "1/min", 1),
]
COMBINE: dict[str, Callable[[list[Any]], Any]] = {
    "mean": lambda v: float(np.mean(v)), "sum": lambda v: int(sum(v)),
    "min": min, "max": max,
}

# The paper's Tables 3 and 4 (Wei et al. 2019), for comparison. "methods": our method of
# each column; "keys": the metric of energy.evaluate_run of each row.
PAPER: dict[str, dict[str, Any]] = {
    "ice": {
        "columns": ["Gap-based DDQN", "Force-based DDQN", "Traditional ACC", "Human"],
        "methods": ["ddqn-gap", "ddqn-force", "acc", "human"],
        "rows": {
            "Fuel (g/mi)": [169.3, 143.8, 143.8, 198.6],
            "Gap RMSE to 55 m (m)": [3.423, 7.686, 6.667, 6.591],
        },
        "keys": {"Fuel (g/mi)": "fuel_g_per_mi", "Gap RMSE to 55 m (m)": "gap_rmse_55m_m"},
    },
    "ev": {
        "columns": ["Gap-based DDQN", "Force-based DDQN", "Traditional ACC", "Human"],
        "methods": ["ddqn-gap", "ddqn-force", "acc", "human"],
        "rows": {
            "Energy (kJ/mi)": [4.914e3, 2.056e3, 1.128e3, 1.500e3],
            "Gap RMSE to 55 m (m)": [5.083, 10.98, 17.44, 5.439],
        },
        "keys": {"Energy (kJ/mi)": "energy_kj_per_mi", "Gap RMSE to 55 m (m)": "gap_rmse_55m_m"},
    },
}


@dataclass(frozen=True)
class Job:
    """One method on one trajectory."""

    method: str
    trajectory: str
    scenario: str
    seed: int
    log: str
    duration: float | None
    checkpoint: str | None = None
    human_file: str | None = None
    cold_start: bool = False  # engage a DDQN policy at frame 0, without the camera's pre-roll
    road: Road = DEFAULT_ROAD  # the server's traffic and sun


def _controller(job: Job) -> Any:
    from agent_client.controllers import make_controller

    if job.method in ("human", "lead"):
        if not job.human_file:
            return make_controller("hdm", seed=job.seed)
        from agent_client.controllers.human_file import read_human_file

        replay = read_human_file(job.human_file)
        replay.check(scenario=job.scenario, trajectory=job.trajectory, seed=job.seed)
        return make_controller("human-file", human_file=replay, pad="hold")
    # every ddqn-* job has its checkpoint (evaluate() gives it one)
    return make_controller("ddqn" if job.method.startswith("ddqn") else job.method, checkpoint=job.checkpoint)


def run_job(job: Job) -> Job:
    """Drive one job through its own server process; returns it when its log is written."""
    import torch

    from agent_client.controllers import camera
    from agent_client.drive import drive_episode
    from agent_client.launcher import local_server
    from agent_client.session import Session

    torch.set_num_threads(1)  # one run per core
    controller = _controller(job)
    image, size = camera(controller)
    log = Path(job.log)
    if job.method == "lead":
        log = log.with_name(log.name + ".tmp")
    with local_server(*job.road.server_args(), stderr=subprocess.DEVNULL) as addr, Session(addr, image_format=image, image_size=size, client_name=f"vacc-evaluate/{job.method}") as s:
        drive_episode(s, controller, scenario=job.scenario, seed=job.seed, trajectory=job.trajectory, duration=job.duration, log=log,
                      preroll=0 if job.cold_start else None)  # fmt: skip
    if job.method == "lead":
        _lead_log(log, Path(job.log))
        log.unlink()
    return job


def drive_jobs(work: list[Job], jobs: int, label: str) -> None:
    """Drive every job, ``jobs`` at a time (each in its own process with its own server).

    Raises:
        click.ClickException: a run failed; the others are cancelled.
    """
    with ProcessPoolExecutor(max_workers=min(jobs, len(work))) as pool, progress_bar(len(work), label, unit="run") as bar:
        futures = [pool.submit(run_job, j) for j in work]
        try:
            for fut in as_completed(futures):
                fut.result()
                bar.update(1)
        except Exception as exc:
            for f in futures:
                f.cancel()
            raise click.ClickException(f"a run failed: {exc}") from None


def _lead_log(follower: Path, out: Path) -> None:
    # The lead's own run: its speed and acceleration as the "host" of a log.
    with follower.open() as f, out.open("w", newline="\n") as g:
        reader = csv.DictReader(f)
        assert reader.fieldnames is not None
        g.write(",".join(reader.fieldnames) + "\n")
        for row in reader:
            row.update(v_host=row["v_lead"], accel=row["a_lead"], gap="55.0", force="0.0", collision="0")
            g.write(",".join(row[k] for k in reader.fieldnames) + "\n")


def _fmt(value: Any, decimals: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.{decimals}f}"


def seed_text(seeds: Sequence[int]) -> str:
    """Seeds as ranges, the way ``--seeds`` takes them: [0, 1, 2, 5] -> "0-2,5"."""
    parts: list[str] = []
    for s in sorted(seeds):
        if parts and parts[-1].split("-")[-1] == str(s - 1):
            parts[-1] = f"{parts[-1].split('-')[0]}-{s}"
        else:
            parts.append(str(s))
    return ",".join(parts)


def log_path(out: Path, method: str, trajectory: str, seed: int | None = None) -> Path:
    """Run log of one run: ``logs/<method>-<trajectory>.csv`` when the evaluation has one
    seed (``seed`` None), ``logs/<method>-<trajectory>-seed<N>.csv`` when it has several."""
    return out / "logs" / (f"{method}-{trajectory}.csv" if seed is None else f"{method}-{trajectory}-seed{seed}.csv")


class Run(NamedTuple):
    """One scored run: a method on a trajectory with one seed."""

    method: str
    trajectory: str
    seed: int | None
    """None: the one seed of a single-seed evaluation (its log has no seed in its name)."""
    log: RunLog
    metrics: Metrics


def score_runs(out: Path, methods: Sequence[str], vehicle: str, settle: float = SETTLE_S, seeds: Sequence[int] | None = None) -> list[Run]:
    """Read and score every run log of ``out/logs`` that exists (see :func:`log_path`).

    Raises:
        click.ClickException: a log is invalid.
    """
    runs = []
    for method in methods:
        for traj in TRAJECTORIES:
            for seed in seeds if seeds is not None else [None]:
                path = log_path(out, method, traj, seed)
                if path.exists():
                    try:
                        log = read_run_log(path)
                    except RunLogError as exc:
                        raise click.ClickException(str(exc)) from None
                    runs.append(Run(method, traj, seed, log, evaluate_run(log, vehicle, settle_s=settle)))
    return runs


def build_tables(
    out: Path, scenario: str, methods: list[str], labels: dict[str, str], vehicle: str,
    settle: float = SETTLE_S, seeds: Sequence[int] | None = None, runs: list[Run] | None = None, road: Road = DEFAULT_ROAD,
) -> dict[str, Any]:
    """Score every log, write table.md/table.csv; returns the combined metrics per method.

    Over several ``seeds`` each mean row is shown with its 95 % bootstrap confidence
    interval (:mod:`vacc.stats`), table.md gains an interquartile-mean table, and
    stats.csv holds every estimate.

    Args:
        settle: seconds at the start of each run left out of the comfort rows [s].
        seeds: the seeds of a multi-seed evaluation; None: one seed.
        runs: the scored runs, if already at hand (:func:`score_runs`).
        road: the runs' traffic and sun (named in the title unless the default).
    """
    rows = (ICE_ROWS if scenario == "ice" else EV_ROWS) + DRIVING_ROWS + COMFORT_ROWS
    if runs is None:
        runs = score_runs(out, methods, vehicle, settle, seeds)
    per: dict[str, dict[str, list[Metrics]]] = {m: {} for m in methods}
    for run in runs:
        per[run.method].setdefault(run.trajectory, []).append(run.metrics)
    trajs = [t for t in TRAJECTORIES if all(t in per[m] for m in methods)]
    multi = seeds is not None and len(seeds) > 1

    def samples(method: str, traj: str | None, row: Row) -> list[list[float]]:
        """The row's values, one list (over seeds) per trajectory; None (undefined on a run) left out."""
        groups = [[float(r[row.key]) for r in per[method][t] if r[row.key] is not None] for t in ([traj] if traj else trajs)]  # type: ignore[arg-type]
        return [g for g in groups if g]

    def estimate(method: str, traj: str | None, row: Row, statistic: stats.Statistic = stats.mean) -> stats.Estimate | None:
        if method == "lead" and row.follower_only:
            return None
        groups = samples(method, traj, row)
        if not groups:
            return None
        if row.combine != "mean" or not multi:  # one seed: no interval to show
            pooled = [x for g in groups for x in g]
            v = COMBINE[row.combine](pooled) if row.combine != "mean" else float(statistic(np.array(pooled))[()])
            return stats.Estimate(v, v, v, len(pooled))
        return stats.bootstrap_ci(groups, statistic)

    def value(method: str, traj: str | None, row: Row) -> Any:
        e = estimate(method, traj, row)
        if e is None:
            return None
        return int(e.value) if row.combine == "sum" else e.value

    def shown(method: str, traj: str | None, row: Row, decimals: int, statistic: stats.Statistic = stats.mean) -> str:
        e = estimate(method, traj, row, statistic)
        if e is None:
            return _fmt(None, decimals)
        text = _fmt(int(e.value) if row.combine == "sum" else e.value * row.scale, decimals)
        if multi and row.combine == "mean":
            text += f" [{_fmt(e.low * row.scale, decimals)}, {_fmt(e.high * row.scale, decimals)}]"
        return text

    cols = [labels[m] for m in methods]
    model = "CMEM " + vehicle if scenario == "ice" else "EV eq. 6 " + vehicle
    over = f"{len(trajs)} trajectories × {len(seeds)} seeds ({seed_text(seeds)})" if multi and seeds else f"{len(trajs)} trajectories"
    lines = [f"# {scenario.upper()} results ({model}), average of {over}{road.note()}", ""]

    def table(traj: str | None, table_rows: list[Row] = rows, statistic: stats.Statistic = stats.mean) -> list[str]:
        t = ["| Metric | Better | " + " | ".join(cols) + " |", "| --- | --- |" + " --- |" * len(cols)]
        for row in table_rows:
            name = f"{row.label} ({row.unit})" if row.unit else row.label
            t.append(f"| {name} | {row.better} | " + " | ".join(shown(m, traj, row, row.decimals, statistic) for m in methods) + " |")
        return t

    lines += table(None)
    lines += [
        "",
        f"Better: which way a row improves (max speed: at most the set speed, {DEFAULT_SET_SPEED:g} m/s). "
        "Collisions are summed, minimum gap, time-to-collision and headway are minima and the maximum speed is "
        "the maximum over the runs; the rest are means.",
        f"The last {len(COMFORT_ROWS)} rows (comfort) leave out the first {settle:g} s of each run (`--settle`); "
        "every other row is over the whole run. ISO 15622 limits: mean deceleration over any 2 s "
        f"≤ {ISO_DECEL_LIMIT_MPS2:g} m/s², mean jerk over any 1 s ≤ {ISO_JERK_LIMIT_MPS3:g} m/s³.",
        "",
    ]
    mean_rows = [r for r in rows if r.combine == "mean"]
    if multi:
        lines[-1:-1] = [
            f"[low, high]: {stats.CONFIDENCE:.0%} stratified bootstrap confidence interval of the mean "
            f"(seeds resampled within each trajectory, {stats.N_RESAMPLES} resamples, generator seed "
            f"{stats.BOOTSTRAP_SEED}); in the per-trajectory tables, over that trajectory's seeds. "
            "Sums, minima and maxima have no interval.",
        ]
        lines += ["## Interquartile mean (rliable)", ""]
        lines += table(None, mean_rows, stats.iqm)
        lines += [
            "",
            "The mean of the middle half of the runs (each seed on each trajectory a run; "
            f"⌊n/4⌋ dropped at each end), with its {stats.CONFIDENCE:.0%} stratified bootstrap interval "
            "(Agarwal et al. 2021). It is robust to one outlying seed.",
            "",
        ]
    paper = PAPER[scenario]
    lines += [f"## The paper's Table {'3' if scenario == 'ice' else '4'} (Wei et al. 2019)", ""]
    lines += ["| Metric | " + " | ".join(paper["columns"]) + " |", "| --- |" + " --- |" * len(paper["columns"])]
    for name, vals in paper["rows"].items():
        lines.append(f"| {name} | " + " | ".join(f"{v:g}" for v in vals) + " |")
    lines += ["", "The paper's vehicle models and human drivers differ from ours; compare orders and ratios, not absolutes.", ""]
    for traj in trajs:
        lines += [f"## {traj}", ""] + table(traj) + [""]
    (out / "table.md").write_text("\n".join(lines))
    with (out / "table.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "metric", "unit", *cols])
        for which in [None, *trajs]:
            for row in rows:
                w.writerow([which or "mean", row.label, row.unit, *[_fmt(None if (v := value(m, which, row)) is None else v * row.scale, 6 if row.decimals else 0) for m in methods]])
    if multi:
        with (out / "stats.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["trajectory", "metric", "unit", "method", "statistic", "value", "ci_low", "ci_high", "runs"])
            for which in [None, *trajs]:
                for row in rows:
                    for m in methods:
                        for name, statistic in [(row.combine, stats.mean)] + ([("iqm", stats.iqm)] if row.combine == "mean" else []):
                            e = estimate(m, which, row, statistic)
                            if e is not None:
                                w.writerow([which or "mean", row.label, row.unit, labels[m], name,
                                            *(f"{x * row.scale:.6g}" for x in e[:3]), e.n])  # fmt: skip
    return {m: {row.key: value(m, None, row) for row in rows} for m in methods}


def _parse_human_files(values: tuple[str, ...]) -> dict[str, str]:
    files = {}
    for item in values:
        traj, sep, path = item.partition("=")
        if not sep or traj not in TRAJECTORIES:
            raise click.BadParameter(f"{item!r} is not TRAJ=PATH with TRAJ in test-1..test-4", param_hint="--human-file")
        if not Path(path).is_file():
            raise click.BadParameter(f"{path}: no such human-file", param_hint="--human-file")
        files[traj] = path
    return files


SAFETY_SEEDS = "0-9"
"""The safety suite's seeds when neither --seed nor --seeds is given (the paper suite's: 0)."""


def _seed_list(seed: int | None, seeds: str | None, suite: str) -> list[int]:
    """The episode seeds of --seed (one) or --seeds (a range or list), whichever is given.

    Raises:
        click.BadParameter: both are given, or --seeds is not a seed list.
    """
    from vacc.safety import parse_seeds

    if seed is not None and seeds is not None:
        raise click.BadParameter(f"give --seed {seed} or --seeds {seeds}, not both (--seed N is --seeds N)", param_hint="--seed/--seeds")
    if seed is not None:
        if seed < 0:
            raise click.BadParameter(f"{seed} is negative; a seed is >= 0", param_hint="--seed")
        return [seed]
    try:
        return parse_seeds(seeds if seeds is not None else SAFETY_SEEDS if suite == "safety" else "0")
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--seeds") from None


def _method_list(methods: str) -> list[str]:
    """--methods as a list.

    Raises:
        click.BadParameter: an unknown method.
    """
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = sorted(set(chosen) - set(METHODS))
    if unknown:
        raise click.BadParameter(f"unknown methods {unknown}; choose from {list(METHODS)}", param_hint="--methods")
    return chosen


def _suite_methods(methods: str) -> list[str]:
    """--methods for the safety suite, which drives the ACC and the DDQN models only.

    Raises:
        click.BadParameter: an unknown method, one the suite does not drive, or none at all.
    """
    chosen = _method_list(methods)
    other = sorted(set(chosen) - set(SUITE_METHODS))
    if other or not chosen:
        raise click.BadParameter(f"the safety suite drives {', '.join(SUITE_METHODS)} only, got {methods!r}", param_hint="--methods")
    return chosen


def _lead_scenarios(names: str | None, suite: str) -> tuple[str, ...]:
    """The safety suite's lead scenarios from --lead-scenarios (default: all of them).

    Raises:
        click.BadParameter: an unknown name, none at all, or the option without --suite safety.
    """
    if names is None:
        return tuple(LEAD_SCENARIOS)
    if suite != "safety":
        raise click.BadParameter("only the safety suite drives lead scenarios; add --suite safety", param_hint="--lead-scenarios")
    chosen = tuple(dict.fromkeys(n.strip() for n in names.split(",") if n.strip()))
    unknown = [n for n in chosen if n not in LEAD_SCENARIOS]
    if unknown or not chosen:
        raise click.BadParameter(f"{names!r} names {'unknown ' + ', '.join(unknown) if unknown else 'no scenario'}; expected some of {', '.join(LEAD_SCENARIOS)}", param_hint="--lead-scenarios")
    return chosen


@click.command("evaluate")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(["ice", "ev"]))
@click.option("--out", required=True, type=click.Path(file_okay=False), callback=writable_dir_option, help="Folder for tables, figures and run logs.")
@click.option("--methods", default=None, help="Comma-separated subset of: " + ", ".join(METHODS) + f". Default: all; {', '.join(OPTIONAL)} only where its model is in --models. With --suite safety: acc and the models of the chosen kinds (ev-eco.pt and ev-eco-*.pt are ddqn-eco); default: the ACC and every model.")
@click.option("--models", default=lambda: str(models_dir()), show_default=MODELS_DEFAULT, type=click.Path(file_okay=False), help="Where <scenario>-gap.pt and <scenario>-force.pt are.")
@click.option("--human-file", "human_files", multiple=True, metavar="TRAJ=PATH", help="Recorded human drive for a trajectory; else the Human Driver Model.")
@click.option("--vehicle", default=None, type=click.Choice(["corolla", "average", "leaf"]), help="Energy model; default corolla (ICE) or leaf (EV).")
@click.option("--duration", default=None, type=click.FloatRange(min=0.5), help="Drive only this many seconds of each trajectory.")
@click.option("--seeds", default=None, metavar="SEEDS", help=f"Episode seeds, a range or a list: 0-9, 0,3,5 or 0-2,7. Over several, the paper suite's tables give means with {stats.CONFIDENCE:.0%} bootstrap intervals and the interquartile mean, and the figures the spread over seeds. Default: 0 (paper), {SAFETY_SEEDS} (safety).")
@click.option("--seed", default=None, type=int, help="One episode seed (initial conditions, traffic, scenery); the same as --seeds N.")
@click.option("--jobs", default=os.cpu_count() or 1, show_default=True, type=click.IntRange(1, 64), help="Runs in parallel.")
@click.option("--settle", default=SETTLE_S, show_default=True, type=float, callback=finite_non_negative, help="Seconds at the start of each run left out of the comfort rows [s] (not of the unprompted hard brakes, counted from engagement).")
@click.option("--cold-start", is_flag=True, help=COLD_START_HELP)
@click.option("--lead-scenarios", default=None, metavar="NAMES", help="With --suite safety: only these lead scenarios, comma-separated. Default: every one (" + ", ".join(LEAD_SCENARIOS) + ").")
@click.option("--traffic", default=TRAFFIC_PER_LANE, show_default=True, type=click.IntRange(*TRAFFIC_PER_LANE_RANGE), help="Cars in each adjacent lane (twice as many oncoming) of every run: the spawned servers' --traffic. A camera policy's neighbours are what it may mistake for a threat.")
@click.option("--sun-elevation", default=",".join(map(str, SUN_ELEVATION)), show_default=True, type=SunElevation(), help="Range [rad] of each run's sun height: the spawned servers' --sun-elevation (the test trajectories keep a fixed sun). A low sun throws shadows across the lane, which a camera policy may take for a car.")
@click.option("--suite", default="paper", show_default=True, type=click.Choice(["paper", "safety"]), help="paper: Tables 3/4 on test-1..test-4. safety: the ACC and every model in --models through every lead scenario (docs/scenarios.md) over --seeds, with a pass/fail table; both vehicles unless --scenario is given.")
def evaluate(scenario: str, out: str, methods: str | None, models: str, human_files: tuple[str, ...], vehicle: str | None, duration: float | None, seeds: str | None, seed: int | None, jobs: int, settle: float, cold_start: bool, lead_scenarios: str | None, traffic: int, sun_elevation: tuple[float, float], suite: str) -> dict[str, Any] | None:
    """Run every method on test-1..test-4 over UDP and write the paper's tables and figures
    (or, with --suite safety, drive every lead scenario and write a pass/fail table).

    Returns the combined metrics per method of the paper suite (see build_tables).
    """
    seed_list = _seed_list(seed, seeds, suite)
    road = Road(traffic, sun_elevation)
    if suite == "paper" and road.sun_elevation != SUN_ELEVATION:
        raise click.BadParameter("test-1..test-4 keep a fixed sun; the lead scenarios draw theirs: add --suite safety", param_hint="--sun-elevation")
    leads = _lead_scenarios(lead_scenarios, suite)
    if suite == "safety":
        from vacc.safety import run_suite

        # Both vehicles, unless --scenario was given: then that one's ACC and models only.
        given = click.get_current_context().get_parameter_source("scenario") == click.core.ParameterSource.COMMANDLINE
        vehicles = (scenario,) if given else SCENARIOS
        found = {p.stem: str(p) for p in sorted(Path(models).glob("*.pt")) if p.stem.split("-")[0] in vehicles}
        with_acc = True
        if methods is not None:  # the ACC and the models of the chosen kinds only (ev-eco, ev-eco-b.pt: ddqn-eco)
            chosen = _suite_methods(methods)
            with_acc = "acc" in chosen
            found = {stem: path for stem, path in found.items() if "ddqn-" + (stem.split("-") + [""])[1] in chosen}
            if not with_acc and not found:
                raise click.BadParameter(f"no model of {', '.join(chosen)} for {', '.join(vehicles)} in {models}", param_hint="--methods")
        click.echo(run_suite(Path(out), found, seed_list, jobs, cold_start, vehicles, leads, acc=with_acc, road=road))
        click.echo(f"Wrote {out}/safety.md, safety.csv and logs/")
        return None
    if methods is None:
        methods = ",".join(m for m in METHODS if m not in OPTIONAL or (Path(models) / f"{scenario}-{m.removeprefix('ddqn-')}.pt").is_file())
    chosen = _method_list(methods)
    files = _parse_human_files(human_files)
    multi = len(seed_list) > 1
    if files and multi:
        raise click.BadParameter("a recorded drive is of one seed; give --human-file with one --seed", param_hint="--human-file")
    models_path = Path(models)
    checkpoints = {}
    for m in chosen:
        if m.startswith("ddqn-"):
            path = models_path / f"{scenario}-{m.removeprefix('ddqn-')}.pt"
            if not path.is_file():
                raise click.ClickException(
                    f"model file {path} not found. Train it with: vacc train --reward {m.removeprefix('ddqn-')} "
                    f"--scenario {scenario} --steps 200000 --out runs/{scenario}-{m.removeprefix('ddqn-')} "
                    f"(then copy runs/.../best.pt to {path}), or leave {m} out of --methods"
                )
            checkpoints[m] = str(path)
    labels = dict(LABELS)
    labels["human"] = "Human (recorded)" if files else HDM_LABEL
    out_dir = Path(out)
    (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    named = seed_list if multi else None  # one seed: logs/<method>-<trajectory>.csv as always
    work = [
        Job(m, t, scenario, s, str(log_path(out_dir, m, t, s if multi else None)), duration, checkpoints.get(m), files.get(t) if m == "human" else None, cold_start, road)
        for m in chosen
        for t in TRAJECTORIES
        for s in seed_list
    ]
    drive_jobs(work, jobs, f"evaluate {scenario}" + (f", seeds {seed_text(seed_list)}" if multi else ""))
    veh = vehicle or DEFAULT_VEHICLE[scenario]
    runs = score_runs(out_dir, chosen, veh, settle, named)
    result = build_tables(out_dir, scenario, chosen, labels, veh, settle, named, runs, road)
    from vacc import figures

    written = [
        *figures.plot_runs(out_dir, runs, labels, scenario),
        figures.plot_comfort(out_dir, runs, labels, scenario, settle),
        figures.plot_emissions(out_dir, runs, labels, scenario),
        figures.plot_headway(out_dir, runs, labels, scenario),
        figures.plot_pareto(out_dir, scenario, chosen, labels, veh, settle, seeds=named, runs=runs),
        figures.plot_training(out_dir, models_path, scenario),
    ]
    click.echo((out_dir / "table.md").read_text().split("\n## The paper")[0].rstrip())
    for w in written:
        if w.empty:
            click.echo(f"{w.name}: nothing to plot: {w.empty}")
    tables = "table.md, table.csv" + (", stats.csv" if multi else "")
    click.echo(f"\nWrote {out_dir}/{tables}, {', '.join(w.name for w in written)} (.png and .pdf each) and logs/")
    return result
