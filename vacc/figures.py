"""The figures of `vacc evaluate`, paper-ready: one style, PNG and PDF of each.

Every function takes the scored runs of :func:`vacc.runs.score_runs` (one per
method, trajectory and seed), writes ``<name>.png`` and ``<name>.pdf`` into the
output folder and returns a :class:`Written`. A figure with nothing to plot says so
in words on the page instead of leaving empty axes, and ``Written.empty`` says why.

* ``fig_gap``, ``fig_speed``: small multiples over the four test trajectories, the
  mean over seeds with the spread over seeds shaded (min to max), like the paper's
  Fig. 5c/5d.
* ``fig_comfort``: distributions of acceleration and of the 1-s mean jerk per method
  (after the settle).
* ``fig_emissions`` (ICE: CO2, CO, HC, NOx) or ``fig_energy`` (EV): bars per method
  with 95 % bootstrap intervals.
* ``fig_headway``: time-headway histogram per method, weighted by time.
* ``fig_pareto``: gap RMSE against energy, coloured by ISO jerk share.
* ``fig_training``: the shipped models' training curves, smoothed.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import click
import numpy as np

from energy import SETTLE_S
from energy.comfort import ISO_JERK_LIMIT_MPS3, ISO_JERK_WINDOW_S, WINDOW_SLACK_S, window_starts
from energy.metrics import HEADWAY_MIN_SPEED_MPS, TIME_GAP_S
from protocol.scenarios import TEST_TRAJECTORIES
from vacc import stats
from vacc.runs import Run, score_runs

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "STYLE", "Written", "plot_runs", "plot_comfort", "plot_emissions", "plot_headway", "plot_pareto", "plot_training",
    "smooth", "late_start", "cut_note", "value_label", "headway_right",
]

DESIRED_GAP_M = 55.0  # [m] the paper's target, drawn on the gap figure
DPI = 150  # [1/inch] of the PNGs; the PDFs are vector
SMOOTHING = 0.6  # [-] TensorBoard-style exponential smoothing weight of the training curves
HEADWAY_MAX_S = 6.0  # [s] the histogram's last bin holds everything above
HEADWAY_BIN_S = 0.1  # [s]
LOG_RATIO = 30.0  # [-] a bar panel whose highest bar exceeds its lowest this many times is drawn on a log axis

STYLE: dict[str, tuple[str, str]] = {
    "lead": ("0.35", "s"),
    "ddqn-gap": ("tab:red", "o"),
    "ddqn-force": ("tab:orange", "D"),
    "ddqn-eco": ("tab:green", "^"),
    "acc": ("tab:blue", "v"),
    "human": ("tab:purple", "P"),
}
"""Colour and marker of each method, the same in every figure."""

RC: dict[str, Any] = {
    "font.size": 8, "axes.titlesize": 9, "axes.labelsize": 8, "legend.fontsize": 7,
    "xtick.labelsize": 7, "ytick.labelsize": 7, "axes.grid": True, "grid.alpha": 0.3,
    "axes.spines.top": False, "axes.spines.right": False, "pdf.fonttype": 42,
}  # fmt: skip
"""Matplotlib settings of every figure (pdf.fonttype 42: editable text in the PDF)."""


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.style.use(RC)
    return plt


def _color(method: str) -> str:
    return STYLE.get(method, ("k", "o"))[0]


def _marker(method: str) -> str:
    return STYLE.get(method, ("k", "o"))[1]


class Written(NamedTuple):
    """A figure written as ``<name>.png`` and ``<name>.pdf``."""

    name: str
    empty: str | None = None
    """Why nothing was plotted (the figure then says this in words), or None."""


def _save(fig: Figure, out: Path, name: str) -> Written:
    for ext in ("png", "pdf"):
        fig.savefig(out / f"{name}.{ext}", dpi=DPI, bbox_inches="tight")
    _plt().close(fig)
    return Written(name)


def _message(out: Path, name: str, title: str, text: str) -> Written:
    """A figure that says in words why there is nothing to plot."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 1.8))
    ax.axis("off")
    ax.set_title(title)
    ax.text(0.5, 0.5, text, ha="center", va="center", wrap=True, transform=ax.transAxes)
    return Written(_save(fig, out, name).name, text.replace("\n", " "))


def cut_note(duration: float | None) -> str:
    """Words for a title when every run was cut short with ``--duration``: nothing otherwise."""
    return "" if duration is None else f" [runs cut short: first {duration:g} s of each (--duration {duration:g})]"


