"""``vacc seeds``: a recipe's gate reports over training seeds, as rliable would summarise them.

Each ``gates.json`` is one training seed's model checked against its recipe
(``vacc reproduce MODEL --seed N`` ends with one). Over the seeds this gives:

* the share of seeds whose model passes every gate, and each check's pass share;
* each check's figure as the interquartile mean over seeds with a 95 % percentile
  bootstrap interval (:mod:`vacc.stats`), and the test trajectories' gap RMSE pooled
  with the interval stratified by trajectory (rliable's ``StratifiedBootstrap``);
* the same for the report's measures, which no gate bounds: the mean gap RMSE, the ISO jerk
  share and the energy against the ACC on the tests and on the random leads, and the safety
  suite's closest gap.

``--across-recipes`` reads summaries that ``--json`` wrote, one per recipe, and prints one row
each with the pass share and the key figures: the table of ``docs/results.md``. ``--name``
labels a summary's row (an ablation of one recipe: each variant its own summary).

Reports that skipped a set of runs (``vacc gates --skip``) are summarised only with reports that
skipped the same; their pass share is over the checks they ran, and the table says so.

Agarwal et al. 2021: with 3-10 runs, report the IQM and its interval, not a best seed.
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import click

from vacc.measures import CLOSEST_GAP, ENERGY_RATIO, ISO_JERK_SHARE, MEAN_GAP_RMSE
from vacc.stats import CONFIDENCE, Estimate, bootstrap_ci, iqm

__all__ = ["read_reports", "seed_summary", "summary_table", "recipes_table", "seeds"]

POOLED_TESTS = ("tests", "gap RMSE (m)")  # the per-trajectory checks pooled in one row
RECIPE_COLUMNS = (  # --across-recipes: (header, (where, measure), decimals, in %)
    ("tests: energy / ACC", ("tests", ENERGY_RATIO), 3, False),
    ("tests: ISO jerk %", ("tests", ISO_JERK_SHARE), 1, True),
    ("random: mean gap RMSE", ("random", MEAN_GAP_RMSE), 2, False),
    ("random: energy / ACC", ("random", ENERGY_RATIO), 3, False),
    ("safety: closest gap", ("safety", CLOSEST_GAP), 1, False),
)
LEGACY_DETAIL = re.compile(r" \(min gap [^)]*\)$")  # reports before Check.detail named the closest gap in "what"
# measures reports of 2026-12-05 held that are not measures: the tests' and random leads' closest gap is their start gap
LEGACY_MEASURES = {("tests", CLOSEST_GAP), ("random", CLOSEST_GAP)}
LEGACY_CPU_PATH = "native"  # reports before the gates pinned their kernels (2026-12-06) drove on the CPU's own


def read_reports(paths: Sequence[Path]) -> list[dict[str, Any]]:
    """The gate reports, checked to be of one recipe, full (not --quick) and of distinct models,
    in the order of their paths: the bootstrap draws by position, so the same files in another
    order give the same intervals.

    Raises:
        click.ClickException: one line naming the file and what is wrong.
    """
    reports = []
    for path in sorted(paths, key=str):
        try:
            report = json.loads(path.read_text())
            _ = (report["recipe"], report["recipe_digest"], report["sha256"])
            for c in report["checks"]:
                _ = (c["gate"], c["what"], float(c["figure"]), c["bound"], bool(c["passed"]))
            for m in report.get("measures", []):  # absent from reports before gates measured
                _ = (m["gate"], m["what"], float(m["figure"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise click.ClickException(f"{path}: not a gates report of `vacc gates` ({exc})") from None
        if report.get("quick"):
            raise click.ClickException(f"{path}: a --quick report checks that the gates run, not the model")
        reports.append({**report, "path": str(path)})
    first = reports[0]
    for r in reports[1:]:
        if r.get("skipped", []) != first.get("skipped", []):
            raise click.ClickException(f"{r['path']}: skipped {r.get('skipped', []) or 'nothing'}, but {first['path']} skipped "
                                       f"{first.get('skipped', []) or 'nothing'}: summarise reports of the same checks")  # fmt: skip
    for r in reports[1:]:
        if (r["recipe"], r["recipe_digest"]) != (first["recipe"], first["recipe_digest"]):
            raise click.ClickException(
                f"{r['path']}: recipe {r['recipe']} ({r['recipe_digest'][:12]}), but {first['path']} is of "
                f"{first['recipe']} ({first['recipe_digest'][:12]}): summarise one recipe's seeds at a time"
            )
    seen: dict[str, str] = {}
    for r in reports:
        if r["sha256"] in seen:
            raise click.ClickException(f"{r['path']}: the same checkpoint as {seen[r['sha256']]} (SHA-256 {r['sha256'][:12]}): one report per seed")
        seen[r["sha256"]] = r["path"]
    return reports


def _estimate(tasks: list[list[float]]) -> Estimate | None:
    """IQM and interval over the finite figures (an energy ratio or a comfort figure can be
    NaN or infinite); None when no task has one."""
    finite = [[x for x in t if math.isfinite(x)] for t in tasks]
    finite = [t for t in finite if t]
    return bootstrap_ci(finite, iqm) if finite else None


def _summarised(row: dict[str, Any]) -> dict[str, Any]:
    """The row with its figures' count, IQM and interval (NaN where none is finite)."""
    est = _estimate([row["figures"]])
    nan = float("nan")
    return {**row, "n": len(row["figures"]), "iqm": est.value if est else nan, "low": est.low if est else nan, "high": est.high if est else nan}


