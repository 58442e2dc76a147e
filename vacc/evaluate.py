"""`vacc evaluate`: every method on the same trajectories, scored as the paper's Tables 3 and 4.

Three suites, one function each; the click command only parses its options and
dispatches:

* :func:`paper_suite` (``--suite paper``): every method on test-1..test-4, the paper's
  tables (:mod:`vacc.tables`) and figures (:mod:`vacc.figures`). The lead vehicle is
  scored on its own trajectory (as in the paper); its logs carry the lead's speed as
  ``v_host`` and a 55 m placeholder gap, so gap rows are blank for it.
* :func:`safety_suite` (``--suite safety``): the ACC and the models through every lead
  scenario, with a pass/fail table (:mod:`vacc.safety`).
* :func:`random_suite` (``--suite random``): the ACC and the models on held-out random
  episodes (:mod:`vacc.random_suite`).

The runs themselves (jobs, driving, scoring) are :mod:`vacc.runs`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import click

from agent_client.drive import COLD_START_HELP
from agent_client.launcher import DEFAULT_ROAD, Road
from agent_client.outputs import writable_dir_option
from energy import SCENARIO_VEHICLES, SETTLE_S
from protocol.constants import (
    MAX_FOLLOWERS,
    SUN_ELEVATION,
    TRAFFIC_PER_LANE,
    TRAFFIC_PER_LANE_RANGE,
)
from protocol.options import SunElevation
from protocol.scenarios import LEAD_SCENARIOS, SCENARIOS
from vacc import figures, stats
from vacc.metrics_cmd import finite_non_negative
from vacc.paths import MODELS_DEFAULT, models_dir
from vacc.random_suite import RANDOM_SEEDS, run_random
from vacc.report import write_report
from vacc.runs import (
    TRAJECTORIES,
    Job,
    Run,
    drive_jobs,
    log_path,
    parse_seeds,
    score_runs,
    seed_text,
)
from vacc.safety import run_suite
from vacc.tables import build_tables
from vacc.video import make_videos

__all__ = [
    "METHODS", "SUITE_METHODS", "LABELS", "OPTIONAL", "HDM_LABEL", "DEFAULT_VEHICLE", "SUITES", "SUITE_SEEDS",
    "SAFETY_SEEDS", "paper_suite", "safety_suite", "random_suite", "evaluate",
]  # fmt: skip

METHODS = ("lead", "ddqn-gap", "ddqn-force", "ddqn-eco", "acc", "human")
SUITE_METHODS = ("acc", "ddqn-gap", "ddqn-force", "ddqn-eco")  # what --suite safety and --suite random drive
LABELS = {
    "lead": "Lead vehicle",
    "ddqn-gap": "Gap-based DDQN",
    "ddqn-force": "Force-based DDQN",
    "ddqn-eco": "Eco DDQN",
    "acc": "Traditional ACC",
}
OPTIONAL = ("ddqn-eco",)  # beyond the paper: in the default methods only where its model is shipped
HDM_LABEL = "Human Driver Model (Treiber et al. 2006)"
DEFAULT_VEHICLE = SCENARIO_VEHICLES

SUITES = ("paper", "safety", "random", "openacc", "string")
SAFETY_SEEDS = "0-9"
"""The safety suite's seeds when neither --seed nor --seeds is given (the paper suite's: 0)."""
SUITE_SEEDS = {"paper": "0", "safety": SAFETY_SEEDS, "random": RANDOM_SEEDS}
"""Each suite's seeds when neither --seed nor --seeds is given."""


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


MODEL_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+]*(-[A-Za-z0-9_.+]+)*")  # a log file's stem: logs/<NAME>-test-1.csv


