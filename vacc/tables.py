"""The results tables of `vacc evaluate`: the paper's Tables 3 and 4, and more rows.

Besides the paper's rows, every table has the safety minima and the comfort rows
(ISO 15622 windows, jerk RMS, sign changes; ``docs/results.md``, "Comfort metrics").
The comfort rows leave out the first ``--settle`` seconds of each run.

:func:`compute_table` gathers a table's values from the scored runs (:mod:`vacc.runs`);
one writer per file turns them into ``table.md``, ``table.csv`` and (over several seeds)
``stats.csv``; :func:`build_tables` does all three.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from agent_client.launcher import DEFAULT_ROAD, Road
from energy import SETTLE_S
from energy.comfort import ISO_DECEL_LIMIT_MPS2, ISO_JERK_LIMIT_MPS3
from energy.metrics import Metrics
from protocol.scenarios import DEFAULT_SET_SPEED
from vacc import stats
from vacc.runs import TRAJECTORIES, Run, score_runs, seed_text

__all__ = [
    "Row", "ICE_ROWS", "EV_ROWS", "RELATIVE_ROWS", "DRIVING_ROWS", "COMFORT_ROWS", "PAPER", "Table", "compute_table",
    "write_table_md", "write_table_csv", "write_stats_csv", "build_tables", "early_lines",
]  # fmt: skip


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
    relative_to: str | None = None
    """A method: each run's value over that method's on the same trajectory and seed (paired)."""

    @property
    def name(self) -> str:
        """The row's key in :func:`build_tables`' result: the metric's, or ``<metric>_vs_<method>``."""
        return self.key if self.relative_to is None else f"{self.key}_vs_{self.relative_to}"


ICE_ROWS = [
    Row("Fuel", "fuel_g_per_mi", "g/mi", 1),
    Row("CO2", "co2_g_per_mi", "g/mi", 1),
    Row("CO", "co_g_per_mi", "g/mi", 3),
    Row("HC", "hc_g_per_mi", "g/mi", 4),
    Row("NOx", "nox_g_per_mi", "g/mi", 4),
]
EV_ROWS = [Row("Energy", "energy_kj_per_mi", "kJ/mi", 1)]
# Paired: the seed's traffic and scenery are the same for both, so the ratio's interval is narrower than the two means'.
RELATIVE_ROWS = {
    "ice": Row("Fuel against the ACC, per run", "fuel_g_per_mi", "×", 3, relative_to="acc"),
    "ev": Row("Energy against the ACC, per run", "energy_kj_per_mi", "×", 3, relative_to="acc"),
}
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


def _fmt(value: Any, decimals: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.{decimals}f}"