def _what(check: dict[str, Any]) -> str:
    """The check's name; a report before the detail field carried the closest gap in it."""
    return LEGACY_DETAIL.sub("", check["what"])


def seed_summary(reports: Sequence[dict[str, Any]], name: str | None = None) -> dict[str, Any]:
    """Pass shares and IQM intervals over the reports (one per seed).

    A check missing from some report (a recipe's gates changed) is summarised over the
    reports that have it; ``n`` says how many. ``name`` labels the summary (default: the recipe's).
    """
    rows: dict[tuple[str, str], dict[str, Any]] = {}
    for r in reports:
        for c in r["checks"]:
            what = _what(c)
            row = rows.setdefault((c["gate"], what), {"gate": c["gate"], "what": what, "bound": c["bound"], "figures": [], "passed": 0})
            row["figures"].append(float(c["figure"]))
            row["passed"] += bool(c["passed"])
    out = [{**_summarised(row), "non_finite": sum(not math.isfinite(x) for x in row["figures"])} for row in rows.values()]
    per_test = [row["figures"] for (gate, what), row in rows.items() if gate == POOLED_TESTS[0] and what.endswith(POOLED_TESTS[1]) and what.startswith("test-")]
    pooled = None
    if per_test and (est := _estimate(per_test)) is not None:
        pooled = {"what": "test-1..4 gap RMSE (m), stratified by trajectory", "iqm": est.value, "low": est.low, "high": est.high, "n": est.n}
    passed_all = sum(all(c["passed"] for c in r["checks"]) for r in reports)
    kernels = Counter(r.get("cpu_path", LEGACY_CPU_PATH) for r in reports)
    return {"recipe": reports[0]["recipe"], "name": name or reports[0]["recipe"], "skipped": reports[0].get("skipped", []), "seeds": len(reports), "passed_every_gate": passed_all, "checks": out, "pooled_tests": pooled,
            "measures": _measure_rows(reports), "cpu_paths": dict(sorted(kernels.items()))}  # fmt: skip