def parse_models(values: tuple[str, ...], scenario: str | None) -> dict[str, str]:
    """--model NAME=PATH (repeatable): any checkpoint, evaluated as a method named NAME
    (trained for ``scenario``; None: either, as in a platoon each drives its own vehicle).

    Raises:
        click.BadParameter: not NAME=PATH, a NAME taken by a method or given twice, no such
            file, an unreadable checkpoint, or one trained for the other scenario (one line).
    """
    models: dict[str, str] = {}
    for item in values:
        name, sep, path = item.partition("=")
        if not sep or not MODEL_NAME.fullmatch(name) or name in METHODS or name in models:
            why = "is not NAME=PATH" if not sep or not MODEL_NAME.fullmatch(name) else f"names {name!r}, which is taken"
            raise click.BadParameter(f"{item!r} {why} (NAME: letters, digits, . _ + -; not one of {', '.join(METHODS)})", param_hint="--model")
        if not Path(path).is_file():
            raise click.BadParameter(f"{path}: no such checkpoint", param_hint="--model")
        from agent_client.errors import InputFileError
        from agent_client.rl.checkpoint import read_checkpoint  # torch only when a model is given

        try:
            trained = read_checkpoint(path)["config"].get("scenario", "ice")
        except InputFileError as exc:
            raise click.BadParameter(str(exc), param_hint="--model") from None
        if scenario is not None and trained != scenario:
            raise click.BadParameter(f"{path} was trained for the {trained} scenario, not {scenario}: add --scenario {trained}", param_hint="--model")
        models[name] = path
    return models


def _seed_list(seed: int | None, seeds: str | None, suite: str) -> list[int]:
    """The episode seeds of --seed (one) or --seeds (a range or list), whichever is given.

    Raises:
        click.BadParameter: both are given, or --seeds is not a seed list.
    """
    if seed is not None and seeds is not None:
        raise click.BadParameter(f"give --seed {seed} or --seeds {seeds}, not both (--seed N is --seeds N)", param_hint="--seed/--seeds")
    if seed is not None:
        if seed < 0:
            raise click.BadParameter(f"{seed} is negative; a seed is >= 0", param_hint="--seed")
        return [seed]
    try:
        return parse_seeds(seeds if seeds is not None else SUITE_SEEDS[suite])
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


def _suite_methods(methods: str, suite: str) -> list[str]:
    """--methods for the safety or random suite, which drive the ACC and the DDQN models only.

    Raises:
        click.BadParameter: an unknown method, one the suite does not drive, or none at all.
    """
    chosen = _method_list(methods)
    other = sorted(set(chosen) - set(SUITE_METHODS))
    if other or not chosen:
        raise click.BadParameter(f"the {suite} suite drives {', '.join(SUITE_METHODS)} only, got {methods!r}", param_hint="--methods")
    return chosen


def _suite_drivers(models: Path, vehicles: Iterable[str], methods: str | None, suite: str,
                   extra: dict[str, str] | None = None) -> tuple[bool, dict[str, str]]:  # fmt: skip
    """Whether the ACC drives, and the models that do (name -> path): those of ``vehicles``
    in ``models``, then each ``extra`` checkpoint (--model), whatever --methods says.

    Without --methods: the ACC and every model. With it: the ACC and the models of the
    chosen kinds only (ev-eco.pt and ev-eco-b.pt are both ddqn-eco).

    Raises:
        click.BadParameter: --methods names a method the suite does not drive, or leaves
            nothing to drive; a --model name is also a model's in ``models``.
    """
    vehicles, extra = tuple(vehicles), extra or {}
    found = {p.stem: str(p) for p in sorted(models.glob("*.pt")) if p.stem.split("-")[0] in vehicles}
    chosen = _suite_methods(methods, suite) if methods is not None else None
    if chosen is not None:
        found = {stem: path for stem, path in found.items() if "ddqn-" + (stem.split("-") + [""])[1] in chosen}
        if "acc" not in chosen and not found and not extra:
            raise click.BadParameter(f"no model of {', '.join(chosen)} for {', '.join(vehicles)} in {models}", param_hint="--methods")
    if taken := sorted(found.keys() & extra.keys()):
        raise click.BadParameter(f"--model {taken[0]}=... names {models / (taken[0] + '.pt')} too: give it another NAME", param_hint="--model")
    return chosen is None or "acc" in chosen, found | extra


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


