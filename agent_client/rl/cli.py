"""`vacc train`: its options are generated from :class:`~agent_client.rl.config.Config`.

One source of truth: each field's name gives the option (``total_steps`` is
``--total-steps``, with the short names below kept from earlier releases), its
default the default, its docstring the help text; ``Config`` itself checks the values,
and a bad one is reported against its option.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
import re
import shlex
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

import click

from agent_client.actions import ACTION_TYPES
from agent_client.errors import ClientError, InputFileError, OutputFileError
from agent_client.outputs import unwritable_dir, write_cause, write_text
from agent_client.preprocess import ZOOMS
from agent_client.rewards import REWARDS
from agent_client.rl.config import (
    ACTOR_LEVELS,
    DECISIONS,
    EMERGENCIES,
    RECURRENT,
    RESUMABLE_CHANGES,
    SCHEDULES,
    SETTINGS,
    TEACHERS,
    TRUNK_TRAINING,
    Config,
    ConfigError,
    config_from,
    single_stream_only,
)
from agent_client.rl.stop import stop_cause, stop_exit_code, stop_handlers
from protocol.scenarios import SCENARIOS

__all__ = ["train", "config_options"]

OPTION_NAMES = {"total_steps": "steps", "torch_threads": "threads"}  # names kept from earlier releases
REQUIRED = ("reward", "total_steps")
ZERO_IS_NONE = ("episode_seconds", "eval_seconds")  # lengths where 0 means none; --crash-reward -1 stays -1
CHOICES: dict[str, tuple[Any, ...]] = {
    "reward": tuple(sorted(REWARDS)), "scenario": SCENARIOS, "schedule": SCHEDULES, "zoom": ZOOMS, "action": ACTION_TYPES,
    "teacher": TEACHERS, "decision": DECISIONS, "recurrent": RECURRENT,
    "actor_levels": ACTOR_LEVELS, "trunk_training": TRUNK_TRAINING, "emergency": EMERGENCIES,
}  # fmt: skip


@lru_cache(maxsize=1)
def field_docs() -> dict[str, str]:
    """Each :class:`Config` field's docstring (the string literal after it in its section's
    class), whitespace folded."""
    docs = {}
    for kind in SETTINGS.values():
        body = ast.parse(inspect.getsource(kind)).body[0].body  # type: ignore[attr-defined]
        for node, after in zip(body, body[1:], strict=False):
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str):
                    docs[node.target.id] = re.sub(r"\s+", " ", after.value.value).strip()
    return docs


MAX_LISTED_CHOICES = 8  # more choices than this show as NAME in --help


def option_name(field: str) -> str:
    return "--" + OPTION_NAMES.get(field, field).replace("_", "-")


def _option(f: dataclasses.Field[Any]) -> Callable[[Any], Any]:
    """The click option of one Config field."""
    name, default, kind = f.name, getattr(Config(), f.name), str(f.type)  # every field has a default
    common: dict[str, Any] = {"help": field_docs().get(name, ""), "show_default": name not in REQUIRED}
    if name in REQUIRED:
        common.update(required=True, show_default=False)
    else:
        common["default"] = default
    if name in CHOICES:
        choices = [str(c) for c in CHOICES[name]]
        if not common.get("required"):
            common["default"] = str(default)
        if len(choices) > MAX_LISTED_CHOICES:  # a long list drowns the help; a wrong name still gets them all
            common["metavar"] = "NAME"
        return click.option(option_name(name), name, type=click.Choice(choices), **common)
    if kind == "bool":
        flag = OPTION_NAMES.get(name, name).replace("_", "-")
        return click.option(f"--{flag}/--no-{flag}", name, **common)
    if kind.startswith("tuple"):
        common["default"] = ",".join(map(str, default))
        return click.option(option_name(name), name, metavar="A,B,...", **common)
    if kind.endswith("| None"):
        base = {"float": float, "int": int}.get(kind.split()[0], click.Path(dir_okay=False, exists=True))
        return click.option(option_name(name), name, type=base, **common)
    return click.option(option_name(name), name, type={"int": int, "float": float, "str": str}[kind], **common)


def config_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """Decorate ``command`` with one option per :class:`Config` field, in field order."""
    for f in reversed(dataclasses.fields(Config)):
        command = _option(f)(command)
    return command


def make_config(values: dict[str, Any]) -> Config:
    """A :class:`Config` from the option values; a bad one fails against its option.

    Raises:
        click.BadParameter: naming the option.
    """
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(Config):
        v = values[f.name]
        if f.name in CHOICES:
            v = type(getattr(Config(), f.name))(v)  # "2" -> 2 for --zoom
        elif str(f.type).startswith("tuple"):
            v = tuple(t.strip() for t in v.split(",") if t.strip())
            number = float if "float" in str(f.type) else int if "int" in str(f.type) else None
            if number is not None:
                try:
                    v = tuple(number(t) for t in v)
                except ValueError:
                    kind = "numbers" if number is float else "whole numbers"
                    raise click.BadParameter(f"{values[f.name]!r} is not a comma-separated list of {kind}", param_hint=option_name(f.name)) from None
        elif f.name in ZERO_IS_NONE and v is not None and v <= 0:
            v = None  # 0: the whole trajectory
        kw[f.name] = v
    for name in ("eval_trajectories", "train_trajectories"):
        if not kw[name]:
            raise click.BadParameter("give at least one trajectory", param_hint=option_name(name))
    try:
        return Config(**kw)
    except ConfigError as exc:
        raise click.BadParameter(str(exc), param_hint=option_name(exc.field)) from None


CONFIG_GIVEN = "vacc.train.config"  # ctx.meta key: --config was given
RESUME_KEEPS = ("use_ray", "ray_address", "actor_cpus", "max_restarts")  # options not in config.json

# The files a training run writes in its folder, and what --overwrite removes (with their
# leftover .tmp files); nothing else, and of subfolders only evals/ (--keep-evals).
RUN_FILES = ("config.json", "summary.json", "scalars.csv", "latest.pt", "best.pt", "replay.npz", "replay-*.npz", "events.out.tfevents.*", "evals/*.pt")


def run_files(run: Path) -> list[Path]:
    """The files of a previous run in ``run`` (:data:`RUN_FILES`)."""
    found = {p for pattern in RUN_FILES for p in [*run.glob(pattern), *run.glob(pattern + ".tmp")] if p.is_file()}
    return sorted(found)


def _resume_command(ctx: click.Context, run: Path) -> str:
    """The command that resumes ``run``: its config.json, and the options above that were given."""
    words = ["vacc", "train", "--config", str(run / "config.json"), "--out", str(run), "--resume"]
    for p in ctx.command.params:
        if p.name in RESUME_KEEPS and ctx.get_parameter_source(p.name) is click.ParameterSource.COMMANDLINE:
            value = ctx.params[p.name]
            words += [p.opts[0]] if isinstance(value, bool) else [p.opts[0], str(value)]
    return shlex.join(words)


def _is_checkpoint(path: str | Path) -> bool:
    """Whether ``path`` starts as ``torch.save``'s zip archive does."""
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PK\x03\x04"
    except OSError:
        return False  # the reading below says what is wrong


