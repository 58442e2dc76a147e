"""``vacc checkpoint``: look into a checkpoint, write its settings, and the model surgery
that makes the shipped models (average, decide, narrow, export).

The work is done by :mod:`agent_client.rl.checkpoint`; this module only reads the
options and prints one line per result. Every error is one line on stderr with exit
status 2, as the surgery tool before it (``python -m agent_client.rl.checkpoint``) had.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from agent_client.errors import ClientError, InputFileError
from agent_client.rl.checkpoint import (
    average_policies,
    checkpoint_config,
    export_policy,
    file_sha256,
    narrow_policy,
    read_checkpoint,
    upgrade,
    with_decision,
)
from agent_client.rl.config import DECISIONS, Config, config_dict

__all__ = ["checkpoint", "checkpoint_summary", "decision_text", "config_json"]


class CheckpointCommandError(click.ClickException):
    """A checkpoint command failed: one line, exit status 2."""

    exit_code = 2


def _one_line_errors(run: Callable[[], None]) -> None:
    """Run ``run``; a :class:`ClientError` (a bad file, a bad setting) becomes one line."""
    try:
        run()
    except ClientError as exc:
        raise CheckpointCommandError(str(exc)) from None


def decision_text(cfg: Config) -> str:
    """The decision rule and its settings, as ``decide`` reports them."""
    return (f"decision {cfg.decision}, temperature {cfg.decision_temperature:g}, brake share {cfg.decision_brake_share:g} "
            f"(confirmed in {cfg.decision_brake_confirm}), the argmax's full brake confirmed in {cfg.decision_full_brake_confirm}, "
            f"deadband {cfg.decision_deadband:g}, smoothing {cfg.decision_smoothing:g}")


def config_json(cfg: Config) -> str:
    """``cfg`` as a run's ``config.json`` holds it (the trainer writes the same text)."""
    return json.dumps(config_dict(cfg), indent=2) + "\n"


def _extra_paths(extra: dict[str, Any]) -> list[str]:
    """The paths an older checkpoint's ``extra`` names as its sources (informative only)."""
    found = [str(extra[k]) for k in ("from", "narrowed_from") if k in extra]
    return found + [f"{s.get('path')} (share {s.get('share', 0):.3g})" for s in extra.get("average_of", [])]


def checkpoint_summary(path: str | Path) -> dict[str, Any]:
    """What ``vacc checkpoint info`` shows of the checkpoint at ``path``.

    Returns:
        path, size [bytes], sha256 (of the file, as ``sha256sum``), digest (of its contents),
        kind, version, step, averaged_steps (each source's, for a mean of policies),
        scenario, action, reward, decision, widths, lineage (None:
        written before checkpoints recorded it), recorded_sources (paths an older file's
        ``extra`` names) and config (every setting).

    Raises:
        InputFileError: not a readable checkpoint.
    """
    ckpt = read_checkpoint(path)
    cfg = checkpoint_config(ckpt, path)
    extra = ckpt.get("extra", {})
    step = ckpt.get("state", {}).get("global_step", extra.get("step"))
    return {
        "path": str(path), "size": Path(path).stat().st_size, "sha256": file_sha256(path), "digest": ckpt.get("sha256"),
        "kind": ckpt.get("kind"), "version": ckpt["version"], "step": None if step is None else int(step),
        "scenario": cfg.scenario, "action": cfg.action, "reward": cfg.reward, "decision": decision_text(cfg),
        "widths": {"conv_channels": list(cfg.conv_channels), "hidden": cfg.hidden},
        "averaged_steps": [s.get("step") for s in extra.get("average_of", [])],
        "lineage": ckpt.get("lineage"), "recorded_sources": _extra_paths(extra), "config": config_dict(cfg),
    }  # fmt: skip


def _step_text(summary: dict[str, Any]) -> str:
    """The step, and for a mean of policies that its step is its first source's, not all it learned."""
    if summary["step"] is None:
        return "not recorded"
    steps = [s for s in summary["averaged_steps"] if s is not None]
    if len(summary["averaged_steps"]) < 2:
        return str(summary["step"])
    span = f", steps {min(steps)}-{max(steps)}" if steps else ""
    return f"{summary['step']} (its first source's: a mean of {len(summary['averaged_steps'])} policies{span})"


