"""`vacc demo`: the main job on a fresh machine.

It evaluates every method on the four ICE test trajectories (the paper's Table 3)
through real simulator processes over UDP and prints the table: the lead, the
traditional ACC, the Human Driver Model, and each shipped DDQN model that is
present, the eco model included (a missing one is named, and left out). The
evaluation's folder also holds its figures and ``report.html``. ``--acc-only`` instead drives the
traditional ACC on one trajectory and scores that one run.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Any

import click

from agent_client.controllers.acc import AccController
from agent_client.drive import drive_episode
from agent_client.launcher import local_server
from agent_client.session import Session
from energy import evaluate_run
from protocol.scenarios import TEST_TRAJECTORIES
from vacc.paths import MODELS_DEFAULT, models_dir
from vacc.tables import PAPER

ROWS = (
    ("gap RMSE to 55 m", "gap_rmse_55m_m", "m", "lower"),
    ("collisions", "collisions", "", "lower"),
    ("min time-to-collision", "ttc_min_s", "s", "higher"),
    ("mean time headway", "headway_mean_s", "s", "~1.8"),
    ("jerk RMS", "jerk_rms_mps3", "m/s^3", "lower"),
    ("fuel", "fuel_g_per_mi", "g/mi", "lower"),
    ("CO2", "co2_g_per_mi", "g/mi", "lower"),
    ("CO", "co_g_per_mi", "g/mi", "lower"),
    ("HC", "hc_g_per_mi", "g/mi", "lower"),
    ("NOx", "nox_g_per_mi", "g/mi", "lower"),
)
"""--acc-only's rows: label, metric, unit, which way is better (headway: near the ACC's 1.8 s time gap)."""


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
    click.echo(f"{'metric':26} {'better':>7} {'2022 Corolla':>14} {'paper-era avg':>14}  unit")
    for label, key, unit, better in ROWS:
        a, b = corolla[key], paper_era[key]
        fa = "n/a" if a is None else f"{a:.3f}"
        fb = "n/a" if b is None else f"{b:.3f}"
        click.echo(f"{label:26} {better:>7} {fa:>14} {fb:>14}  {unit}")
    click.echo("")
    paper = PAPER["ice"]
    acc = paper["methods"].index("acc")
    figures = ", ".join(f"{name} {values[acc]:g}" for name, values in paper["rows"].items())
    click.echo(f"Paper, Table 3 (ACC, ICE average of 4 runs; lower is better): {figures}.")
    click.echo(f"Run log: {log}  (recompute with: vacc metrics {log} --vehicle corolla)")


SHORT = {
    "ddqn-gap": "the gap-based DDQN",
    "ddqn-force": "the force-based DDQN",
    "ddqn-eco": "the eco DDQN",
    "acc": "the traditional ACC",
    "human": "the human driver",
}
"""How the reading names a method."""


def _paper_rows(scenario: str) -> tuple[str, str, str, str]:
    """The paper's energy row and gap row: (energy name, energy key, gap name, gap key)."""
    paper = PAPER[scenario]
    (energy, gap) = paper["rows"]
    return energy, paper["keys"][energy], gap, paper["keys"][gap]


def beside_paper(result: dict[str, dict[str, Any]], scenario: str) -> list[str]:
    """Lines of a table: each of the paper's rows, which way is better, ours and the
    paper's figure for each of the paper's methods that ``result`` has.

    Args:
        result: metrics per method, as :func:`vacc.tables.build_tables` returns them.
    """
    paper = PAPER[scenario]
    columns = [(m, c) for m, c in zip(paper["methods"], paper["columns"], strict=True) if m in result]
    width = 20
    lines = [
        f"Ours beside the paper's Table {'3' if scenario == 'ice' else '4'} (Wei et al. 2019), means over the test trajectories; each cell: ours / paper",
        f"{'metric':22} {'better':7}" + "".join(f" {c:>{width}}" for _, c in columns),
    ]
    for name, values in paper["rows"].items():
        key = paper["keys"][name]
        theirs = dict(zip(paper["methods"], values, strict=True))
        cells = []
        for m, _ in columns:
            ours = result[m].get(key)
            cells.append(f"{'n/a' if ours is None else f'{ours:.4g}'} / {theirs[m]:.4g}")
        lines.append(f"{name:22} {'lower':7}" + "".join(f" {c:>{width}}" for c in cells))
    lines.append("The paper's vehicle models and human drivers differ from ours: compare orders and ratios, not absolutes.")
    return lines