def _paper_checkpoints(chosen: list[str], models: Path, scenario: str) -> dict[str, str]:
    """The checkpoint of each ddqn-* method: ``<models>/<scenario>-<reward>.pt``.

    Raises:
        click.ClickException: a model file is missing (the message says how to train it).
    """
    checkpoints = {}
    for m in chosen:
        if m.startswith("ddqn-"):
            path = models / f"{scenario}-{m.removeprefix('ddqn-')}.pt"
            if not path.is_file():
                raise click.ClickException(
                    f"model file {path} not found. Train it with: vacc train --reward {m.removeprefix('ddqn-')} "
                    f"--scenario {scenario} --steps 200000 --out runs/{scenario}-{m.removeprefix('ddqn-')} "
                    f"(then copy runs/.../best.pt to {path}), or leave {m} out of --methods"
                )
            checkpoints[m] = str(path)
    return checkpoints


def _paper_figures(
    out: Path, runs: list[Run], labels: dict[str, str], scenario: str, chosen: list[str], vehicle: str, settle: float,
    seeds: list[int] | None, models: Path, duration: float | None,
) -> list[figures.Written]:  # fmt: skip
    return [
        *figures.plot_runs(out, runs, labels, scenario, duration=duration),
        figures.plot_comfort(out, runs, labels, scenario, settle, duration=duration),
        figures.plot_emissions(out, runs, labels, scenario, duration=duration),
        figures.plot_headway(out, runs, labels, scenario, duration=duration),
        figures.plot_pareto(out, scenario, chosen, labels, vehicle, settle, seeds=seeds, runs=runs, duration=duration),
        figures.plot_training(out, models, scenario),
    ]


def _paper_jobs(
    out: Path, scenario: str, methods: str | None, models: Path, seeds: list[int], human_files: tuple[str, ...],
    extra: dict[str, str], duration: float | None, cold_start: bool, road: Road, view: bool,
) -> tuple[list[str], dict[str, str], list[Job]]:  # fmt: skip
    """The methods (with the --model ones last), their column names and the jobs of the paper suite.

    Raises:
        click.BadParameter: an unknown method, a bad --human-file, or one over several seeds.
        click.ClickException: a model file is missing.
    """
    if methods is None:
        methods = ",".join(m for m in METHODS if m not in OPTIONAL or (models / f"{scenario}-{m.removeprefix('ddqn-')}.pt").is_file())
    chosen = _method_list(methods)
    files = _parse_human_files(human_files)
    multi = len(seeds) > 1
    if files and multi:
        raise click.BadParameter("a recorded drive is of one seed; give --human-file with one --seed", param_hint="--human-file")
    checkpoints = {**_paper_checkpoints(chosen, models, scenario), **extra}
    labels = {**LABELS, **{name: name for name in extra}}
    labels["human"] = "Human (recorded)" if files else HDM_LABEL
    chosen += list(extra)
    work = [
        Job(m, t, scenario, s, str(log_path(out, m, t, s if multi else None)), duration, checkpoints.get(m), files.get(t) if m == "human" else None,
            cold_start, road, view)  # fmt: skip
        for m in chosen
        for t in TRAJECTORIES
        for s in seeds
    ]
    return chosen, labels, work


