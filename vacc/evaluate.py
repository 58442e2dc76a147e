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
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import click
import numpy as np

from energy import SETTLE_S, evaluate_run
from energy.comfort import ISO_DECEL_LIMIT_MPS2, ISO_JERK_LIMIT_MPS3
from protocol.scenarios import TEST_TRAJECTORIES
from vacc.metrics_cmd import finite_non_negative
from vacc.paths import MODELS_DEFAULT, models_dir

TRAJECTORIES = TEST_TRAJECTORIES  # the tables are over the paper's test set
METHODS = ("lead", "ddqn-gap", "ddqn-force", "ddqn-eco", "acc", "human")
LABELS = {
    "lead": "Lead vehicle",
    "ddqn-gap": "Gap-based DDQN",
    "ddqn-force": "Force-based DDQN",
    "ddqn-eco": "Eco DDQN (force steps)",
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
    Row("Min gap", "gap_min_m", "m", 2, "min", follower_only=True),
    Row("Min time-to-collision", "ttc_min_s", "s", 2, "min", follower_only=True),
    Row("Min time headway", "headway_min_s", "s", 2, "min", follower_only=True),
    Row("Max speed", "speed_max_mps", "m/s", 2, "max"),
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

# The paper's Tables 3 and 4 (Wei et al. 2019), for comparison.
PAPER: dict[str, dict[str, Any]] = {
    "ice": {
        "columns": ["Gap-based DDQN", "Force-based DDQN", "Traditional ACC", "Human"],
        "rows": {
            "Fuel (g/mi)": [169.3, 143.8, 143.8, 198.6],
            "Gap RMSE to 55 m (m)": [3.423, 7.686, 6.667, 6.591],
        },
    },
    "ev": {
        "columns": ["Gap-based DDQN", "Force-based DDQN", "Traditional ACC", "Human"],
        "rows": {
            "Energy (kJ/mi)": [4.914e3, 2.056e3, 1.128e3, 1.500e3],
            "Gap RMSE to 55 m (m)": [5.083, 10.98, 17.44, 5.439],
        },
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
    with local_server(stderr=subprocess.DEVNULL) as addr, Session(addr, image_format=image, image_size=size, client_name=f"vacc-evaluate/{job.method}") as s:
        drive_episode(s, controller, scenario=job.scenario, seed=job.seed, trajectory=job.trajectory, duration=job.duration, log=log)
    if job.method == "lead":
        _lead_log(log, Path(job.log))
        log.unlink()
    return job


def drive_jobs(work: list[Job], jobs: int, label: str) -> None:
    """Drive every job, ``jobs`` at a time (each in its own process with its own server).

    Raises:
        click.ClickException: a run failed; the others are cancelled.
    """
    with ProcessPoolExecutor(max_workers=min(jobs, len(work))) as pool, click.progressbar(length=len(work), label=label, file=None) as bar:
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


def build_tables(
    out: Path, scenario: str, methods: list[str], labels: dict[str, str], vehicle: str,
    settle: float = SETTLE_S,
) -> dict[str, Any]:
    """Score every log, write table.md/table.csv; returns the combined metrics per method.

    Args:
        settle: seconds at the start of each run left out of the comfort rows [s].
    """
    rows = (ICE_ROWS if scenario == "ice" else EV_ROWS) + DRIVING_ROWS + COMFORT_ROWS
    per: dict[str, dict[str, dict[str, Any]]] = {}
    for method in methods:
        per[method] = {}
        for traj in TRAJECTORIES:
            log = out / "logs" / f"{method}-{traj}.csv"
            if log.exists():
                per[method][traj] = evaluate_run(log, vehicle, settle_s=settle)
    trajs = [t for t in TRAJECTORIES if all(t in per[m] for m in methods)]

    def value(method: str, traj: str | None, row: Row) -> Any:
        if method == "lead" and row.follower_only:
            return None
        vals = [per[method][t][row.key] for t in ([traj] if traj else trajs)]
        vals = [v for v in vals if v is not None]  # None: undefined on that run (no closing-in)
        return COMBINE[row.combine](vals) if vals else None

    def shown(method: str, traj: str | None, row: Row, decimals: int) -> str:
        v = value(method, traj, row)
        return _fmt(None if v is None else v * row.scale, decimals)

    cols = [labels[m] for m in methods]
    lines = [f"# {scenario.upper()} results ({'CMEM ' + vehicle if scenario == 'ice' else 'EV eq. 6 ' + vehicle}), average of {len(trajs)} trajectories", ""]

    def table(traj: str | None) -> list[str]:
        t = ["| Metric | " + " | ".join(cols) + " |", "| --- |" + " --- |" * len(cols)]
        for row in rows:
            name = f"{row.label} ({row.unit})" if row.unit else row.label
            t.append(f"| {name} | " + " | ".join(shown(m, traj, row, row.decimals) for m in methods) + " |")
        return t

    lines += table(None)
    lines += [
        "",
        "Collisions are summed, minimum gap, time-to-collision and headway are minima and the maximum speed is "
        "the maximum over the runs; the rest are means.",
        f"The last {len(COMFORT_ROWS)} rows (comfort) leave out the first {settle:g} s of each run (`--settle`); "
        "every other row is over the whole run. ISO 15622 limits: mean deceleration over any 2 s "
        f"≤ {ISO_DECEL_LIMIT_MPS2:g} m/s², mean jerk over any 1 s ≤ {ISO_JERK_LIMIT_MPS3:g} m/s³.",
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
                w.writerow([which or "mean", row.label, row.unit, *[shown(m, which, row, 6 if row.decimals else 0) for m in methods]])
    return {m: {row.key: value(m, None, row) for row in rows} for m in methods}


def plot_runs(out: Path, methods: list[str], labels: dict[str, str], traj: str = "test-1") -> None:
    """fig_gap.png and fig_speed.png for one trajectory, like the paper's Fig. 5c/5d."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    logs = {m: np.genfromtxt(out / "logs" / f"{m}-{traj}.csv", delimiter=",", names=True) for m in methods}
    fig, ax = plt.subplots(figsize=(9, 4))
    for m, d in logs.items():
        if m != "lead":
            ax.plot(d["t"], d["gap"], label=labels[m], lw=1)
    ax.axhline(55.0, color="k", ls="--", lw=0.8, label="desired gap 55 m")
    ax.set(xlabel="time [s]", ylabel="gap [m]", title=f"Gap, {traj}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "fig_gap.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 4))
    any_log = next(iter(logs.values()))
    ax.plot(any_log["t"], any_log["v_lead"], color="k", lw=1.5, label="lead vehicle")
    for m, d in logs.items():
        if m != "lead":
            ax.plot(d["t"], d["v_host"], label=labels[m], lw=1)
    ax.set(xlabel="time [s]", ylabel="speed [m/s]", title=f"Speed, {traj}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "fig_speed.png", dpi=110)
    plt.close(fig)


def plot_pareto(out: Path, scenario: str, methods: list[str], labels: dict[str, str], vehicle: str, settle: float = SETTLE_S) -> None:
    """fig_pareto.png/.pdf: gap RMSE against energy, one point per method, coloured by the
    share of 1-s windows over ISO 15622's jerk limit; one panel per trajectory and their mean.

    Lower left is better on both axes; a pale point rides more comfortably than a dark one.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    energy_key, energy_label = ("fuel_g_per_mi", "fuel [g/mi]") if scenario == "ice" else ("energy_kj_per_mi", "energy [kJ/mi]")
    followers = [m for m in methods if m != "lead"]
    points: dict[str, dict[str, tuple[float, float, float]]] = {}
    for traj in TRAJECTORIES:
        for m in followers:
            log = out / "logs" / f"{m}-{traj}.csv"
            if log.exists():
                r: dict[str, Any] = evaluate_run(log, vehicle, settle_s=settle)
                points.setdefault(traj, {})[m] = (float(r[energy_key]), float(r["gap_rmse_55m_m"]), float(r["iso_jerk_window_share"] or 0.0))
    complete = [t for t in points if all(m in points[t] for m in followers)]
    if complete:
        points["mean of " + str(len(complete))] = {m: tuple(float(np.mean([points[t][m][i] for t in complete])) for i in range(3)) for m in followers}  # type: ignore[misc]
    panels = list(points) or ["no runs"]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 3.4), squeeze=False, sharey=False)
    markers = dict(zip(followers, "osD^vP*X", strict=False))
    sc = None
    for ax, name in zip(axes[0], panels, strict=True):
        if name not in points:
            ax.text(0.5, 0.5, f"no runs in {out / 'logs'}", ha="center", va="center", transform=ax.transAxes)
            continue
        for m, (e, rmse, jerk) in points[name].items():
            sc = ax.scatter([e], [rmse], c=[100.0 * jerk], cmap="viridis_r", vmin=0.0, vmax=100.0, marker=markers[m], s=60, edgecolors="k", label=labels[m])
        ax.set(title=name, xlabel=energy_label)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("gap RMSE to 55 m [m]")
    if sc is not None:
        axes[0][0].legend(fontsize=7, loc="best")
        fig.colorbar(sc, ax=axes[0].tolist(), label=f"1-s windows over {ISO_JERK_LIMIT_MPS3:g} m/s³ [%]")
    fig.suptitle(f"{scenario.upper()}: gap against energy (lower left is better)", fontsize=10)
    for ext in ("png", "pdf"):
        fig.savefig(out / f"fig_pareto.{ext}", dpi=110)
    plt.close(fig)


def plot_training(out: Path, models: Path, scenario: str) -> None:
    """fig_training.png from the shipped models' training curves (``<model>.curve.csv``: step,avg_reward;
    ``#`` lines are comments)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    found = False
    for reward in ("gap", "force", "eco"):
        curve = models / f"{scenario}-{reward}.curve.csv"
        if curve.exists():
            rows = [r for r in csv.DictReader(line for line in curve.open() if not line.startswith("#"))]
            try:
                steps = [int(r["step"]) for r in rows]
                values = [float(r["avg_reward"]) for r in rows]
            except (KeyError, TypeError, ValueError):
                raise click.ClickException(f"{curve}: expected columns step,avg_reward") from None
            ax.plot(steps, values, label=f"{reward}-based DDQN")
            found = True
    if not found:
        ax.text(0.5, 0.5, f"no training curves shipped in {models}", ha="center", va="center", transform=ax.transAxes)
    ax.set(xlabel="training step", ylabel="average reward", title=f"Training, {scenario.upper()} (like Fig. 5a/5b)")
    if found:
        ax.legend()
    fig.tight_layout()
    fig.savefig(out / "fig_training.png", dpi=110)
    plt.close(fig)


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


@click.command("evaluate")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(["ice", "ev"]))
@click.option("--out", required=True, type=click.Path(file_okay=False), help="Folder for tables, figures and run logs.")
@click.option("--methods", default=None, help="Comma-separated subset of: " + ", ".join(METHODS) + f". Default: all; {', '.join(OPTIONAL)} only where its model is in --models.")
@click.option("--models", default=lambda: str(models_dir()), show_default=MODELS_DEFAULT, type=click.Path(file_okay=False), help="Where <scenario>-gap.pt and <scenario>-force.pt are.")
@click.option("--human-file", "human_files", multiple=True, metavar="TRAJ=PATH", help="Recorded human drive for a trajectory; else the Human Driver Model.")
@click.option("--vehicle", default=None, type=click.Choice(["corolla", "average", "leaf"]), help="Energy model; default corolla (ICE) or leaf (EV).")
@click.option("--duration", default=None, type=click.FloatRange(min=0.5), help="Drive only this many seconds of each trajectory.")
@click.option("--seed", default=0, show_default=True, type=int, help="Episode seed (initial conditions, traffic).")
@click.option("--jobs", default=os.cpu_count() or 1, show_default=True, type=click.IntRange(1, 64), help="Runs in parallel.")
@click.option("--settle", default=SETTLE_S, show_default=True, type=float, callback=finite_non_negative, help="Seconds at the start of each run left out of the comfort rows [s].")
@click.option("--suite", default="paper", show_default=True, type=click.Choice(["paper", "safety"]), help="paper: Tables 3/4 on test-1..test-4. safety: the ACC and every model in --models through every lead scenario (docs/scenarios.md) over --seeds, with a pass/fail table.")
@click.option("--seeds", default="0-9", show_default=True, help="--suite safety: episode seeds, e.g. 0-9 or 0,3,5.")
def evaluate(scenario: str, out: str, methods: str | None, models: str, human_files: tuple[str, ...], vehicle: str | None, duration: float | None, seed: int, jobs: int, settle: float, suite: str, seeds: str) -> None:
    """Run every method on test-1..test-4 over UDP and write the paper's tables and figures
    (or, with --suite safety, drive every lead scenario and write a pass/fail table)."""
    if suite == "safety":
        from vacc.safety import parse_seeds, run_suite

        try:
            seed_list = parse_seeds(seeds)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--seeds") from None
        found = {p.stem: str(p) for p in sorted(Path(models).glob("*.pt")) if p.stem.split("-")[0] in ("ice", "ev")}
        click.echo(run_suite(Path(out), found, seed_list, jobs))
        click.echo(f"Wrote {out}/safety.md, safety.csv and logs/")
        return
    if methods is None:
        methods = ",".join(m for m in METHODS if m not in OPTIONAL or (Path(models) / f"{scenario}-{m.removeprefix('ddqn-')}.pt").is_file())
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = sorted(set(chosen) - set(METHODS))
    if unknown:
        raise click.BadParameter(f"unknown methods {unknown}; choose from {list(METHODS)}", param_hint="--methods")
    files = _parse_human_files(human_files)
    models_dir = Path(models)
    checkpoints = {}
    for m in chosen:
        if m.startswith("ddqn-"):
            path = models_dir / f"{scenario}-{m.removeprefix('ddqn-')}.pt"
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
    work = [
        Job(m, t, scenario, seed, str(out_dir / "logs" / f"{m}-{t}.csv"), duration, checkpoints.get(m), files.get(t) if m == "human" else None)
        for m in chosen
        for t in TRAJECTORIES
    ]
    drive_jobs(work, jobs, f"evaluate {scenario}")
    veh = vehicle or DEFAULT_VEHICLE[scenario]
    build_tables(out_dir, scenario, chosen, labels, veh, settle)
    plot_runs(out_dir, chosen, labels)
    plot_training(out_dir, models_dir, scenario)
    plot_pareto(out_dir, scenario, chosen, labels, veh, settle)
    click.echo((out_dir / "table.md").read_text().split("\n## ")[0])
    click.echo(f"Wrote {out_dir}/table.md, table.csv, fig_gap.png, fig_speed.png, fig_training.png, fig_pareto.png/.pdf and logs/")
