"""`vacc demo`: the main job on a fresh machine.

It evaluates every method on the four ICE test trajectories (the paper's Table 3)
through real simulator processes over UDP and prints the table: the lead, the
traditional ACC, the Human Driver Model, and each shipped DDQN model that is
present (a missing one is named, and left out). ``--acc-only`` instead drives the
traditional ACC on one trajectory and scores that one run.
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
from protocol.scenarios import TEST_TRAJECTORIES
from vacc.paths import MODELS_DEFAULT, models_dir

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


def acc_only(out: Path, trajectory: str) -> None:
    """Drive the ACC on one trajectory and print its Table 3 style figures."""
    log = out / f"ice-{trajectory}-acc.csv"
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


@click.command("demo")
@click.option("--out", default="runs/demo", show_default=True, type=click.Path(file_okay=False), help="Where tables, figures and logs go.")
@click.option("--models", default=lambda: str(models_dir()), show_default=MODELS_DEFAULT, type=click.Path(file_okay=False), help="Where ice-gap.pt and ice-force.pt are.")
@click.option("--acc-only", "acc_only_", is_flag=True, help="Only drive the traditional ACC on --trajectory.")
@click.option("--trajectory", default="test-1", show_default=True, type=click.Choice(TEST_TRAJECTORIES), help="Trajectory of --acc-only.")
@click.pass_context
def demo(ctx: click.Context, out: str, models: str, acc_only_: bool, trajectory: str) -> None:
    """Evaluate every method on the ICE tests over UDP and print the paper's Table 3."""
    from vacc.evaluate import evaluate

    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    if acc_only_:
        acc_only(out_dir, trajectory)
        return
    methods = ["lead"]
    for reward in ("gap", "force"):
        path = Path(models) / f"ice-{reward}.pt"
        if path.is_file():
            methods.append(f"ddqn-{reward}")
        else:
            click.echo(f"note: {path} is not shipped; the {reward}-based DDQN column is left out")
    methods += ["acc", "human"]
    click.echo(f"Evaluating {', '.join(methods)} on ICE test-1..test-4 (240 s each) over UDP...")
    ctx.invoke(evaluate, scenario="ice", out=out, models=models, methods=",".join(methods))