@dataclass(frozen=True)
class Table:
    """The values of one results table: every row's estimate, per method and trajectory.

    A trajectory of None is the combination over every trajectory of the table.
    """

    scenario: str
    methods: list[str]
    labels: dict[str, str]
    """Each method's column name."""
    vehicle: str
    rows: list[Row]
    trajectories: list[str]
    """The trajectories every method drove."""
    per: dict[str, dict[str, dict[int | None, Metrics]]]
    """Method -> trajectory -> seed -> the metrics of its run (seed None: a single-seed evaluation's)."""
    seeds: Sequence[int] | None
    settle: float
    """Seconds at the start of each run left out of the comfort rows [s]."""
    road: Road
    early: tuple[Run, ...] = ()
    """The runs that ended before their duration (:attr:`vacc.runs.Run.early`)."""
    include_early: bool = False
    """Whether ``early`` runs are in ``per`` (and so in every value); by default they are left out."""

    @property
    def multi(self) -> bool:
        """Whether the table is over several seeds (then a mean has an interval)."""
        return self.seeds is not None and len(self.seeds) > 1

    @property
    def columns(self) -> list[str]:
        return [self.labels[m] for m in self.methods]

    def _samples(self, method: str, traj: str | None, row: Row) -> list[list[float]]:
        """The row's values, one list (over seeds) per trajectory; None (undefined on a run) left out.
        A relative row pairs each run with the reference method's of the same seed, where both have one."""
        groups = []
        for t in [traj] if traj else self.trajectories:
            runs = self.per[method].get(t, {})
            if row.relative_to is None:
                groups.append([float(r[row.key]) for r in runs.values() if r[row.key] is not None])  # type: ignore[arg-type]
                continue
            ref = self.per[row.relative_to].get(t, {})
            pairs = [(r[row.key], ref[seed][row.key]) for seed, r in runs.items() if seed in ref]
            groups.append([float(a) / float(b) for a, b in pairs if a is not None and b])  # type: ignore[arg-type]
        return [g for g in groups if g]

    def estimate(self, method: str, traj: str | None, row: Row, statistic: stats.Statistic = stats.mean) -> stats.Estimate | None:
        """The row's value for one method (with its interval over several seeds), or None: blank."""
        if (method == "lead" and row.follower_only) or method == row.relative_to:
            return None
        groups = self._samples(method, traj, row)
        if not groups:
            return None
        if row.combine != "mean" or not self.multi:  # one seed: no interval to show
            pooled = [x for g in groups for x in g]
            v = COMBINE[row.combine](pooled) if row.combine != "mean" else float(statistic(np.array(pooled))[()])
            return stats.Estimate(v, v, v, len(pooled))
        return stats.bootstrap_ci(groups, statistic)

    def value(self, method: str, traj: str | None, row: Row) -> Any:
        """The row's value in evaluate_run's units (a sum as an int), or None."""
        e = self.estimate(method, traj, row)
        if e is None:
            return None
        return int(e.value) if row.combine == "sum" else e.value

    def shown(self, method: str, traj: str | None, row: Row, statistic: stats.Statistic = stats.mean) -> str:
        """The row's value as table.md shows it, with its interval over several seeds."""
        e = self.estimate(method, traj, row, statistic)
        if e is None:
            return _fmt(None, row.decimals)
        text = _fmt(int(e.value) if row.combine == "sum" else e.value * row.scale, row.decimals)
        if self.multi and row.combine == "mean":
            text += f" [{_fmt(e.low * row.scale, row.decimals)}, {_fmt(e.high * row.scale, row.decimals)}]"
        return text


def compute_table(
    runs: Sequence[Run], scenario: str, methods: list[str], labels: dict[str, str], vehicle: str,
    settle: float = SETTLE_S, seeds: Sequence[int] | None = None, road: Road = DEFAULT_ROAD, include_early: bool = False,
) -> Table:  # fmt: skip
    """The table of ``methods`` over the trajectories every one of them drove in ``runs``.

    A run that ended before its duration (a collision, a lost lead) is left out of every
    value unless ``include_early``; the table lists it either way.
    """
    energy = ICE_ROWS if scenario == "ice" else EV_ROWS
    relative = [RELATIVE_ROWS[scenario]] if "acc" in methods and len(methods) > 1 else []
    rows = energy + relative + DRIVING_ROWS + COMFORT_ROWS
    per: dict[str, dict[str, dict[int | None, Metrics]]] = {m: {} for m in methods}
    driven: dict[str, set[str]] = {m: set() for m in methods}
    for run in runs:
        driven[run.method].add(run.trajectory)
        if run.early is None or include_early:
            per[run.method].setdefault(run.trajectory, {})[run.seed] = run.metrics
    trajs = [t for t in TRAJECTORIES if all(t in driven[m] for m in methods)]
    early = tuple(r for r in runs if r.early is not None)
    return Table(scenario, methods, labels, vehicle, rows, trajs, per, seeds, settle, road, early, include_early)


