"""``vacc models``: the shipped models, as ``models/index.json`` lists them, each checked
against its file.

The index holds, per model, what its file says (scenario, action type, decision rule,
size, SHA-256), where its recipe is (``recipes/<model>.toml``), the gate figures
measured for that file, with where they come from, and the verdict of a ``vacc gates``
run on it (``--record-gates``). :func:`write_index` re-makes the
file fields from ``models/*.pt`` and keeps each model's figures while its SHA-256 is the
one they were measured on.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from agent_client.errors import ClientError
from agent_client.rl.checkpoint import checkpoint_config, file_sha256, read_checkpoint
from vacc.paths import MODELS_DEFAULT, models_dir

__all__ = ["INDEX_NAME", "INDEX_FORMAT", "models", "model_entry", "write_index", "read_index", "check_models", "recipe_path", "record_gates"]

INDEX_NAME = "index.json"
INDEX_FORMAT = "vacc-models"
INDEX_VERSION = 1
RECIPES = "recipes"  # beside models/: recipes/<model>.toml


def recipe_path(name: str) -> str:
    """Where the recipe of the model ``name`` is, relative to the checkout."""
    return f"{RECIPES}/{name}.toml"


def model_entry(path: Path, gates: dict[str, Any] | None, verdict: dict[str, Any] | None = None) -> dict[str, Any]:
    """The index entry of the checkpoint at ``path``, with the figures ``gates`` (None: unmeasured)
    and the ``verdict`` of a `vacc gates` run on this file (None: not run).

    Raises:
        InputFileError: not a readable checkpoint.
    """
    ckpt = read_checkpoint(path)
    cfg = checkpoint_config(ckpt, path)
    return {
        "name": path.stem, "file": path.name, "scenario": cfg.scenario, "action": cfg.action, "reward": cfg.reward,
        "decision": cfg.decision, "size": path.stat().st_size, "sha256": file_sha256(path), "recipe": recipe_path(path.stem),
        "gates": gates, "verdict": verdict,
    }  # fmt: skip


def read_index(folder: Path) -> dict[str, Any]:
    """``folder/index.json``, checked for its format.

    Raises:
        click.ClickException: missing, not JSON, or not a models index.
    """
    path = folder / INDEX_NAME
    try:
        index = json.loads(path.read_text())
    except FileNotFoundError:
        raise click.ClickException(f"{path}: no models index; write one with `vacc models --write-index`") from None
    except (OSError, ValueError) as exc:
        raise click.ClickException(f"{path}: not a readable models index ({exc})") from None
    if not isinstance(index, dict) or index.get("format") != INDEX_FORMAT or not isinstance(index.get("models"), list):
        raise click.ClickException(f"{path}: not a models index (no format tag {INDEX_FORMAT!r} and models list)")
    return index


def write_index(folder: Path, out: Path | None = None) -> list[str]:
    """Write the index of ``folder/*.pt`` to ``out`` (default ``folder/index.json``).

    A model keeps the figures of the index already there while its SHA-256 is the one
    they were measured on; a changed file's figures are dropped (set to null).

    Returns:
        One line per model whose figures were dropped or are missing.

    Raises:
        InputFileError: a model file is not a readable checkpoint.
    """
    old = {m["name"]: m for m in read_index(folder)["models"]} if (folder / INDEX_NAME).is_file() else {}
    entries, notes = [], []
    for path in sorted(folder.glob("*.pt")):
        before = old.get(path.stem, {})
        entry = model_entry(path, before.get("gates"), before.get("verdict"))
        if before and before.get("sha256") != entry["sha256"] and (entry["gates"] is not None or entry["verdict"] is not None):
            entry["gates"] = entry["verdict"] = None
            notes.append(f"{path.stem}: its file changed; its gate figures and verdict were dropped (measure them again)")
        elif entry["gates"] is None:
            notes.append(f"{path.stem}: no gate figures")
        entries.append(entry)
    index = {"format": INDEX_FORMAT, "version": INDEX_VERSION, "written_by": "vacc models --write-index", "models": entries}
    (out or folder / INDEX_NAME).write_text(json.dumps(index, indent=2, ensure_ascii=False) + "\n")
    return notes


def record_gates(folder: Path, report_path: Path) -> str:
    """Put the verdict of a `vacc gates` report (its ``gates.json``) into ``folder``'s index,
    on the model whose file it checked (matched by SHA-256); return a line saying so.

    Raises:
        click.ClickException: the report does not read, is a --quick or --skip one, or checked a file
            that is no indexed model.
    """
    try:
        report = json.loads(report_path.read_text())
        sha, checks = report["sha256"], report["checks"]
        failed = [f"{c['gate']}: {c['what']}" for c in checks if not c["passed"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise click.ClickException(f"{report_path}: not a gates report of `vacc gates` ({exc})") from None
    if report.get("quick"):
        raise click.ClickException(f"{report_path}: a --quick report checks that the gates run, not the model: run `vacc gates` without --quick")
    if report.get("skipped"):
        raise click.ClickException(f"{report_path}: it skipped {', '.join(report['skipped'])} (--skip), so it is no verdict on the model: run `vacc gates` without --skip")
    if not checks:
        raise click.ClickException(f"{report_path}: the report holds no check (its recipe declares no gates)")
    index = read_index(folder)
    entries = [m for m in index["models"] if m.get("sha256") == sha]
    if not entries:
        raise click.ClickException(f"{report_path}: it checked a file of SHA-256 {sha[:12]}, which is no model of {folder / INDEX_NAME}")
    if len(entries) > 1:
        raise click.ClickException(f"{report_path}: {', '.join(m['name'] for m in entries)} are the same file (SHA-256 {sha[:12]}): which one it checked is not known")
    entry = entries[0]
    if report.get("recipe") != entry["name"]:
        raise click.ClickException(f"{report_path}: it checked {entry['name']}'s file against the gates of {report.get('recipe')}: record a report of {entry['name']}'s own recipe")
    entry["verdict"] = {
        "passed": not failed, "checks_passed": len(checks) - len(failed), "checks": len(checks), "failed": failed,
        "recipe": report.get("recipe"), "recipe_digest": report.get("recipe_digest"), "measured_by": "vacc gates",
    }  # fmt: skip
    (folder / INDEX_NAME).write_text(json.dumps(index, indent=2, ensure_ascii=False) + "\n")
    return f"{entry['name']}: {'PASS' if not failed else 'FAIL'} {len(checks) - len(failed)}/{len(checks)} gate checks recorded from {report_path}"


def _verdict_text(verdict: dict[str, Any] | None) -> str:
    if not verdict:
        return "not run"
    return f"{'PASS' if verdict['passed'] else 'FAIL'} {verdict['checks_passed']}/{verdict['checks']}"


def check_models(folder: Path) -> list[dict[str, Any]]:
    """The index's models, each with ``check``: "ok", "MISMATCH" (the file's SHA-256 is not the
    index's), "missing"; and the ``*.pt`` files the index leaves out ("not indexed")."""
    index = read_index(folder)
    rows = []
    for entry in index["models"]:
        path = folder / entry["file"]
        if not path.is_file():
            rows.append({**entry, "check": "missing"})
            continue
        actual = file_sha256(path)
        rows.append({**entry, "check": "ok" if actual == entry["sha256"] else "MISMATCH", "file_sha256": actual})
    listed = {entry["file"] for entry in index["models"]}
    rows += [{"name": p.stem, "file": p.name, "check": "not indexed"} for p in sorted(folder.glob("*.pt")) if p.name not in listed]
    return rows


def _gap_text(gates: dict[str, Any] | None) -> str:
    gap = (gates or {}).get("gap_rmse_m")
    if not gap:
        return "—"
    each = gap.get("per_trajectory")
    detail = "/".join(f"{v:.2f}" for v in each.values()) if each else ("–".join(f"{v:.2f}" for v in gap["range"]) if gap.get("range") else "")
    return f"{gap['mean']:.3f}" + (f" ({detail})" if detail else "")


def _energy_text(gates: dict[str, Any] | None) -> str:
    energy = (gates or {}).get("energy")
    if not energy:
        return "—"
    return f"{energy['model']:g} {energy['unit']}, ACC {energy['acc']:g} ({energy['model'] / energy['acc'] - 1:+.1%})"


def _recipe_text(recipe: str | None, root: Path) -> str:
    if recipe is None:
        return "—"
    return recipe if (root / recipe).is_file() else f"{recipe} (not written yet)"


def _table(rows: list[dict[str, Any]], root: Path) -> list[str]:
    head = ("model", "scenario", "action", "size", "sha256", "check", "recipe", "vacc gates", "gap RMSE m: mean (per test, or range)", "energy vs ACC")
    cells = [head]
    for r in rows:
        size = f"{r['size'] / 1e6:.2f} MB" if "size" in r else "—"
        cells.append((r["name"], r.get("scenario", "—"), r.get("action", "—"), size, r.get("sha256", "—")[:12], r["check"],
                      _recipe_text(r.get("recipe"), root), _verdict_text(r.get("verdict")), _gap_text(r.get("gates")),
                      _energy_text(r.get("gates"))))  # fmt: skip
    widths = [max(len(str(c[i])) for c in cells) for i in range(len(head))]
    return ["  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in cells]


def _problems(rows: list[dict[str, Any]], folder: Path) -> list[str]:
    lines = []
    for r in rows:
        if r["check"] == "MISMATCH":
            lines.append(f"MISMATCH {folder / r['file']}: its SHA-256 is {r['file_sha256']}, {INDEX_NAME} says {r['sha256']}: "
                         "the file is not the model the index describes")  # fmt: skip
        elif r["check"] != "ok":
            lines.append(f"{r['check'].upper()} {folder / r['file']}")
    return lines


@click.command("models")
@click.option("--models", "folder", default=lambda: str(models_dir()), show_default=MODELS_DEFAULT, type=click.Path(file_okay=False),
              help="The folder of the shipped models and their index.json.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@click.option("--write-index", "rewrite", is_flag=True, help="Re-make index.json from the folder's *.pt (keeping the figures of unchanged files).")
@click.option("--record-gates", "reports", multiple=True, type=click.Path(dir_okay=False), metavar="GATES_JSON",
              help="Record the verdict of a `vacc gates` run (its gates.json) on the model whose file it checked (repeatable).")
def models(folder: str, as_json: bool, rewrite: bool, reports: tuple[str, ...] = ()) -> None:
    """List the shipped models: scenario, action type, size, SHA-256 (checked against the
    file), recipe and gate figures, from the folder's index.json.

    Exits with status 1 when a file's SHA-256 is not the index's, or one is missing or
    not indexed.
    """
    path = Path(folder)
    if rewrite:
        try:
            notes = write_index(path)
        except ClientError as exc:
            raise click.ClickException(str(exc)) from None
        for note in notes:
            click.echo(note, err=True)
        click.echo(f"wrote {path / INDEX_NAME}", err=True)
    for report in reports:
        click.echo(record_gates(path, Path(report)), err=True)
    rows = check_models(path)
    if as_json:
        click.echo(json.dumps(rows, indent=2, ensure_ascii=False))
    else:
        click.echo("\n".join(_table(rows, path.resolve().parent)))
    problems = _problems(rows, path)
    for line in problems:
        click.echo(line, err=True)
    if problems:
        raise SystemExit(1)
