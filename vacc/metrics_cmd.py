"""``vacc metrics``: every metric of a run log, as a table or JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import click

from agent_client.errors import InputFileError
from agent_client.runlog import read_card
from energy import SCENARIO_VEHICLES, RunLogError, evaluate_run
from energy.metrics import D_SAFE_M, SETTLE_S, TIME_GAP_S, VEHICLE_NAMES, Metrics


def finite_non_negative(ctx: click.Context, param: click.Parameter, value: float) -> float:
    """Click callback: refuse a negative, NaN or infinite option with one line."""
    if not (math.isfinite(value) and value >= 0.0):
        raise click.BadParameter(f"must be a finite number >= 0, got {value}")
    return value


def json_safe(result: Metrics) -> Metrics:
    """The metrics with every non-finite float (an overflow) as None, so JSON has null."""
    return {
        k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in result.items()
    }


def card_line(card: dict[str, Any]) -> str:
    """One line of what a run card says: the episode, the road and who drove."""
    ep, road, ctl = card.get("episode") or {}, card.get("road") or {}, card.get("controller") or {}
    traffic, sun = road.get("traffic"), road.get("sun_elevation")  # None: a server before protocol 5
    who = str(ctl.get("name", "?")) + (f" ({ctl['checkpoint']})" if ctl.get("checkpoint") else "")
    sun_text = "unknown" if not isinstance(sun, list) or len(sun) != 2 else "{:g}-{:g} rad high".format(*sun)
    return (
        f"run: {ep.get('scenario', '?')}/{ep.get('trajectory', '?')} seed {ep.get('seed', '?')}, set speed {ep.get('set_speed', '?')} m/s, "
        f"traffic {'unknown' if traffic is None else traffic} a lane, the sun {sun_text}, {who}"
    )


def card_vehicle(card: dict[str, Any] | None, given: str | None) -> str:
    """The vehicle to score with: ``given`` (--vehicle), else the card's scenario's, else
    corolla. A given one of the other powertrain than the card's scenario is said in one
    line on stderr (it still scores: the option overrides)."""

    scenario = ((card or {}).get("episode") or {}).get("scenario")
    own = SCENARIO_VEHICLES.get(scenario) if isinstance(scenario, str) else None
    if given is None:
        return own or "corolla"
    if own is not None and (given == "leaf") != (own == "leaf"):
        click.echo(f"note: --vehicle {given}, but the run's card says the {scenario} scenario (vehicle {own})", err=True)
    return given


def _fmt(value: float | int | str | None) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, str | int) and not isinstance(value, bool):
        return str(value)
    x = float(value)
    if x == 0.0 or not math.isfinite(x):
        return f"{x:g}"
    return f"{x:.4g}" if abs(x) < 1e4 else f"{x:.4e}"


def platoon_metrics(folder: Path, as_json: bool) -> None:
    """Print a platoon folder's figures (:func:`vacc.platoon_cmd.platoon_figures`)."""
    from vacc.platoon_cmd import figure_lines, platoon_figures

    try:
        result = platoon_figures(folder)
    except RunLogError as e:
        raise click.ClickException(str(e)) from None
    if as_json:
        click.echo(json.dumps(json_safe(result["figures"]), indent=2, allow_nan=False))
        return
    click.echo("\n".join(figure_lines(result)))


@click.command("metrics")
@click.argument("run_csv", type=click.Path())
@click.option(
    "--vehicle",
    type=click.Choice(VEHICLE_NAMES),
    default=None,
    help="corolla: CMEM calibrated 2022 Corolla; average: paper-era CMEM category; leaf: EV eq. 6. "
    "Default: the scenario's on the log's card (ice: corolla, ev: leaf), else corolla.",
)
@click.option(
    "--time-gap",
    type=float,
    default=TIME_GAP_S,
    show_default=True,
    callback=finite_non_negative,
    help="t_gap of d_ref [s].",
)
@click.option(
    "--d-safe",
    type=float,
    default=D_SAFE_M,
    show_default=True,
    callback=finite_non_negative,
    help="d_safe of d_ref [m].",
)
@click.option(
    "--settle",
    type=float,
    default=SETTLE_S,
    show_default=True,
    callback=finite_non_negative,
    help="Seconds at the start left out of the comfort figures (accel, jerk, ISO windows, "
    "sign changes); gap RMSE, energy, safety and the unprompted hard brakes stay over the whole run.",
)
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def metrics(
    run_csv: str, vehicle: str | None, time_gap: float, d_safe: float, settle: float, as_json: bool
) -> None:
    """Print gap, safety, comfort and fuel/emission or energy metrics of RUN_CSV.

    The vehicle is the scenario's on the log's card (run.csv -> run.card.json);
    --vehicle overrides it, and one of the other powertrain is said on stderr.
    RUN_CSV may be a platoon's folder (vacc platoon --out): its string-stability,
    safety and energy figures are printed.
    """
    if Path(run_csv).is_dir():
        platoon_metrics(Path(run_csv), as_json)
        return
    try:
        card = read_card(run_csv)
    except InputFileError as e:  # the metrics stand without it
        click.echo(f"warning: {e}; the run's card is left out", err=True)
        card = None
    vehicle = card_vehicle(card, vehicle)
    try:
        result = evaluate_run(
            run_csv, vehicle, time_gap_s=time_gap, d_safe_m=d_safe, settle_s=settle
        )
    except RunLogError as e:
        raise click.ClickException(str(e)) from None
    if as_json:
        click.echo(json.dumps(json_safe(result), indent=2, allow_nan=False))
        return
    if card is not None:
        click.echo(card_line(card))
    width = max(len(k) for k in result)
    click.echo(f"{'metric':<{width}}  value")
    for key, value in result.items():
        click.echo(f"{key:<{width}}  {_fmt(value)}")