def _measure_rows(reports: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each measure's IQM and interval over the reports that hold it (a report written before
    gates measured is left out; ``n`` says how many)."""
    rows: dict[tuple[str, str], dict[str, Any]] = {}
    for r in reports:
        for m in (m for m in r.get("measures", []) if (m["gate"], m["what"]) not in LEGACY_MEASURES):
            rows.setdefault((m["gate"], m["what"]), {"gate": m["gate"], "what": m["what"], "figures": []})["figures"].append(float(m["figure"]))
    return [_summarised(row) for row in rows.values()]


def _interval(row: dict[str, Any] | None, decimals: int, percent: bool = False) -> str:
    """``IQM [low, high]`` of a summarised row; ``–`` where there is none."""
    if row is None or not math.isfinite(row["iqm"]):
        return "–"
    k = 100.0 if percent else 1.0
    return f"{k * row['iqm']:.{decimals}f} [{k * row['low']:.{decimals}f}, {k * row['high']:.{decimals}f}]"


def summary_table(s: dict[str, Any]) -> str:
    """The summary as Markdown: the pass share, then one row per check."""
    ci = f"{CONFIDENCE:.0%}"
    skipped = "".join(f"; {p} not checked" for p in s.get("skipped", []))
    label = s["recipe"] if s.get("name", s["recipe"]) == s["recipe"] else f"{s['name']} ({s['recipe']})"
    lines = [f"{label}: {s['passed_every_gate']} of {s['seeds']} seeds pass every gate{' checked' if skipped else ''}{skipped}", ""]
    paths = s.get("cpu_paths", {})
    if len(paths) > 1:  # a last-bit difference can move a decision: say so beside the figures
        mixed = ", ".join(f"{n} on {p}" for p, n in paths.items())
        lines[1:1] = [f"gated on mixed CPU kernels ({mixed}): a figure can differ in its last digits from one path to another", ""]
    lines += [
        f"| gate | check | seeds passed | IQM over seeds [{ci} CI] | bound |",
        "| --- | --- | --- | --- | --- |",
    ]
    for c in s["checks"]:
        value = _interval(c, 3)
        if c["non_finite"]:
            value += f" ({c['non_finite']} non-finite left out)"
        lines.append(f"| {c['gate']} | {c['what']} | {c['passed']}/{c['n']} | {value} | {c['bound']:g} |")
    if (p := s["pooled_tests"]) is not None:
        lines.append(f"| tests | {p['what']} | | {_interval(p, 3)} | |")
    if s.get("measures"):
        lines += ["", f"| where | measure (no gate) | seeds | IQM over seeds [{ci} CI] |", "| --- | --- | --- | --- |"]
        for m in s["measures"]:
            lines.append(f"| {m['gate']} | {m['what']} | {m['n']} | {_interval(m, 3)} |")
    return "\n".join(lines)


def recipes_table(paths: Sequence[Path]) -> str:
    """One Markdown row per summary (``vacc seeds --json``): seeds (and how many hold the
    measures, where fewer), pass share, the pooled tests' gap RMSE and :data:`RECIPE_COLUMNS`,
    each as IQM [interval].

    Raises:
        click.ClickException: one line naming the file that is not such a summary.
    """
    heads = ["model", "seeds", "pass every gate", "tests: gap RMSE"] + [c[0] for c in RECIPE_COLUMNS]
    lines = ["| " + " | ".join(heads) + " |", "|" + " --- |" * len(heads)]
    for path in paths:
        try:
            s = json.loads(path.read_text())
            measures = {(m["gate"], m["what"]): m for m in s.get("measures", [])}  # none in a summary before gates measured
            shown = [measures.get(key) for _, key, _, _ in RECIPE_COLUMNS]
            measured = min((m["n"] for m in shown if m is not None), default=0)
            seeds = str(s["seeds"]) + ("" if measured == s["seeds"] else f" ({measured} measured)")
            if len(s.get("cpu_paths", {})) > 1:  # absent from summaries before 2026-12-06
                seeds += " (" + ", ".join(f"{n} {p}" for p, n in s["cpu_paths"].items()) + " kernels)"
            passed = f"{s['passed_every_gate']} of {s['seeds']}" + "".join(f" ({p} not checked)" for p in s.get("skipped", []))
            cells = [s.get("name", s["recipe"]), seeds, passed, _interval(s["pooled_tests"], 2)]
            cells += [_interval(m, decimals, percent) for m, (_, _, decimals, percent) in zip(shown, RECIPE_COLUMNS, strict=True)]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise click.ClickException(f"{path}: not a summary of `vacc seeds --json` ({exc})") from None
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


@click.command("seeds")
@click.argument("reports", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "json_out", type=click.Path(dir_okay=False), help="Also write the summary as JSON.")
@click.option("--name", default=None, help="The summary's name, its row in --across-recipes (default: the recipe's): e.g. an ablation's variant.")
@click.option("--across-recipes", is_flag=True, help="The arguments are summaries that --json wrote, one per recipe: print one row each (docs/results.md's table).")
def seeds(reports: tuple[str, ...], json_out: str | None, name: str | None, across_recipes: bool) -> None:
    """Summarise one recipe's gate reports over training seeds (each a gates.json of
    `vacc gates` or `vacc reproduce --seed N`): the share of seeds that pass every gate,
    and each check's interquartile mean with a 95 % bootstrap interval."""
    if across_recipes:
        if json_out is not None or name is not None:
            raise click.UsageError("--json and --name make one recipe's summary; --across-recipes reads them")
        click.echo(recipes_table([Path(p) for p in reports]))
        return
    summary = seed_summary(read_reports([Path(p) for p in reports]), name)
    click.echo(summary_table(summary))
    if json_out is not None:
        Path(json_out).write_text(json.dumps(summary, indent=1) + "\n")