def _lineage_lines(summary: dict[str, Any]) -> list[str]:
    lineage = summary["lineage"]
    if lineage is None:
        lines = ["  unknown: written before checkpoints recorded their lineage"]
        lines += [f"  recorded source (a path, informative only): {p}" for p in summary["recorded_sources"]]
        return lines
    made = lineage.get("recipe")
    recipe = f"{made['name']}, stage {made['stage']} (digest {made['digest'][:12]}, seed {made['seed']})" if isinstance(made, dict) else "none"
    lines = [f"  stage    {lineage['stage']}", f"  recipe   {recipe}"]
    if not lineage["parents"]:
        lines.append("  parents  none (trained from scratch)")
    for parent in lineage["parents"]:
        role = f" as {parent['role']}" if parent.get("role") else ""
        of = " (its weights)" if parent.get("digest_of") == "weights" else ""
        lines.append(f"  parent   {parent['sha256']}{of}{role} (was {parent['path']})")
    return lines


def _info_lines(summary: dict[str, Any]) -> list[str]:
    widths = summary["widths"]
    lines = [
        f"{summary['path']}",
        f"  sha256   {summary['sha256']}",
        f"  size     {summary['size']:,} bytes",
        f"  kind     {summary['kind']} (version {summary['version']}, contents digest {summary['digest'] or 'none'})",
        f"  step     {_step_text(summary)}",
        f"  scenario {summary['scenario']}, action {summary['action']}, reward {summary['reward']}",
        f"  network  conv {'/'.join(map(str, widths['conv_channels']))}, hidden {widths['hidden']}",
        f"  {summary['decision']}",
        "lineage",
        *_lineage_lines(summary),
        "config",
    ]
    return lines + [f"  {k} = {json.dumps(v)}" for k, v in summary["config"].items()]


@click.group("checkpoint")
def checkpoint() -> None:
    """Look into a checkpoint, write its settings, or make a new policy from checkpoints.

    Every command that writes a checkpoint refuses an existing file and records the
    SHA-256 of the files it was made from (its lineage; `vacc checkpoint info` shows it).
    """