def paper_suite(
    out: Path, scenario: str, methods: str | None, models: Path, seeds: list[int], *, human_files: tuple[str, ...] = (),
    vehicle: str | None = None, duration: float | None = None, jobs: int = 1, settle: float = SETTLE_S,
    cold_start: bool = False, road: Road = DEFAULT_ROAD, extra: dict[str, str] | None = None, include_early: bool = False,
    view: bool = False, videos: bool = False, figures: bool = True,
) -> dict[str, Any]:  # fmt: skip
    """Every method on test-1..test-4: drive, write table.md/.csv (and stats.csv), the figures and report.html.

    Args:
        methods: --methods, comma-separated; None: every method whose model is in ``models``.
        seeds: the episode seeds; over several, the logs are named by seed.
        duration: drive only this many seconds of each trajectory [s]; None: all of it.
        settle: seconds at the start of each run left out of the comfort rows [s].
        extra: --model: method name -> checkpoint, driven beside ``methods``.
        include_early: keep the runs that ended before their duration in the tables' values.
        view: watch each run in a window, one at a time.
        videos: write one video per run into ``out/videos`` (linked from the report).
        figures: draw the figures (False: tables, logs and the report only).

    Returns:
        The combined metrics per method (see :func:`vacc.tables.build_tables`).

    Raises:
        click.BadParameter: an unknown method, a bad --human-file, or one over several seeds.
        click.ClickException: a model file is missing, or a run failed.
    """
    chosen, labels, work = _paper_jobs(out, scenario, methods, models, seeds, human_files, extra or {}, duration, cold_start, road, view)
    multi = len(seeds) > 1
    (out / "logs").mkdir(parents=True, exist_ok=True)
    named = seeds if multi else None  # one seed: logs/<method>-<trajectory>.csv as always
    drive_jobs(work, jobs, f"evaluate {scenario}" + (f", seeds {seed_text(seeds)}" if multi else ""))
    veh = vehicle or DEFAULT_VEHICLE[scenario]
    runs = score_runs(out, chosen, veh, settle, named, duration, ends=True)
    result = build_tables(out, scenario, chosen, labels, veh, settle, named, runs, road, include_early)
    written = _paper_figures(out, runs, labels, scenario, chosen, veh, settle, named, models, duration) if figures else []
    made = make_videos(work, out, jobs) if videos else {}
    title = (out / "table.md").read_text().splitlines()[0].lstrip("# ")
    write_report(out, title=title, figures=[w.name for w in written], runs=runs, jobs=work, labels=labels, scenario=scenario, videos=made)
    click.echo((out / "table.md").read_text().split("\n## The paper")[0].rstrip())
    for w in written:
        if w.empty:
            click.echo(f"{w.name}: nothing to plot: {w.empty}")
    tables = "table.md, table.csv" + (", stats.csv" if multi else "")
    drawn = f"{', '.join(w.name for w in written)} (.png and .pdf each), " if written else ""
    click.echo(f"\nWrote {out}/{tables}, {drawn}report.html"
               + (", videos/" if made else "") + " and logs/")  # fmt: skip
    return result


def safety_suite(
    out: Path, vehicles: tuple[str, ...], methods: str | None, models: Path, seeds: list[int], *, jobs: int = 1,
    cold_start: bool = False, leads: tuple[str, ...] = tuple(LEAD_SCENARIOS), road: Road = DEFAULT_ROAD,
    extra: dict[str, str] | None = None, extra_vehicle: str = "ice",
) -> None:  # fmt: skip
    """The ACC of each of ``vehicles`` and their models through the lead scenarios ``leads``,
    and each ``extra`` checkpoint (--model; it drives ``extra_vehicle``): write
    safety.md/.csv and print the table.

    Raises:
        click.BadParameter: --methods names nothing the suite can drive, or a --model name is a model's in --models.
        click.ClickException: a run failed.
    """
    with_acc, found = _suite_drivers(models, vehicles, methods, "safety", extra)
    own = dict.fromkeys(extra or {}, extra_vehicle)
    click.echo(run_suite(out, found, seeds, jobs, cold_start, vehicles, leads, acc=with_acc, road=road, model_vehicles=own))
    click.echo(f"Wrote {out}/safety.md, safety.csv and logs/")


def random_suite(
    out: Path, scenario: str, methods: str | None, models: Path, seeds: list[int], *, vehicle: str | None = None,
    duration: float | None = None, jobs: int = 1, settle: float = SETTLE_S, cold_start: bool = False,
    road: Road = DEFAULT_ROAD, extra: dict[str, str] | None = None,
) -> None:  # fmt: skip
    """The ACC and the ``scenario`` models (and each ``extra`` checkpoint, --model) on the
    random episodes of ``seeds``: write summary.json and random.md and print the table.

    Raises:
        click.BadParameter: --methods names nothing the suite can drive, or a --model name is a model's in --models.
        click.ClickException: a run failed.
    """
    with_acc, found = _suite_drivers(models, (scenario,), methods, "random", extra)
    veh = vehicle or DEFAULT_VEHICLE[scenario]
    click.echo(run_random(out, found, scenario, seeds, jobs, veh, settle, with_acc, duration, cold_start, road), nl=False)
    click.echo(f"Wrote {out}/summary.json, random.md and logs/")