def value_label(value: float) -> str:
    """A bar's value as text: three significant digits, never in exponent form (1513, not 1.51e+03)."""
    if not np.isfinite(value):
        return "—"
    if abs(value) >= 100:
        return f"{value:.0f}"
    return np.format_float_positional(value, precision=3, unique=False, fractional=False, trim="-")


def _seeds_note(runs: Sequence[Run]) -> str:
    seeds = sorted({r.seed for r in runs if r.seed is not None})
    return f"mean of {len(seeds)} seeds, shaded min to max" if len(seeds) > 1 else "one seed"


def _group(runs: Sequence[Run], method: str, traj: str) -> list[Run]:
    return sorted((r for r in runs if r.method == method and r.trajectory == traj), key=lambda r: r.seed or 0)


def _methods(runs: Sequence[Run], followers: bool = False) -> list[str]:
    seen = list(dict.fromkeys(r.method for r in runs))
    return [m for m in seen if not (followers and m == "lead")]


def plot_runs(out: Path, runs: Sequence[Run], labels: dict[str, str], scenario: str, *, duration: float | None = None) -> list[Written]:
    """fig_gap and fig_speed: one panel per test trajectory, each follower's mean over seeds
    with the min-to-max spread shaded; the speed panels add the lead in black.

    Args:
        duration: the runs' ``--duration`` [s], named in the titles; None: whole runs.
    """
    plt = _plt()
    followers = _methods(runs, followers=True)
    names: list[Written] = []
    for name, column, ylabel in (("fig_gap", "gap", "gap [m]"), ("fig_speed", "v_host", "speed [m/s]")):
        title = f"{scenario.upper()} {'gap' if column == 'gap' else 'speed'} ({_seeds_note(runs)})" + cut_note(duration)
        if not followers:
            names.append(_message(out, name, title, "no follower runs to plot (only the lead, or no logs)"))
            continue
        fig, axes = plt.subplots(2, 2, figsize=(7.2, 4.6), sharex=True, squeeze=False)
        for ax, traj in zip(axes.flat, TEST_TRAJECTORIES, strict=True):
            lead_drawn = False
            for m in followers:
                group = _group(runs, m, traj)
                if not group:
                    continue
                n = min(r.log.t.size for r in group)  # a run cut short by a collision
                t = group[0].log.t[:n]
                y = np.stack([getattr(r.log, column)[:n] for r in group])  # [seeds, T]
                if column == "v_host" and not lead_drawn:
                    ax.plot(t, group[0].log.v_lead[:n], color="k", lw=1.2, label="lead vehicle")
                    lead_drawn = True
                ax.plot(t, y.mean(axis=0), color=_color(m), lw=0.9, label=labels[m])
                if len(group) > 1:
                    ax.fill_between(t, y.min(axis=0), y.max(axis=0), color=_color(m), alpha=0.2, lw=0)
            if column == "gap":
                ax.axhline(DESIRED_GAP_M, color="k", ls="--", lw=0.7, label=f"desired gap {DESIRED_GAP_M:g} m")
            ax.set_title(traj)
            if not ax.has_data():
                ax.axis("off")
                ax.text(0.5, 0.5, f"no runs on {traj}", ha="center", va="center", transform=ax.transAxes)
        for ax in axes[1]:
            ax.set_xlabel("time [s]")
        for ax in axes[:, 0]:
            ax.set_ylabel(ylabel)
        handles, texts = axes.flat[0].get_legend_handles_labels()
        fig.legend(handles, texts, loc="lower center", ncol=min(len(texts), 4), frameon=False, bbox_to_anchor=(0.5, -0.06))
        fig.suptitle(title)
        fig.tight_layout()
        names.append(_save(fig, out, name))
    return names