@checkpoint.command("info")
@click.argument("path", metavar="FILE.pt", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def info(path: str, as_json: bool) -> None:
    """Print a checkpoint's SHA-256, size, lineage and settings."""
    def run() -> None:
        summary = checkpoint_summary(path)
        click.echo(json.dumps(summary, indent=2) if as_json else "\n".join(_info_lines(summary)))

    _one_line_errors(run)


def _path_notes(cfg: Config, lineage: dict[str, Any] | None) -> list[str]:
    """Warnings for the file settings of ``cfg`` that do not name what the run read."""
    recorded = {p.get("role"): p["sha256"] for p in (lineage or {}).get("parents", [])}
    notes = []
    for role in ("init_from", "teacher_policy"):
        value = getattr(cfg, role)
        if value is None:
            continue
        if not Path(value).is_file():
            notes.append(f"note: {role} {value} does not exist here; give --{role.replace('_', '-')} FILE to vacc train")
        elif role in recorded and file_sha256(value) != recorded[role]:
            notes.append(f"note: {role} {value} is not the file the run read (its SHA-256 was {recorded[role]})")
    return notes


@checkpoint.command("config")
@click.argument("path", metavar="FILE.pt", type=click.Path(dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="A new config.json ('-': print it).")
def config(path: str, out: str) -> None:
    """Write a checkpoint's settings as a config.json for `vacc train --config`.

    The settings are written as recorded; a file setting (init_from, teacher_policy) that
    does not name here what the run read gets a note on stderr.
    """
    def run() -> None:
        if out != "-" and Path(out).exists():
            raise InputFileError(f"{out}: exists; give a new file for the config")
        ckpt = read_checkpoint(path)
        cfg = checkpoint_config(ckpt, path)
        if out == "-":
            click.echo(config_json(cfg), nl=False)
        else:
            Path(out).write_text(config_json(cfg))
            click.echo(f"{out}: the settings of {path}; train with: vacc train --config {out} --out DIR")
        for note in _path_notes(cfg, ckpt.get("lineage")):
            click.echo(note, err=True)

    _one_line_errors(run)


@checkpoint.command("decide")
@click.argument("src", metavar="SRC.pt")
@click.argument("dst", metavar="DST.pt")
@click.option("--decision", required=True, type=click.Choice(DECISIONS))
@click.option("--temperature", type=float, default=None, help="The mean decision's softmax temperature (default: the checkpoint's).")
@click.option("--brake-share", type=float, default=None,
              help="The mean decision's full-brake share that brakes at once (Config.decision_brake_share; default: the checkpoint's).")
@click.option("--brake-confirm", type=int, default=None, metavar="N",
              help="Decisions in a row at the brake share before it brakes fully (Config.decision_brake_confirm; default: the checkpoint's).")
@click.option("--full-brake-confirm", type=int, default=None, metavar="N",
              help="Decisions in a row with the full brake the argmax before it acts at once; until then the ramp "
                   "heads for it (Config.decision_full_brake_confirm; default: the checkpoint's).")
@click.option("--deadband", type=float, default=None,
              help="Force within which the mean decision keeps the held force (Config.decision_deadband; default: the checkpoint's).")
@click.option("--smoothing", type=float, default=None,
              help="The share of the way to the mean's target asked each step (Config.decision_smoothing; default: the checkpoint's).")
def decide(src: str, dst: str, decision: str, temperature: float | None, brake_share: float | None, brake_confirm: int | None,
           full_brake_confirm: int | None, deadband: float | None, smoothing: float | None) -> None:  # fmt: skip
    """Copy the policy SRC to the new file DST with another decision rule (weights unchanged)."""
    def run() -> None:
        cfg = with_decision(src, dst, decision, temperature, brake_share, deadband, smoothing, brake_confirm, full_brake_confirm)
        click.echo(f"{dst}: {decision_text(cfg)}")

    _one_line_errors(run)


@checkpoint.command("export")
@click.argument("src", metavar="SRC.pt")
@click.argument("dst", metavar="DST.pt")
def export(src: str, dst: str) -> None:
    """Write a checkpoint's policy alone to the new file DST (< 5 MB, as best.pt; weights unchanged).

    SRC is a training run's latest.pt (its target network, optimizer, random states and
    replay names are left out) or a policy.
    """
    _one_line_errors(lambda: click.echo(f"{dst}: the policy at step {export_policy(src, dst)}"))


def _three_widths(ctx: click.Context, param: click.Parameter, text: str) -> tuple[int, int, int]:
    """``narrow --conv-channels``: three whole numbers, comma-separated."""
    parts = text.split(",")
    if len(parts) != 3 or not all(p.strip().isdigit() for p in parts):
        raise click.BadParameter(f"want three whole numbers such as 8,16,32, got {text!r}", ctx, param)
    a, b, c = (int(p) for p in parts)
    return a, b, c


@checkpoint.command("narrow")
@click.argument("src", metavar="SRC.pt")
@click.argument("dst", metavar="DST.pt")
@click.option("--conv-channels", required=True, callback=_three_widths, metavar="C1,C2,C3",
              help="The three convolutions' channels, each at most SRC's.")
@click.option("--hidden", required=True, type=int, help="The hidden layer's units, at most SRC's.")
def narrow(src: str, dst: str, conv_channels: tuple[int, int, int], hidden: int) -> None:
    """Write SRC cut down to fewer channels and hidden units as the new policy DST.

    A start for distilling it (vacc train --teacher policy --init-from DST); it must be
    trained before it drives.
    """
    def run() -> None:
        cfg = narrow_policy(src, dst, conv_channels, hidden)
        click.echo(f"{dst}: conv {'/'.join(map(str, cfg.conv_channels))}, hidden {cfg.hidden}; train it before driving it")

    _one_line_errors(run)


def _weights(ctx: click.Context, param: click.Parameter, text: str | None) -> list[float] | None:
    """``average --weights``: numbers, comma-separated (their checks are the average's)."""
    if text is None:
        return None
    try:
        return [float(w) for w in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"want numbers such as 3,1,1, got {text!r}", ctx, param) from None


@checkpoint.command("average")
@click.argument("srcs", nargs=-1, required=True, metavar="SRC.pt...")
@click.option("--out", required=True, metavar="DST.pt", help="A new file.")
@click.option("--weights", default=None, callback=_weights, metavar="W1,W2,...",
              help="One positive weight per policy, normalised to sum to 1 (default: equal).")
def average(srcs: tuple[str, ...], out: str, weights: list[float] | None) -> None:
    """Write the mean of the weights of two or more policies fine-tuned from one start (a model soup).

    The policies must see and act alike (scenario, action, zoom, frame stack, decision rule).
    """
    def run() -> None:
        average_policies(list(srcs), out, weights)
        click.echo(f"{out}: the {'weighted ' if weights else ''}mean of {len(srcs)} policies")

    _one_line_errors(run)


@checkpoint.command("upgrade")
@click.argument("paths", nargs=-1, required=True, metavar="FILE.pt...")
def upgrade_cmd(paths: tuple[str, ...]) -> None:
    """Rewrite version-1 checkpoints in this layout, in place (weights unchanged)."""
    def run() -> None:
        for name in paths:
            click.echo(f"{name}: {'upgraded to version 2' if upgrade(name) else 'already version 2'}")

    _one_line_errors(run)
