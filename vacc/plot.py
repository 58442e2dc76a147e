"""`vacc plot RUN.csv [RUN2.csv ...] --out fig.png|pdf`: one run (or several, overlaid) over time.

Five panels sharing the time axis:

* speed: the host's, the lead's (dashed) and the set speed (dotted);
* gap: with the 55 m target and the :data:`protocol.constants.MIN_GAP` line;
* acceleration: with ISO 15622's deceleration limit;
* jerk: the mean over each 1-s window, centred, with ISO 15622's limit either way;
* energy used since the start: fuel [g] (CMEM) or battery energy [kJ] (eq. 6), from
  the vehicle of the run's card (``ice``: the Corolla, ``ev``: the Leaf), or ``--vehicle``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import click
import numpy as np

from agent_client.runlog import read_card
from energy import RunLog, RunLogError, cmem, ev, read_run_log
from energy.comfort import ISO_DECEL_LIMIT_MPS2, ISO_JERK_LIMIT_MPS3, ISO_JERK_WINDOW_S
from energy.metrics import DESIRED_GAP_M, VEHICLE_NAMES
from energy.trace import intervals
from protocol.constants import MIN_GAP
from protocol.scenarios import DEFAULT_SET_SPEED

__all__ = ["SCENARIO_VEHICLE", "Plotted", "load_run", "energy_used", "window_jerk", "plot_logs", "plot"]

SCENARIO_VEHICLE = {"ice": "corolla", "ev": "leaf"}
"""The energy model of a run whose card names its scenario (vacc evaluate's defaults)."""


class Plotted(NamedTuple):
    """One run to plot: its log, a label, its set speed [m/s] and its energy model."""

    log: RunLog
    label: str
    set_speed: float
    vehicle: str


def load_run(path: str | Path, vehicle: str | None = None) -> Plotted:
    """A run log with what its card says: the controller (for the label), the set speed
    and the scenario (for the vehicle; ``vehicle`` overrides; no card: ICE).

    Raises:
        click.ClickException: an invalid log or card.
    """
    try:
        log = read_run_log(path)
        card = read_card(path) or {}
    except (RunLogError, ValueError) as exc:
        raise click.ClickException(str(exc)) from None
    episode = card.get("episode") or {}
    controller = (card.get("controller") or {}).get("name")
    label = Path(path).stem + (f" ({controller})" if controller else "")
    veh = vehicle or SCENARIO_VEHICLE.get(episode.get("scenario", "ice"), "corolla")
    return Plotted(log, label, float(episode.get("set_speed") or DEFAULT_SET_SPEED), veh)


def energy_used(log: RunLog, vehicle: str) -> tuple[np.ndarray, np.ndarray, str]:
    """Energy used since the start at each row after the first: (t [s], amount, axis label).

    Fuel in grams (CMEM) for an ICE vehicle, battery energy in kJ (eq. 6, regeneration
    counted back) for the Leaf; each interval at its mean speed and constant acceleration,
    as :mod:`energy.metrics` integrates it.
    """
    iv = intervals(log.t, log.v_host)
    if vehicle == "leaf":
        return log.t[1:], np.cumsum(ev.eq6_power_kw(iv.v, iv.a) * iv.dt), "battery energy used [kJ]"
    return log.t[1:], np.cumsum(cmem.cmem_rates(iv.v, iv.a, cmem.VEHICLES[vehicle]).fuel_g_s * iv.dt), "fuel used [g]"


def window_jerk(t: np.ndarray, a: np.ndarray, window: float = ISO_JERK_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """The mean jerk over each ``window`` [s], centred: (times [s], (a(t + w/2) - a(t - w/2)) / w [m/s^3])."""
    keep = (t >= t[0] + window / 2) & (t <= t[-1] - window / 2)
    mid = t[keep]
    return mid, (np.interp(mid + window / 2, t, a) - np.interp(mid - window / 2, t, a)) / window


def _limits(axes: Any) -> None:
    """The lines every overlay shares: targets and ISO 15622 limits, drawn once."""
    axes[1].axhline(DESIRED_GAP_M, color="k", ls="--", lw=0.8, label=f"target {DESIRED_GAP_M:g} m")
    axes[1].axhline(MIN_GAP, color="tab:red", ls=":", lw=0.9, label=f"{MIN_GAP:g} m (the safety floor)")
    axes[2].axhline(-ISO_DECEL_LIMIT_MPS2, color="tab:red", ls=":", lw=0.9, label=f"ISO 15622 decel. limit -{ISO_DECEL_LIMIT_MPS2:g} m/s²")
    for sign in (1, -1):
        axes[3].axhline(sign * ISO_JERK_LIMIT_MPS3, color="tab:red", ls=":", lw=0.9,
                        label=f"ISO 15622 jerk limit ±{ISO_JERK_LIMIT_MPS3:g} m/s³" if sign > 0 else None)  # fmt: skip


def plot_logs(runs: Sequence[Plotted], out: str | Path, title: str = "") -> Any:
    """Draw ``runs`` overlaid and save the figure to ``out`` (.png or .pdf); returns the figure.

    Raises:
        click.ClickException: ``out`` is neither .png nor .pdf.
    """
    from vacc.figures import DPI, _plt

    if Path(out).suffix.lower() not in (".png", ".pdf"):
        raise click.ClickException(f"{out}: a plot is .png or .pdf")
    plt = _plt()
    fig, axes = plt.subplots(5, 1, figsize=(7.2, 9.0), sharex=True)
    units = {}
    for i, run in enumerate(runs):
        color, log = f"C{i % 10}", run.log
        axes[0].plot(log.t, log.v_host, color=color, lw=1.0, label=run.label)
        axes[0].plot(log.t, log.v_lead, color=color, lw=0.8, ls="--", alpha=0.7, label="lead" if len(runs) == 1 else None)
        axes[0].axhline(run.set_speed, color=color, ls=":", lw=0.7, label="set speed" if i == 0 else None)
        axes[1].plot(log.t, log.gap, color=color, lw=1.0)
        axes[2].plot(log.t, log.accel, color=color, lw=0.8)
        axes[3].plot(*window_jerk(log.t, log.accel), color=color, lw=0.8)
        t, used, ylabel = energy_used(log, run.vehicle)
        units[ylabel] = True
        axes[4].plot(t, used, color=color, lw=1.0)
    _limits(axes)
    ylabels = ["speed [m/s] (dashed: lead)", "gap [m]", "acceleration [m/s²]", f"{ISO_JERK_WINDOW_S:g}-s mean jerk [m/s³]", " / ".join(units)]
    for ax, ylabel in zip(axes, ylabels, strict=True):
        ax.set_ylabel(ylabel)
        if ax.get_legend_handles_labels()[1]:
            ax.legend(loc="upper right", fontsize=6)
    axes[4].set_xlabel("time [s]")
    vehicles = ", ".join(sorted({r.vehicle for r in runs}))
    fig.suptitle(title or f"{', '.join(r.label for r in runs)} (energy: {vehicles})")
    fig.tight_layout()
    fig.savefig(out, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return fig


@click.command("plot")
@click.argument("logs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="The figure: .png or .pdf.")
@click.option("--vehicle", default=None, type=click.Choice(VEHICLE_NAMES), help="Energy model of every run; default: from each run's card (ice: corolla, ev: leaf).")
@click.option("--title", default="", help="The figure's title; default: the runs' names.")
def plot(logs: tuple[str, ...], out: str, vehicle: str | None, title: str) -> None:
    """Plot LOGS (vacc drive run logs) over time, overlaid: speed (host, lead, set speed), gap
    with its target and the 2 m floor, acceleration and 1-s jerk with ISO 15622's limits, and
    energy used."""
    runs = [load_run(p, vehicle) for p in logs]
    plot_logs(runs, out, title)
    click.echo(f"Wrote {out} ({len(runs)} run{'s' if len(runs) > 1 else ''})")