def early_lines(table: Table) -> list[str]:
    """table.md's section on the runs that ended before their duration; none when every run ran to its end."""
    if not table.early:
        return []
    kept = "are in every value above (--include-early)" if table.include_early else "are left out of every value above (--include-early keeps them)"
    lines = [f"## Runs that ended early ({len(table.early)})", "", f"These runs ended before their duration and {kept}.", ""]
    lines += ["| Method | Trajectory | Seed | How | When (s) | Of (s) |", "| --- | --- | --- | --- | --- | --- |"]
    for r in table.early:
        assert r.early is not None
        seed = "" if r.seed is None else str(r.seed)
        lines.append(f"| {table.labels[r.method]} | {r.trajectory} | {seed} | {r.early.how} | {r.early.at:.1f} | {r.early.expected:g} |")
    return lines + [""]


def _md_rows(table: Table, traj: str | None, rows: list[Row], statistic: stats.Statistic = stats.mean) -> list[str]:
    cols = table.columns
    t = ["| Metric | Better | " + " | ".join(cols) + " |", "| --- | --- |" + " --- |" * len(cols)]
    for row in rows:
        name = f"{row.label} ({row.unit})" if row.unit else row.label
        t.append(f"| {name} | {row.better} | " + " | ".join(table.shown(m, traj, row, statistic) for m in table.methods) + " |")
    return t


def _md_notes(table: Table) -> list[str]:
    """What the rows mean, under the mean table; over several seeds, the IQM table too."""
    lines = [
        "",
        f"Better: which way a row improves (max speed: at most the set speed, {DEFAULT_SET_SPEED:g} m/s). "
        "Collisions are summed, minimum gap, time-to-collision and headway are minima and the maximum speed is "
        "the maximum over the runs; the rest are means.",
        f"The last {len(COMFORT_ROWS)} rows (comfort) leave out the first {table.settle:g} s of each run (`--settle`); "
        "every other row is over the whole run. ISO 15622 limits: mean deceleration over any 2 s "
        f"≤ {ISO_DECEL_LIMIT_MPS2:g} m/s², mean jerk over any 1 s ≤ {ISO_JERK_LIMIT_MPS3:g} m/s³.",
        "",
    ]
    for row in table.rows:
        if row.relative_to is not None:
            lines[-1:-1] = [f"{row.label}: each run's {row.key.split('_')[0]} over the {table.labels[row.relative_to]}'s "
                            "on the same trajectory and seed, averaged (paired, so the seed's traffic and scenery cancel); "
                            "a run whose reference has no run of its seed, or used none, has no ratio (stats.csv counts the runs)."]
    if table.multi:
        lines[-1:-1] = [
            f"[low, high]: {stats.CONFIDENCE:.0%} stratified bootstrap confidence interval of the mean "
            f"(seeds resampled within each trajectory, {stats.N_RESAMPLES} resamples, generator seed "
            f"{stats.BOOTSTRAP_SEED}); in the per-trajectory tables, over that trajectory's seeds. "
            "Sums, minima and maxima have no interval.",
        ]
        lines += ["## Interquartile mean (rliable)", ""]
        lines += _md_rows(table, None, [r for r in table.rows if r.combine == "mean"], stats.iqm)
        lines += [
            "",
            "The mean of the middle half of the runs (each seed on each trajectory a run; "
            f"⌊n/4⌋ dropped at each end), with its {stats.CONFIDENCE:.0%} stratified bootstrap interval "
            "(Agarwal et al. 2021). It is robust to one outlying seed.",
            "",
        ]
    return lines


def _md_paper(scenario: str) -> list[str]:
    paper = PAPER[scenario]
    lines = [f"## The paper's Table {'3' if scenario == 'ice' else '4'} (Wei et al. 2019)", ""]
    lines += ["| Metric | " + " | ".join(paper["columns"]) + " |", "| --- |" + " --- |" * len(paper["columns"])]
    for name, vals in paper["rows"].items():
        lines.append(f"| {name} | " + " | ".join(f"{v:g}" for v in vals) + " |")
    return lines + ["", "The paper's vehicle models and human drivers differ from ours; compare orders and ratios, not absolutes.", ""]


