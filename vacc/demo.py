"""`vacc demo`: the main job on a fresh machine.

Until trained DDQN models ship, the demo drives the traditional ACC on the ICE
test-1 trajectory through a real simulator process over UDP and scores the run
like the paper's Table 3.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import click

from agent_client.controllers.acc import AccController
from agent_client.drive import drive_episode
from agent_client.launcher import local_server
from agent_client.session import Session
from energy import evaluate_run

ROWS = (
    ("gap RMSE to 55 m", "gap_rmse_55m_m", "m"),
    ("collisions", "collisions", ""),
    ("min time-to-collision", "ttc_min_s", "s"),
    ("mean time headway", "headway_mean_s", "s"),
    ("jerk RMS", "jerk_rms_mps3", "m/s^3"),
    ("fuel", "fuel_g_per_mi", "g/mi"),
    ("CO2", "co2_g_per_mi", "g/mi"),
    ("CO", "co_g_per_mi", "g/mi"),
    ("HC", "hc_g_per_mi", "g/mi"),
    ("NOx", "nox_g_per_mi", "g/mi"),
)


@click.command("demo")
@click.option("--out", default="runs/demo", show_default=True, type=click.Path(file_okay=False), help="Where the run log goes.")
@click.option("--trajectory", default="test-1", show_default=True, type=click.Choice(["test-1", "test-2", "test-3", "test-4"]))
def demo(out: str, trajectory: str) -> None:
    """Drive the ACC on an ICE test trajectory over UDP and print a scored summary."""
    log = Path(out) / f"ice-{trajectory}-acc.csv"
    click.echo(f"Spawning a simulator server and driving the traditional ACC on ICE {trajectory} (240 s)...")
    with local_server(stderr=subprocess.DEVNULL) as addr, Session(addr, client_name="vacc-demo") as session:
        summary = drive_episode(session, AccController(), scenario="ice", seed=0, trajectory=trajectory, log=log)
    for line in summary.lines():
        click.echo("  " + line)
    corolla = evaluate_run(log, "corolla")
    paper_era = evaluate_run(log, "average")
    click.echo("")
    click.echo(f"{'metric':26} {'2022 Corolla':>14} {'paper-era avg':>14}  unit")
    for label, key, unit in ROWS:
        a, b = corolla[key], paper_era[key]
        fa = "n/a" if a is None else f"{a:.3f}"
        fb = "n/a" if b is None else f"{b:.3f}"
        click.echo(f"{label:26} {fa:>14} {fb:>14}  {unit}")
    click.echo("")
    click.echo("Paper, Table 3 (ACC, ICE average of 4 runs): gap RMSE 6.667 m, fuel 143.8 g/mi.")
    click.echo(f"Run log: {log}  (recompute with: vacc metrics {log} --vehicle corolla)")