def openacc_suite(out: Path, methods: str | None, model_files: tuple[str, ...] = (), followers: int | None = None) -> None:
    """Platoons of the laws (and of each --model, from its camera) behind the nine OpenACC
    leads, beside the real platoons (:mod:`vacc.openacc_suite`): write openacc.md and
    openacc.json and print the table.

    Raises:
        click.BadParameter: --methods names a platoon kind that does not exist, or a bad --model.
    """
    from vacc.openacc_suite import PLATOONS, run_openacc

    kinds = list(PLATOONS) if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
    if (not kinds and not model_files) or any(k not in PLATOONS for k in kinds):
        raise click.BadParameter(f"the openacc suite drives platoons of {', '.join(PLATOONS)}, got {methods!r}", param_hint="--methods")
    models = parse_models(model_files, None)  # each model drives its own vehicle
    if models.keys() & set(kinds):
        raise click.BadParameter(f"--model names {sorted(models.keys() & set(kinds))}, which are platoon kinds", param_hint="--model")
    click.echo(run_openacc(out, platoons=kinds, models=models, followers=followers), nl=False)
    click.echo(f"Wrote {out}/openacc.md and openacc.json")


def string_suite(out: Path, methods: str | None, model_files: tuple[str, ...], followers: int | None, seeds: str | None) -> None:
    """Each law's and --model's speed-to-speed gain behind sinusoidal leads and its platoons
    behind held-out random leads (:mod:`vacc.string_suite`): write string.md and string.json
    and print the tables.

    Raises:
        click.BadParameter: --methods names no law, or a bad --model or --seeds.
    """
    from vacc.string_suite import FOLLOWERS, LAWS, LEAD_SEEDS, law_maker, model_maker, run_string

    laws = ["acc"] if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
    if (not laws and not model_files) or any(k not in LAWS for k in laws):
        raise click.BadParameter(f"the string suite drives the laws {', '.join(LAWS)}, got {methods!r}", param_hint="--methods")
    models = parse_models(model_files, None)
    if models.keys() & set(laws):
        raise click.BadParameter(f"--model names {sorted(models.keys() & set(laws))}, which are laws", param_hint="--model")
    drivers = {name: law_maker(name) for name in laws} | {name: model_maker(path) for name, path in models.items()}
    lead_seeds = LEAD_SEEDS if seeds is None else parse_seeds(seeds)
    n = FOLLOWERS if followers is None else followers
    click.echo(run_string(out, drivers, followers=n, seeds=lead_seeds), nl=False)
    click.echo(f"Wrote {out}/string.md and string.json")


_PLATOON_SUITE_OPTIONS = {"openacc": ("out", "methods", "suite", "model_files", "followers"),
                          "string": ("out", "methods", "suite", "model_files", "followers", "seeds")}  # fmt: skip


def _not_for_platoons(ctx: click.Context, suite: str) -> None:
    """Refuse the options that the openacc or string suite would ignore.

    Raises:
        click.BadParameter: one line naming the option.
    """
    takes = _PLATOON_SUITE_OPTIONS[suite]
    for param in ctx.command.params:
        if param.name not in takes and ctx.get_parameter_source(param.name) == click.core.ParameterSource.COMMANDLINE:  # type: ignore[arg-type]
            names = ", ".join("--" + t.replace("model_files", "model").replace("_", "-") for t in takes if t != "suite")
            raise click.BadParameter(f"the {suite} suite takes {names} only", param_hint=param.opts[0] if param.opts else param.name)


def _paper_only(suite: str, given: dict[str, Any]) -> None:
    """Refuse the paper suite's options with another suite, and --view without a window to show.

    Raises:
        click.BadParameter, click.ClickException: one line.
    """
    for option, value in given.items():
        if value and suite != "paper":
            raise click.BadParameter(f"{option} works with --suite paper only", param_hint=option)
    if given.get("--view"):
        from agent_client.controllers.keyboard import require_display, require_pygame
        from agent_client.errors import ClientError

        try:
            require_pygame()
            require_display()
        except ClientError as exc:
            raise click.ClickException(str(exc)) from None