def write_table_md(out: Path, table: Table) -> Path:
    """table.md: the mean table, its notes, the paper's table and one table per trajectory."""
    model = "CMEM " + table.vehicle if table.scenario == "ice" else "EV eq. 6 " + table.vehicle
    n, seeds = len(table.trajectories), table.seeds
    over = f"{n} trajectories × {len(seeds)} seeds ({seed_text(seeds)})" if table.multi and seeds else f"{n} trajectories"
    flag = ""
    if table.early:
        flag = f"; {len(table.early)} run{'s' if len(table.early) > 1 else ''} ended early, " + ("kept" if table.include_early else "left out")
    lines = [f"# {table.scenario.upper()} results ({model}), average of {over}{table.road.note()}{flag}", ""]
    lines += _md_rows(table, None, table.rows)
    lines += _md_notes(table)
    lines += early_lines(table)
    lines += _md_paper(table.scenario)
    for traj in table.trajectories:
        lines += [f"## {traj}", ""] + _md_rows(table, traj, table.rows) + [""]
    path = out / "table.md"
    path.write_text("\n".join(lines))
    return path


def write_table_csv(out: Path, table: Table) -> Path:
    """table.csv: every row's value per method, for the mean and for each trajectory."""
    path = out / "table.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "metric", "unit", *table.columns])
        for which in [None, *table.trajectories]:
            for row in table.rows:
                values = [None if (v := table.value(m, which, row)) is None else v * row.scale for m in table.methods]
                w.writerow([which or "mean", row.label, row.unit, *[_fmt(v, 6 if row.decimals else 0) for v in values]])
    return path


def write_stats_csv(out: Path, table: Table) -> Path:
    """stats.csv: every estimate with its interval and its number of runs (a mean's IQM too)."""
    path = out / "stats.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "metric", "unit", "method", "statistic", "value", "ci_low", "ci_high", "runs"])
        for which in [None, *table.trajectories]:
            for row in table.rows:
                for m in table.methods:
                    for name, statistic in [(row.combine, stats.mean)] + ([("iqm", stats.iqm)] if row.combine == "mean" else []):
                        e = table.estimate(m, which, row, statistic)
                        if e is not None:
                            w.writerow([which or "mean", row.label, row.unit, table.labels[m], name,
                                        *(f"{x * row.scale:.6g}" for x in e[:3]), e.n])  # fmt: skip
    return path


def build_tables(
    out: Path, scenario: str, methods: list[str], labels: dict[str, str], vehicle: str,
    settle: float = SETTLE_S, seeds: Sequence[int] | None = None, runs: list[Run] | None = None, road: Road = DEFAULT_ROAD,
    include_early: bool = False,
) -> dict[str, Any]:
    """Score every log, write table.md/table.csv; returns the combined metrics per method.

    Over several ``seeds`` each mean row is shown with its 95 % bootstrap confidence
    interval (:mod:`vacc.stats`), table.md gains an interquartile-mean table, and
    stats.csv holds every estimate.

    Args:
        settle: seconds at the start of each run left out of the comfort rows [s].
        seeds: the seeds of a multi-seed evaluation; None: one seed.
        runs: the scored runs, if already at hand (:func:`vacc.runs.score_runs`).
        road: the runs' traffic and sun (named in the title unless the default).
        include_early: keep the runs that ended before their duration in the values.

    Raises:
        click.ClickException: a log is invalid (when ``runs`` is None).
    """
    if runs is None:
        runs = score_runs(out, methods, vehicle, settle, seeds)
    table = compute_table(runs, scenario, methods, labels, vehicle, settle, seeds, road, include_early)
    write_table_md(out, table)
    write_table_csv(out, table)
    if table.multi:
        write_stats_csv(out, table)
    return {m: {row.name: table.value(m, None, row) for row in table.rows} for m in methods}