def _after_settle(run: Run, settle: float) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration [m/s^2] of a run after the settle, as energy.metrics cuts it, and the
    mean jerk of each 1-s window ``|a(t + 1 s) - a(t)| / 1 s`` [m/s^3] (ISO 15622's, as
    energy.comfort judges it)."""
    log = run.log
    keep = log.t >= log.t[0] + settle - WINDOW_SLACK_S
    t, a = log.t[keep], log.accel[keep]
    if t.size < 2:
        return a, np.empty(0)
    starts = window_starts(t, ISO_JERK_WINDOW_S)
    jerk = np.abs(np.interp(starts + ISO_JERK_WINDOW_S, t, a) - np.interp(starts, t, a)) / ISO_JERK_WINDOW_S
    return a, jerk


def plot_comfort(
    out: Path, runs: Sequence[Run], labels: dict[str, str], scenario: str, settle: float = SETTLE_S, *, duration: float | None = None,
) -> Written:
    """fig_comfort: box plots per method, over every run and seed after the first ``settle``
    seconds [s], of the acceleration and of the 1-s mean jerk that ISO 15622 limits;
    whiskers at the 1st and 99th percentiles, and a sample of the values themselves beside each box.

    A DDQN holds its force between decisions, so its step-to-step jerk is mostly zero
    with spikes between; the 1-s mean shows how hard it rides, on the limit's own terms.
    A box whose quartiles coincide (a force policy that holds one acceleration most of
    the time) is labelled with the share of time at that value, so it does not read as no data.

    Args:
        duration: the runs' ``--duration`` [s], named in the title; None: whole runs.
    """
    methods = _methods(runs)
    data = {m: [_after_settle(r, settle) for r in runs if r.method == m] for m in methods}
    accel = {m: np.concatenate([a for a, _ in v]) for m, v in data.items()}
    jerk = {m: np.concatenate([j for _, j in v]) for m, v in data.items()}
    methods = [m for m in methods if jerk[m].size]
    title = f"{scenario.upper()} comfort after the first {settle:g} s: acceleration and {ISO_JERK_WINDOW_S:g}-s mean jerk" + cut_note(duration)
    if not methods:
        return _message(out, "fig_comfort", title, f"no run is longer than the {settle:g} s settle (--settle)")
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(7.2, 3.0))
    for ax, values, ylabel in ((axes[0], accel, "acceleration [m/s²]"), (axes[1], jerk, f"{ISO_JERK_WINDOW_S:g}-s mean jerk [m/s³]")):
        _boxes(ax, [values[m] for m in methods], methods)
        ax.set_xticks(range(1, len(methods) + 1), [labels[m].replace(" (", "\n(") for m in methods], rotation=30, ha="right")
        ax.set_ylabel(ylabel)
    axes[1].set_yscale("symlog", linthresh=0.01)  # a smooth ride's windows are near zero
    axes[1].set_ylim(bottom=0.0)
    axes[1].axhline(ISO_JERK_LIMIT_MPS3, color="k", ls=":", lw=0.8)
    axes[1].annotate(f"ISO 15622 limit {ISO_JERK_LIMIT_MPS3:g} m/s³", xy=(1.0, ISO_JERK_LIMIT_MPS3), xycoords=("axes fraction", "data"),
                     ha="right", va="bottom", fontsize=6)  # fmt: skip
    fig.suptitle(title + " (box: quartiles, whiskers: 1st to 99th percentile, dots: a sample of the values)")
    fig.tight_layout()
    return _save(fig, out, "fig_comfort")


STRIP_POINTS = 300  # values drawn beside each box (an even sample, so the figure is deterministic)


def _boxes(ax: Any, values: list[np.ndarray], methods: list[str]) -> None:
    """Box plots at x = 1, 2, ... with a strip of sampled values beside each, and a label on
    a box whose quartiles coincide: the share of the values at its median."""
    box = ax.boxplot(values, whis=(1, 99), showfliers=False, patch_artist=True, widths=0.5)
    for patch, m in zip(box["boxes"], methods, strict=True):
        patch.set(facecolor=_color(m), alpha=0.5)
    for median in box["medians"]:
        median.set(color="k")
    for i, (v, m) in enumerate(zip(values, methods, strict=True), start=1):
        sample = v[np.linspace(0, v.size - 1, min(v.size, STRIP_POINTS)).astype(int)]
        offsets = 0.3 + 0.08 * ((np.arange(sample.size) * 0.618) % 1.0)  # beside the box, spread without randomness
        ax.scatter(i + offsets, sample, s=1.5, color=_color(m), alpha=0.5, lw=0, gid=f"strip-{m}")
        q1, med, q3 = np.percentile(v, [25, 50, 75])
        if q3 - q1 <= 1e-9:
            share = 100.0 * np.mean(np.abs(v - med) <= 1e-9)
            ax.annotate(f"{share:.0f} % at {med:.2g}", (i, med), xytext=(0, 4), textcoords="offset points", ha="center", va="bottom",
                        fontsize=6, gid=f"collapsed-{m}")  # fmt: skip


EMISSIONS = (("co2_g_per_mi", "CO2 [g/mi]"), ("co_g_per_mi", "CO [g/mi]"), ("hc_g_per_mi", "HC [g/mi]"), ("nox_g_per_mi", "NOx [g/mi]"))
"""The ICE emission bars: metric of energy.evaluate_run and axis label."""


def plot_emissions(out: Path, runs: Sequence[Run], labels: dict[str, str], scenario: str, *, duration: float | None = None) -> Written:
    """fig_emissions (ICE: CO2, CO, HC, NOx) or fig_energy (EV): the mean per method over every
    trajectory and seed, with its 95 % stratified bootstrap interval, on a log axis.

    Each bar's value is written upright above it (:func:`value_label`), so narrow bars'
    labels never run into each other.

    Args:
        duration: the runs' ``--duration`` [s], named in the title; None: whole runs.
    """
    name = "fig_emissions" if scenario == "ice" else "fig_energy"
    panels = EMISSIONS if scenario == "ice" else (("energy_kj_per_mi", "energy [kJ/mi]"),)
    methods = _methods(runs)
    if not methods:
        return _message(out, name, f"{scenario.upper()} {'emissions' if scenario == 'ice' else 'energy'}", "no runs to plot")
    plt = _plt()
    fig, axes = plt.subplots(1, len(panels), figsize=(1.9 * len(panels) + 1.2 * (len(panels) == 1), 3.0), squeeze=False)
    x = np.arange(len(methods))
    for ax, (key, ylabel) in zip(axes[0], panels, strict=True):
        est = []
        for m in methods:
            groups = [[float(r.metrics[key]) for r in _group(runs, m, t)] for t in TEST_TRAJECTORIES]  # type: ignore[arg-type]
            est.append(stats.bootstrap_ci([g for g in groups if g]))
        values = np.array([e.value for e in est])
        err = np.array([[e.value - e.low for e in est], [e.high - e.value for e in est]])
        ax.bar(x, values, yerr=err, color=[_color(m) for m in methods], capsize=2, alpha=0.8)
        for xi, v, top in zip(x, values, values + err[1], strict=True):
            ax.annotate(value_label(v), (xi, top), ha="center", va="bottom", fontsize=6, xytext=(0, 2), textcoords="offset points", rotation=90)
        if np.all(values > 0) and values.max() > LOG_RATIO * values.min():
            ax.set_yscale("log")  # CO and HC can span orders of magnitude between methods
            ax.set_title("log scale", fontsize=7)
        ax.margins(y=0.3)  # room for the upright labels
        ax.set_ylabel(ylabel)
        ax.set_xticks(x, [labels[m].split(" (")[0] for m in methods], rotation=40, ha="right")
    what = "tailpipe emissions (CMEM)" if scenario == "ice" else "energy (EV eq. 6)"
    seeds = {r.seed for r in runs}
    fig.suptitle(f"{scenario.upper()} {what}, mean of {len(runs) // len(methods)} runs per method"
                 + (f" ({len(seeds)} seeds × trajectories), 95 % bootstrap interval" if len(seeds) > 1 else "") + cut_note(duration))
    fig.tight_layout()
    return _save(fig, out, name)


def plot_headway(out: Path, runs: Sequence[Run], labels: dict[str, str], scenario: str, *, duration: float | None = None) -> Written:
    """fig_headway: the share of driving time at each time headway (gap / own speed, while
    moving faster than 0.5 m/s) per follower, over every run and seed. The x-axis ends a
    little past the last headway driven (and past the ACC's time gap), not at the last bin.

    Args:
        duration: the runs' ``--duration`` [s], named in the title; None: whole runs.
    """
    followers = _methods(runs, followers=True)
    title = f"{scenario.upper()} time headway (gap / own speed, while moving)" + cut_note(duration)
    edges = np.arange(0.0, HEADWAY_MAX_S + HEADWAY_BIN_S / 2, HEADWAY_BIN_S)
    hists = {}
    for m in followers:
        hw, w = [], []
        for r in runs:
            if r.method != m:
                continue
            log = r.log
            dt = np.append(np.diff(log.t), np.diff(log.t)[-1])  # [s] each row's time, as energy.metrics weights it
            moving = log.v_host > HEADWAY_MIN_SPEED_MPS
            hw.append(np.clip(log.gap[moving] / log.v_host[moving], 0.0, HEADWAY_MAX_S - 1e-9))
            w.append(dt[moving])
        if hw and np.concatenate(w).sum() > 0:
            h, _ = np.histogram(np.concatenate(hw), bins=edges, weights=np.concatenate(w))
            hists[m] = 100.0 * h / h.sum()
    if not hists:
        return _message(out, "fig_headway", title, "no follower drove faster than 0.5 m/s in any run")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.2, 3.0))
    for m, h in hists.items():
        ax.stairs(h, edges, color=_color(m), lw=1.2, label=labels[m])
    ax.axvline(TIME_GAP_S, color="k", ls=":", lw=0.8, label=f"{TIME_GAP_S:g} s (the ACC's time gap)")
    ax.set(xlabel=f"time headway [s] (last bin: {HEADWAY_MAX_S - HEADWAY_BIN_S:g} s and above)",
           ylabel=f"share of time per {HEADWAY_BIN_S:g} s [%]", title=title)  # fmt: skip
    ax.set_xlim(0.0, headway_right(edges, list(hists.values())))
    ax.legend()
    fig.tight_layout()
    return _save(fig, out, "fig_headway")


def headway_right(edges: np.ndarray, hists: list[np.ndarray]) -> float:
    """The headway axis' right end [s]: two bins past the last one with time in it, and past the ACC's time gap."""
    last = max(int(np.flatnonzero(h > 0)[-1]) for h in hists)
    return float(min(edges[-1], max(edges[last + 1] + 2 * HEADWAY_BIN_S, TIME_GAP_S + 0.5)))


def plot_pareto(
    out: Path, scenario: str, methods: list[str], labels: dict[str, str], vehicle: str, settle: float = SETTLE_S,
    *, seeds: Sequence[int] | None = None, runs: Sequence[Run] | None = None, duration: float | None = None,
) -> Written:
    """fig_pareto: gap RMSE against energy, one point per method, coloured by the share of
    1-s windows over ISO 15622's jerk limit; one panel per trajectory and their mean.

    Over several seeds a point is the mean over seeds, with bars from the lowest to the
    highest seed. Lower left is better on both axes; a pale point rides more comfortably
    than a dark one.

    Args:
        runs: the scored runs; default: :func:`vacc.runs.score_runs` on ``out/logs``.
        duration: the runs' ``--duration`` [s], named in the title; None: whole runs.
    """
    if runs is None:
        runs = score_runs(out, methods, vehicle, settle, seeds)
    plt = _plt()
    energy_key, energy_label = ("fuel_g_per_mi", "fuel [g/mi]") if scenario == "ice" else ("energy_kj_per_mi", "energy [kJ/mi]")
    followers = [m for m in methods if m != "lead"]
    # panel -> method -> rows of (energy, gap RMSE, jerk share), one row per seed
    points: dict[str, dict[str, np.ndarray]] = {}
    for traj in TEST_TRAJECTORIES:
        for m in followers:
            group = _group(runs, m, traj)
            if group:
                points.setdefault(traj, {})[m] = np.array([[float(r.metrics[energy_key]), float(r.metrics["gap_rmse_55m_m"]),  # type: ignore[arg-type]
                                                            float(r.metrics["iso_jerk_window_share"] or 0.0)] for r in group])  # type: ignore[arg-type]  # fmt: skip
    complete = [t for t in points if all(m in points[t] for m in followers)]
    if complete:
        n = min(points[t][m].shape[0] for t in complete for m in followers)
        # per seed, the mean over trajectories
        points["mean of " + str(len(complete))] = {m: np.mean([points[t][m][:n] for t in complete], axis=0) for m in followers}
    if not points:
        return _message(out, "fig_pareto", f"{scenario.upper()}: gap against energy", f"no follower runs in {out / 'logs'}")
    panels = list(points)
    fig, axes = plt.subplots(1, len(panels), figsize=(2.4 * len(panels) + 1.0, 3.2), squeeze=False, layout="constrained")
    sc = None
    for ax, name in zip(axes[0], panels, strict=True):
        for m, p in points[name].items():
            e, rmse, jerk = p.mean(axis=0)
            if p.shape[0] > 1:
                ax.errorbar([e], [rmse], xerr=[[e - p[:, 0].min()], [p[:, 0].max() - e]], yerr=[[rmse - p[:, 1].min()], [p[:, 1].max() - rmse]],
                            color="0.4", lw=0.7, capsize=2, zorder=1)  # fmt: skip
            sc = ax.scatter([e], [rmse], c=[100.0 * jerk], cmap="viridis_r", vmin=0.0, vmax=100.0, marker=_marker(m), s=45,
                            edgecolors=_color(m), linewidths=1.2, label=labels[m], zorder=2)  # fmt: skip
        ax.set(title=name, xlabel=energy_label)
    axes[0][0].set_ylabel("gap RMSE to 55 m [m]")
    handles, texts = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, texts, loc="outside lower center", ncol=min(len(texts), 4), frameon=False)
    if sc is not None:
        fig.colorbar(sc, ax=axes[0].tolist(), label=f"1-s windows over {ISO_JERK_LIMIT_MPS3:g} m/s³ [%]")
    spread = " (bars: lowest to highest seed)" if any(p.shape[0] > 1 for pts in points.values() for p in pts.values()) else ""
    fig.suptitle(f"{scenario.upper()}: gap against energy, lower left is better{spread}" + cut_note(duration))
    return _save(fig, out, "fig_pareto")


def smooth(values: Sequence[float], weight: float = SMOOTHING) -> np.ndarray:
    """TensorBoard's debiased exponential moving average: ``s_k = w s_{k-1} + (1 - w) x_k``,
    divided by ``1 - w^(k+1)`` so the first points are not pulled toward zero.

    Raises:
        ValueError: ``weight`` outside [0, 1).
    """
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"smoothing weight must be in [0, 1), got {weight}")
    out = np.empty(len(values))
    acc = 0.0
    for k, x in enumerate(values):
        acc = weight * acc + (1.0 - weight) * x
        out[k] = acc / (1.0 - weight ** (k + 1))
    return out


def late_start(steps: Sequence[int]) -> bool:
    """Whether a curve starts later than two of its own bins after step 0 (a fine-tuned
    model's steps count on from the model it started from)."""
    if len(steps) < 2:
        return bool(steps) and steps[0] > 0
    bin_width = float(np.median(np.diff(steps)))
    return steps[0] > 2 * bin_width


def plot_training(out: Path, models: Path, scenario: str) -> Written:
    """fig_training from the shipped models' training curves (``<scenario>-<reward>.curve.csv``:
    step,avg_reward; ``#`` lines are comments): raw faint, smoothed bold. A curve that starts
    late is marked and explained.

    Raises:
        click.ClickException: a curve file lacks the step,avg_reward columns.
    """
    curves = {}
    for reward in ("gap", "force", "eco"):
        curve = models / f"{scenario}-{reward}.curve.csv"
        if curve.exists():
            with curve.open() as f:
                rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
            try:
                curves[reward] = ([int(r["step"]) for r in rows], [float(r["avg_reward"]) for r in rows])
            except (KeyError, TypeError, ValueError):
                raise click.ClickException(f"{curve}: expected columns step,avg_reward") from None
    curves = {k: v for k, v in curves.items() if v[0]}
    title = f"Training, {scenario.upper()} (like the paper's Fig. 5a/5b)"
    if not curves:
        return _message(out, "fig_training", title,
                        f"No training curves to plot: none of {scenario}-gap/-force/-eco.curve.csv in {models}/ has a row.\n"
                        "They are written next to a shipped model (docs/training.md).")  # fmt: skip
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.2, 3.2))
    notes = []
    colors = {"gap": _color("ddqn-gap"), "force": _color("ddqn-force"), "eco": _color("ddqn-eco")}
    for reward, (steps, values) in curves.items():
        ax.plot(steps, values, color=colors[reward], lw=0.7, alpha=0.3)
        ax.plot(steps, smooth(values), color=colors[reward], lw=1.6, label=f"{reward}-based DDQN")
        if late_start(steps):
            ax.plot([steps[0]], [values[0]], marker="|", ms=12, color=colors[reward])
            notes.append(f"The {reward} curve starts at step {steps[0]:,}: a fine-tuned model, whose steps count on "
                         "from those of the model it started from (docs/training.md).")  # fmt: skip
    ax.set(xlabel="training step", ylabel="average reward per step", title=title)
    ax.set_xlim(left=0)
    ax.legend(title=f"bold: smoothed ({SMOOTHING:g}); faint: raw", loc="lower right")
    if notes:
        fig.text(0.01, -0.02, "\n".join(notes), ha="left", va="top", fontsize=7)
    fig.tight_layout()
    return _save(fig, out, "fig_training")