def _config_defaults(ctx: click.Context, path: str | Path, *, refuse: type[click.ClickException] = click.BadParameter) -> None:
    """A run's config.json becomes the defaults of every Config option.

    Raises:
        click.ClickException: (``refuse``) the file is missing, not JSON or out of range;
            one line naming it. Nothing is written.
    """
    try:
        saved = json.loads(Path(path).read_text(encoding="utf-8"))
        if not isinstance(saved, dict):
            raise ValueError("not a JSON object")
        cfg = config_from(saved, path)
    except FileNotFoundError:
        raise refuse(f"{path}: not found; give the run's settings with --config FILE") from None
    except (OSError, ValueError, InputFileError) as exc:
        detail = str(exc).splitlines()[0] if str(exc).strip() else type(exc).__name__
        kw = {"param_hint": "--config"} if refuse is click.BadParameter else {}
        raise refuse(f"{path}: not a readable config.json ({detail})", **kw) from None
    defaults = {}
    for f in dataclasses.fields(Config):
        v = getattr(cfg, f.name)
        defaults[f.name] = ",".join(map(str, v)) if isinstance(v, tuple) else (str(v) if f.name in CHOICES else v)
    ctx.default_map = {**(ctx.default_map or {}), **defaults}


def _load_config(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """--config FILE: a run's config.json gives the defaults; options given override them."""
    if value is None:
        return None
    if _is_checkpoint(value):
        raise click.BadParameter(f"{value} is a checkpoint, not a config.json: write its settings with `vacc checkpoint config {value} --out config.json`",
                                 param_hint="--config")  # fmt: skip
    _config_defaults(ctx, value)
    ctx.meta[CONFIG_GIVEN] = True
    return value


def _resume_defaults(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
    """--out DIR --resume: DIR/config.json gives the defaults (unless --config is given),
    so that a resume needs no other option. Runs once both are known (both are eager)."""
    other = "resume" if param.name == "out" else "out"
    out, resume = (value, ctx.params.get(other)) if param.name == "out" else (ctx.params.get(other), value)
    if out is not None and resume and not ctx.meta.get(CONFIG_GIVEN) and other in ctx.params:
        config = Path(out) / "config.json"
        if not config.exists() and not (Path(out) / "latest.pt").exists():
            raise click.ClickException(f"--resume: {Path(out)} holds no run (no latest.pt)")
        _config_defaults(ctx, config, refuse=click.ClickException)
    return value


def _refuse_resume_changes(ctx: click.Context, cfg: Config, run: Path) -> None:
    """A resume may change only :data:`RESUMABLE_CHANGES`; an option given on the command
    line that differs from the run's settings (the defaults --out's or --config's
    config.json gave) would break the bit-exact resume.

    Raises:
        click.ClickException: one line naming the first such option.
    """
    if not ctx.default_map:
        return
    saved = make_config({f.name: ctx.default_map[f.name] for f in dataclasses.fields(Config)})
    for f in dataclasses.fields(Config):
        if f.name in RESUMABLE_CHANGES or ctx.get_parameter_source(f.name) is not click.ParameterSource.COMMANDLINE:
            continue
        if getattr(cfg, f.name) != getattr(saved, f.name):
            changeable = ", ".join(option_name(n) for n in RESUMABLE_CHANGES)
            raise click.ClickException(
                f"--resume: {option_name(f.name)} {ctx.params[f.name]} differs from the run's {ctx.default_map[f.name]}; "
                f"a resumed run keeps its settings so that it continues bit for bit (only {changeable} may change)"
            )


@click.command("train")
@click.option("--config", "config_file", default=None, is_eager=True, expose_value=False, callback=_load_config, type=click.Path(dir_okay=False, exists=True), help="A run's config.json: its settings as defaults.")
@click.option("--out", "out", required=True, is_eager=True, callback=_resume_defaults, type=click.Path(file_okay=False), help="Run folder, e.g. runs/ice-gap.")
@click.option("--resume", is_flag=True, is_eager=True, callback=_resume_defaults, help="Continue --out from latest.pt with its config.json's settings.")
@click.option("--overwrite", is_flag=True, help="First remove a previous run's files in --out.")
@click.option("--quiet", is_flag=True, help="No progress line.")
@click.option("--ray", "use_ray", is_flag=True, help="Servers and actors as Ray actors (vacc[ray]).")
@click.option("--ray-address", default=None, help="With --ray: 'auto' or HOST:PORT (default: local).")
@click.option("--actor-cpus", default=1.0, show_default=True, type=click.FloatRange(min=0.0, min_open=True), help="With --ray: CPUs per actor and its server.")
@click.option("--max-restarts", default=3, show_default=True, type=click.IntRange(min=0), help="Restarts of a dead actor (servers > 1 or --ray).")
@config_options
def train(out: str, resume: bool, overwrite: bool, quiet: bool, use_ray: bool, ray_address: str | None, actor_cpus: float,
          max_restarts: int, **values: Any) -> None:  # fmt: skip
    """Train a policy from camera frames (Double DQN; DrQ-v2 with --action continuous)
    against spawned simulator servers.

    Writes config.json, scalars.csv, latest.pt and best.pt (the best evaluation) in
    OUT. Why the defaults: docs/training.md, "Options".
    """
    cfg = make_config(values)
    if ray_address is not None and not use_ray:
        raise click.UsageError("--ray-address needs --ray")
    distributed = use_ray or cfg.servers > 1
    if distributed and (needs := single_stream_only(cfg)) is not None:
        raise click.BadParameter(needs[1], param_hint=option_name(needs[0]))
    run = Path(out)
    if resume and overwrite:
        raise click.UsageError("--resume continues the run in --out, --overwrite removes it: give one of them")
    if resume and not (run / "latest.pt").exists():
        raise click.ClickException(f"--resume: {run / 'latest.pt'} does not exist")
    if resume:
        _refuse_resume_changes(click.get_current_context(), cfg, run)
    if not resume and not overwrite and (run / "config.json").exists():
        raise click.UsageError(f"--out {run} already holds a run: add --resume to continue it, or --overwrite to start afresh")
    if (why := unwritable_dir(run)) is not None:
        raise click.ClickException(f"--out {run}: cannot be written: {why}")
    old_files = run_files(run) if overwrite else []
    if cfg.init_from is not None and Path(cfg.init_from).resolve() in {p.resolve() for p in old_files}:
        raise click.UsageError(f"--init-from {cfg.init_from} is a file of the run in --out {run}, which --overwrite removes: copy it elsewhere first")
    # The first Ctrl-C or `kill` stops with a checkpoint; a second aborts through SystemExit,
    # whose finally blocks reap the spawned servers and actors.
    with stop_handlers("vacc train", ""):
        try:
            if use_ray:
                from agent_client.rl.distributed import import_ray

                import_ray()  # before any work: say how to install it
            for path in old_files:  # else TensorBoard mixes both runs' events, and an old best.pt passes for ours
                try:
                    path.unlink(missing_ok=True)
                except OSError as exc:
                    raise click.ClickException(f"--overwrite: cannot remove {path} ({exc.strerror or exc})") from None
            if old_files:
                click.echo(f"vacc train: --overwrite removed {len(old_files)} files of the previous run in {run}", err=True)
            if distributed:
                from agent_client.rl.distributed import train_distributed

                summary = train_distributed(cfg, out, resume=resume, progress=not quiet, use_ray=use_ray,
                                            ray_address=ray_address, actor_cpus=actor_cpus, max_restarts=max_restarts)  # fmt: skip
            else:
                from agent_client.rl.train import train as run_training

                summary = run_training(cfg, out, resume=resume, progress=not quiet)
        except ClientError as exc:
            raise click.ClickException(str(exc)) from None
        except OSError as exc:  # a run folder's file (scalars.csv, events): one line naming it
            raise click.ClickException(f"{exc.filename or run}: could not be written: {write_cause(exc)}") from None
        cause, code = stop_cause(), stop_exit_code()

    click.echo(f"trained {summary['steps']} steps, {summary['episodes']} episodes in {summary['wall_s']:.0f} s -> {out}")
    if summary.get("stopped"):
        click.echo(f"stopped by {cause} at step {summary['steps']}; continue with: {_resume_command(click.get_current_context(), run)}")
    if distributed:
        click.echo(
            f"  {summary['servers']} actors ({summary['backend']}): transitions {summary['transitions_by_actor']}, "
            f"restarts {summary['restarts_by_actor']}, {summary['env_steps_per_s']:.0f} env steps/s"
        )
    for r in summary["last_eval"]:
        click.echo(f"  {r['trajectory']}: gap RMSE {r['gap_rmse_m']:.3f} m, collision {'yes' if r['collision'] else 'no'}")
    try:
        write_text(run / "summary.json", json.dumps(summary, indent=2, default=float) + "\n")
    except OutputFileError as exc:
        raise click.ClickException(str(exc)) from None
    if summary.get("stopped"):
        raise SystemExit(code)  # as the signal ends a program, but with the run saved