@click.command("evaluate")
@click.option("--scenario", default="ice", show_default=True, type=click.Choice(["ice", "ev"]))
@click.option("--out", required=True, type=click.Path(file_okay=False), callback=writable_dir_option, help="Folder for tables, figures and run logs.")
@click.option("--methods", default=None, help="Comma-separated subset of: " + ", ".join(METHODS) + f". Default: all; {', '.join(OPTIONAL)} only where its model is in --models. With --suite safety or random: acc and the models of the chosen kinds (ev-eco.pt and ev-eco-*.pt are ddqn-eco); default: the ACC and every model.")
@click.option("--models", default=lambda: str(models_dir()), show_default=MODELS_DEFAULT, type=click.Path(file_okay=False), help="Where <scenario>-gap.pt and <scenario>-force.pt are.")
@click.option("--human-file", "human_files", multiple=True, metavar="TRAJ=PATH", help="Recorded human drive for a trajectory; else the Human Driver Model.")
@click.option("--vehicle", default=None, type=click.Choice(["corolla", "average", "leaf"]), help="Energy model; default corolla (ICE) or leaf (EV).")
@click.option("--duration", default=None, type=click.FloatRange(min=0.5), help="Drive only this many seconds of each trajectory.")
@click.option("--seeds", default=None, metavar="SEEDS", help=f"Episode seeds, a range or a list: 0-9, 0,3,5 or 0-2,7. Over several, the paper suite's tables give means with {stats.CONFIDENCE:.0%} bootstrap intervals and the interquartile mean, and the figures the spread over seeds. Default: " + ", ".join(f"{v} ({k})" for k, v in SUITE_SEEDS.items()) + ".")
@click.option("--seed", default=None, type=int, help="One episode seed (initial conditions, traffic, scenery); the same as --seeds N.")
@click.option("--jobs", default=os.cpu_count() or 1, show_default=True, type=click.IntRange(1, 64), help="Runs in parallel.")
@click.option("--settle", default=SETTLE_S, show_default=True, type=float, callback=finite_non_negative, help="Seconds at the start of each run left out of the comfort rows [s] (not of the unprompted hard brakes, counted from engagement).")
@click.option("--cold-start", is_flag=True, help=COLD_START_HELP)
@click.option("--lead-scenarios", default=None, metavar="NAMES", help="With --suite safety: only these lead scenarios, comma-separated. Default: every one (" + ", ".join(LEAD_SCENARIOS) + ").")
@click.option("--traffic", default=TRAFFIC_PER_LANE, show_default=True, type=click.IntRange(*TRAFFIC_PER_LANE_RANGE), help="Cars in each adjacent lane (twice as many oncoming) of every run: the spawned servers' --traffic. A camera policy's neighbours are what it may mistake for a threat.")
@click.option("--sun-elevation", default=",".join(map(str, SUN_ELEVATION)), show_default=True, type=SunElevation(), help="Range [rad] of each run's sun height: the spawned servers' --sun-elevation (the test trajectories keep a fixed sun). A low sun throws shadows across the lane, which a camera policy may take for a car.")
@click.option("--suite", default="paper", show_default=True, type=click.Choice(SUITES), help="paper: Tables 3/4 on test-1..test-4. safety: the ACC and every model in --models through every lead scenario (docs/scenarios.md) over --seeds, with a pass/fail table; both vehicles unless --scenario is given. random: the ACC and the --scenario models in --models on held-out random episodes over --seeds (summary.json, random.md). openacc: platoons of the laws (--methods acc,hdm,mixed) behind the nine real OpenACC leads, beside the real platoons' amplification (openacc.md). string: each law's (--methods, default acc) and model's speed gain behind sinusoidal leads and its platoons behind held-out random leads (--seeds, default 7001-7003; string.md).")
@click.option("--model", "model_files", multiple=True, metavar="NAME=PATH", help="Also evaluate this checkpoint, as a method named NAME (repeatable; --suite paper, safety and random, or openacc and string: a platoon of it). A checkpoint trained for the other scenario than --scenario's is refused.")
@click.option("--followers", default=None, type=click.IntRange(1, MAX_FOLLOWERS), help="Followers in each platoon of --suite openacc (default: the real platoon's length) and string (default: 10).")
@click.option("--include-early", is_flag=True, help="Keep the runs that ended before their duration (a collision, a lost lead) in the tables' values; by default they are left out, and listed either way.")
@click.option("--view", is_flag=True, help="Watch each run in a window, one at a time (--suite paper): the camera, a head-up strip and a scrolling plot. The logs are the same as without it.")
@click.option("--videos", is_flag=True, help="Write one video per run into OUT/videos (vacc video), linked from report.html (--suite paper).")
@click.option("--no-figures", is_flag=True, help="Tables, logs and report.html without the figures (--suite paper): the figures take most of a short evaluation's time.")
def evaluate(
    scenario: str, out: str, methods: str | None, models: str, human_files: tuple[str, ...], vehicle: str | None,
    duration: float | None, seeds: str | None, seed: int | None, jobs: int, settle: float, cold_start: bool,
    lead_scenarios: str | None, traffic: int, sun_elevation: tuple[float, float], suite: str, model_files: tuple[str, ...] = (),
    followers: int | None = None, include_early: bool = False, view: bool = False, videos: bool = False, no_figures: bool = False,
) -> dict[str, Any] | None:  # fmt: skip
    """Run every method on test-1..test-4 over UDP and write the paper's tables and figures
    (or, with --suite safety, drive every lead scenario and write a pass/fail table; with
    --suite random, drive held-out random episodes and write a summary; with --suite
    openacc, drive law platoons behind the nine real OpenACC leads beside the real ones).

    Returns the combined metrics per method of the paper suite (see build_tables).
    """
    if suite in _PLATOON_SUITE_OPTIONS:
        _not_for_platoons(click.get_current_context(), suite)
        if suite == "openacc":
            openacc_suite(Path(out), methods, model_files, followers)
        else:
            string_suite(Path(out), methods, model_files, followers, seeds)
        return None
    if followers is not None:
        raise click.BadParameter("sets the platoons' length of --suite openacc and --suite string only", param_hint="--followers")
    seed_list = _seed_list(seed, seeds, suite)
    road = Road(traffic, sun_elevation)
    if suite == "paper" and road.sun_elevation != SUN_ELEVATION:
        raise click.BadParameter("test-1..test-4 keep a fixed sun; the lead scenarios draw theirs: add --suite safety", param_hint="--sun-elevation")
    leads = _lead_scenarios(lead_scenarios, suite)
    _paper_only(suite, {"--include-early": include_early, "--view": view, "--videos": videos, "--no-figures": no_figures})
    extra = parse_models(model_files, scenario)
    out_dir, models_path = Path(out), Path(models)
    if suite == "safety":
        # Both vehicles, unless --scenario was given: then that one's ACC and models only.
        given = click.get_current_context().get_parameter_source("scenario") == click.core.ParameterSource.COMMANDLINE
        vehicles = (scenario,) if given else SCENARIOS
        safety_suite(out_dir, vehicles, methods, models_path, seed_list, jobs=jobs, cold_start=cold_start, leads=leads, road=road,
                     extra=extra, extra_vehicle=scenario)  # fmt: skip
        return None
    if suite == "random":
        random_suite(out_dir, scenario, methods, models_path, seed_list, vehicle=vehicle, duration=duration, jobs=jobs,
                     settle=settle, cold_start=cold_start, road=road, extra=extra)  # fmt: skip
        return None
    return paper_suite(out_dir, scenario, methods, models_path, seed_list, human_files=human_files, vehicle=vehicle, duration=duration,
                       jobs=jobs, settle=settle, cold_start=cold_start, road=road, extra=extra, include_early=include_early,
                       view=view, videos=videos, figures=not no_figures)  # fmt: skip
