"""``report.html`` of `vacc evaluate`: one self-contained page to open from disk or send.

Everything is inside the one file: the tables of ``table.md`` (as HTML tables), every
figure (its PNG embedded as base64), the per-run table with the runs that ended early
flagged, each run's card (what was driven, with which checkpoint and road), and links
to the videos when ``--videos`` made them (relative links: the videos stay beside the
report). No script, no stylesheet or font from the internet.
"""

from __future__ import annotations

import base64
import datetime
import html
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vacc.runs import Job, Run

__all__ = ["CSS", "markdown_html", "run_rows", "write_report"]

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 24px auto; max-width: 1180px; color: #1b1b1b; padding: 0 16px; }
h1 { font-size: 22px; } h2 { font-size: 17px; margin-top: 28px; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 8px 0 16px; font-size: 12.5px; }
th, td { border: 1px solid #d0d0d0; padding: 3px 7px; text-align: right; } th { background: #f2f2f2; }
td:first-child, th:first-child { text-align: left; }
tr.early td { background: #fde8e6; } .flag { color: #b3261e; font-weight: 600; }
figure { margin: 12px 0 24px; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { color: #555; font-size: 12px; } details { margin: 4px 0; } pre { background: #f7f7f7; padding: 8px; overflow-x: auto; }
"""


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def markdown_html(text: str) -> str:
    """The subset of markdown ``table.md`` uses, as HTML: headings, pipe tables, paragraphs."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")) + 1, 4)  # the page's own h1 is the title
            out.append(f"<h{level}>{html.escape(line.lstrip('#').strip())}</h{level}>")
        elif line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].startswith("|"):
                block.append(lines[i])
                i += 1
            head, body = _cells(block[0]), [_cells(b) for b in block[2:]]
            rows = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in body)
            out.append("<table><thead><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head) + f"</tr></thead><tbody>{rows}</tbody></table>")
            continue
        elif line.strip():
            out.append(f"<p>{html.escape(line)}</p>")
        i += 1
    return "\n".join(out)


RUN_COLUMNS = ("Method", "Trajectory", "Seed", "Driven (s)", "Gap RMSE (m)", "Min gap (m)", "Collisions", "Energy", "End", "Video")


def run_rows(runs: Sequence[Run], labels: dict[str, str], energy_key: str, videos: dict[str, str]) -> str:
    """The per-run table: one row per run, an early end flagged (how and when), its video linked."""
    rows = []
    for r in runs:
        m = r.metrics
        gap = "—" if r.method == "lead" else f"{m['gap_rmse_55m_m']:.3f}"
        min_gap = "—" if r.method == "lead" else f"{m['gap_min_m']:.2f}"
        end = f'<span class="flag">ended early: {html.escape(r.early.text())}</span>' if r.early else "ran to its end"
        key = Path(r.log.path).name
        video = f'<a href="{html.escape(videos[key])}">{html.escape(Path(videos[key]).name)}</a>' if key in videos else ""
        cells = [labels.get(r.method, r.method), r.trajectory, "" if r.seed is None else str(r.seed), f"{float(r.log.t[-1]):.1f}", gap, min_gap,
                 str(m["collisions"]), f"{float(m[energy_key]):.1f}", end, video]  # type: ignore[arg-type]  # fmt: skip
        tr = '<tr class="early">' if r.early else "<tr>"
        rows.append(tr + "".join(f"<td>{c if i >= 8 else html.escape(c)}</td>" for i, c in enumerate(cells)) + "</tr>")
    head = "".join(f"<th>{c}</th>" for c in RUN_COLUMNS).replace("Energy", "Fuel (g/mi)" if energy_key.startswith("fuel") else "Energy (kJ/mi)")
    return f'<table id="runs"><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>'


def _card(job: Job) -> dict[str, Any]:
    from agent_client.runlog import file_sha256

    return {
        "method": job.method, "scenario": job.scenario, "trajectory": job.trajectory, "seed": job.seed, "duration": job.duration,
        "checkpoint": job.checkpoint, "checkpoint_sha256": file_sha256(job.checkpoint) if job.checkpoint else None,
        "human_file": job.human_file, "cold_start": job.cold_start,
        "road": {"traffic": job.road.traffic, "sun_elevation": list(job.road.sun_elevation)}, "log": Path(job.log).name,
    }  # fmt: skip


def _figures(out: Path, names: Sequence[str]) -> str:
    parts = []
    for name in names:
        png = out / f"{name}.png"
        if png.is_file():
            data = base64.b64encode(png.read_bytes()).decode("ascii")
            parts.append(f'<figure id="{name}"><img alt="{name}" src="data:image/png;base64,{data}"><figcaption>{name}.png (and {name}.pdf)</figcaption></figure>')
    return "\n".join(parts) or "<p>None drawn (vacc evaluate --no-figures).</p>"


def write_report(
    out: Path, *, title: str, figures: Sequence[str], runs: Sequence[Run], jobs: Sequence[Job], labels: dict[str, str],
    scenario: str, videos: dict[str, str] | None = None,
) -> Path:  # fmt: skip
    """Write ``out/report.html`` from ``out/table.md``, the figures' PNGs, the scored runs and their jobs.

    Args:
        figures: the figures' names (``<name>.png`` in ``out``).
        videos: log file name -> the video's path relative to ``out``.

    Returns:
        The report's path.
    """
    videos = videos or {}
    energy_key = "fuel_g_per_mi" if scenario == "ice" else "energy_kj_per_mi"
    early = sum(1 for r in runs if r.early)
    cards = "\n".join(
        f"<details><summary>{html.escape(Path(j.log).name)}</summary><pre>{html.escape(json.dumps(_card(j), indent=2))}</pre></details>" for j in jobs
    )
    when = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    body = [
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Written by vacc evaluate at {when}. {len(runs)} runs; "
        + (f'<span class="flag">{early} ended early</span> (flagged below).' if early else "every run ran to its end.") + "</p>",
        '<section id="tables">' + markdown_html((out / "table.md").read_text()) + "</section>",
        '<h2>Figures</h2><section id="figures">' + _figures(out, figures) + "</section>",
        '<h2>Every run</h2><section id="per-run">' + run_rows(runs, labels, energy_key, videos) + "</section>",
        f'<h2>Run cards</h2><section id="cards">{cards}</section>',
    ]
    page = f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title><style>{CSS}</style></head>\n<body>\n' + "\n".join(body) + "\n</body></html>\n"
    path = out / "report.html"
    path.write_text(page, encoding="utf-8")
    return path