def reading(result: dict[str, dict[str, Any]], scenario: str) -> str:
    """One line that reads the table: who follows tightest, who burns the most and the
    least energy, whether the paper agrees, and whose ride is the roughest. Derived from
    ``result`` and :data:`vacc.tables.PAPER` only.

    Args:
        result: metrics per method, as :func:`vacc.tables.build_tables` returns them.
    """
    energy_name, energy_key, _, gap_key = _paper_rows(scenario)
    unit = energy_name[energy_name.index("(") + 1:-1]
    what = "fuel" if scenario == "ice" else "energy"
    paper = PAPER[scenario]
    ours = [m for m in paper["methods"] if m in result and result[m].get(gap_key) is not None and result[m].get(energy_key) is not None]
    if len(ours) < 2:
        return f"Fewer than two of the paper's methods were evaluated ({', '.join(ours) or 'none'}): nothing to compare."
    theirs = {key: dict(zip(paper["methods"], paper["rows"][name], strict=True)) for name, key in paper["keys"].items()}
    tight = min(ours, key=lambda m: result[m][gap_key])
    hungry = max(ours, key=lambda m: result[m][energy_key])
    frugal = min(ours, key=lambda m: result[m][energy_key])
    p_tight = min(ours, key=lambda m: theirs[gap_key][m])  # among the same methods
    p_hungry = max(ours, key=lambda m: theirs[energy_key][m])
    e_max, e_min = result[hungry][energy_key], result[frugal][energy_key]
    burns = f"burns the most {what} ({e_max:.0f} {unit}, {e_max / e_min:.1f}x {SHORT[frugal]}'s {e_min:.0f})"
    if tight == hungry:
        text = f"{SHORT[tight]} follows tightest ({result[tight][gap_key]:.2f} m gap RMSE) and {burns}"
    else:
        text = f"{SHORT[tight]} follows tightest ({result[tight][gap_key]:.2f} m gap RMSE); {SHORT[hungry]} {burns}"
    if (tight, hungry) == (p_tight, p_hungry):
        text += ", as in the paper."
    elif tight == p_tight:
        text += f". In the paper, too, {SHORT[tight]} follows tightest, but {SHORT[p_hungry]} burns the most {what}."
    elif hungry == p_hungry:
        text += f". In the paper {SHORT[p_tight]} follows tightest, and {SHORT[hungry]} burns the most {what} too."
    else:
        text += f". In the paper {SHORT[p_tight]} follows tightest and {SHORT[p_hungry]} burns the most {what}."
    jerky = [m for m in result if m != "lead" and result[m].get("jerk_rms_mps3") is not None]
    if len(jerky) >= 2:
        rough = max(jerky, key=lambda m: result[m]["jerk_rms_mps3"])
        smooth = min(jerky, key=lambda m: result[m]["jerk_rms_mps3"])
        text += (f" The roughest ride is {SHORT.get(rough, rough)}'s (jerk RMS {result[rough]['jerk_rms_mps3']:.2f} m/s^3 against "
                 f"{result[smooth]['jerk_rms_mps3']:.2f} for {SHORT.get(smooth, smooth)}); the paper reports no comfort figure.")  # fmt: skip
    return text[0].upper() + text[1:]


@click.command("demo")
@click.option("--out", default="runs/demo", show_default=True, type=click.Path(file_okay=False), help="Where tables, figures and logs go.")
@click.option("--models", default=lambda: str(models_dir()), show_default=MODELS_DEFAULT, type=click.Path(file_okay=False), help="Where ice-gap.pt and ice-force.pt are.")
@click.option("--acc-only", "acc_only_", is_flag=True, help="Only drive the traditional ACC on --trajectory.")
@click.option("--trajectory", default="test-1", show_default=True, type=click.Choice(TEST_TRAJECTORIES), help="Trajectory of --acc-only.")
@click.option("--duration", default=None, type=click.FloatRange(min=0.5), help="Drive only this many seconds of each trajectory (a quick look; the paper's figures are over the whole 240 s).")
@click.option("--jobs", default=os.cpu_count() or 1, show_default=True, type=click.IntRange(1, 64), help="Runs in parallel.")
@click.pass_context
def demo(ctx: click.Context, out: str, models: str, acc_only_: bool, trajectory: str, duration: float | None, jobs: int) -> None:
    """Evaluate every method on the ICE tests over UDP and print the paper's Table 3
    beside ours, which way each row is better, and a line of reading."""
    from vacc.evaluate import evaluate

    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    if acc_only_:
        acc_only(out_dir, trajectory)
        return
    methods = ["lead"]
    for reward in ("gap", "force", "eco"):  # the eco model too: the learned policy that beats the ACC's fuel
        path = Path(models) / f"ice-{reward}.pt"
        if path.is_file():
            methods.append(f"ddqn-{reward}")
        else:
            click.echo(f"note: {path} is not shipped; the {SHORT[f'ddqn-{reward}'].removeprefix('the ')} column is left out")
    methods += ["acc", "human"]
    click.echo(f"Evaluating {', '.join(methods)} on ICE test-1..test-4 ({duration or 240:g} s each) over UDP...")
    result = ctx.invoke(evaluate, scenario="ice", out=out, models=models, methods=",".join(methods), duration=duration, jobs=jobs)
    click.echo("")
    for line in beside_paper(result, "ice"):
        click.echo(line)
    click.echo("")
    click.echo("Reading: " + reading(result, "ice"))
    click.echo(f"Open {out_dir / 'report.html'} in a browser: every table, every figure and each run's card in one file.")
