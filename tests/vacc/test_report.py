"""report.html of `vacc evaluate` (headless Chromium), runs that end early, and --model NAME=PATH."""

from __future__ import annotations

import shutil
import subprocess
import sys
from html.parser import HTMLParser

import click
import numpy as np
import pytest

from energy import evaluate_run, read_run_log
from vacc.evaluate import parse_models
from vacc.runs import Run, early_end, log_path
from vacc.tables import compute_table, write_table_md

LABELS = {"acc": "ACC", "human": "HDM"}


def vacc(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout)


class Structure(HTMLParser):
    """What a page holds: its tags by name, ids, images' sources, links."""

    def __init__(self):
        super().__init__()
        self.tags: dict[str, int] = {}
        self.ids: set[str] = set()
        self.images: list[str] = []
        self.links: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags[tag] = self.tags.get(tag, 0) + 1
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag == "a":
            self.links.append(a.get("href", ""))


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    result = vacc("evaluate", "--out", str(out), "--methods", "lead,acc", "--duration", "3", "--jobs", "2", "--settle", "1", "--videos")
    assert result.returncode == 0, result.stderr
    return out, result


def test_report_holds_every_table_figure_run_and_card(evaluated):
    out, result = evaluated
    assert "report.html" in result.stdout.splitlines()[-1]
    page = Structure()
    page.feed((out / "report.html").read_text())
    # table.md's tables: the mean, the paper's, one per trajectory; and the per-run table
    assert page.tags["table"] == 1 + 1 + 4 + 1 and "runs" in page.ids
    figures = ["fig_gap", "fig_speed", "fig_comfort", "fig_emissions", "fig_headway", "fig_pareto", "fig_training"]
    assert set(figures) <= page.ids and len(page.images) == len(figures)
    assert all(src.startswith("data:image/png;base64,") and len(src) > 5000 for src in page.images)  # embedded, no file beside
    assert page.tags["details"] == 8  # a card per run (lead and ACC on four trajectories)
    assert sorted(page.links) == [f"videos/acc-test-{i}.mp4" for i in range(1, 5)]  # the lead's log is not a run to replay
    assert all((out / link).stat().st_size > 1000 for link in page.links)
    assert "http://" not in (out / "report.html").read_text() and "https://" not in (out / "report.html").read_text()


def test_report_in_headless_chromium_is_not_blank(evaluated, tmp_path):
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("no headless Chromium: apt-get install -y chromium (Debian) to screenshot report.html")
    from PIL import Image

    out, _ = evaluated
    shot = tmp_path / "report.png"
    subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1200,2000",
                    f"--screenshot={shot}", (out / "report.html").as_uri()], capture_output=True, timeout=120, check=True)  # fmt: skip
    pixels = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert pixels.shape == (2000, 1200)
    assert pixels.std() > 20 and (pixels < 100).mean() > 0.005  # text and table lines on a white page


def _log(path, n: int, collision_at: int | None = None) -> None:
    with path.open("w") as f:
        f.write("t,frame,v_host,v_lead,gap,accel,force,collision,a_lead\n")
        for k in range(n):
            hit = int(collision_at is not None and k == n - 1)
            f.write(f"{k / 10!r},{k},20.0,20.0,{50.0 - 0.01 * k!r},0.0,0.0,{hit},0.0\n")


def test_runs_that_end_early_are_flagged_and_left_out(tmp_path):
    (tmp_path / "logs").mkdir()
    runs = []
    for m in ("acc", "human"):
        for traj in ("test-1", "test-2"):
            early = m == "human" and traj == "test-2"
            path = log_path(tmp_path, m, traj)
            _log(path, 141 if early else 201, collision_at=140 if early else None)
            log = read_run_log(path)
            runs.append(Run(m, traj, None, log, evaluate_run(log, "corolla", settle_s=1.0), early_end(log, 20.0)))
    assert [r.early is not None for r in runs] == [False, False, False, True]
    assert runs[3].early.text() == "collision at 14.0 s of 20 s"
    row = next(r for r in compute_table(runs, "ice", ["acc", "human"], LABELS, "corolla").rows if r.key == "collisions")
    left_out = compute_table(runs, "ice", ["acc", "human"], LABELS, "corolla")
    kept = compute_table(runs, "ice", ["acc", "human"], LABELS, "corolla", include_early=True)
    assert left_out.value("human", None, row) == 0 and kept.value("human", None, row) == 1
    assert left_out.trajectories == ["test-1", "test-2"] and left_out.shown("human", "test-2", row) == "—"
    text = write_table_md(tmp_path, left_out).read_text()
    assert text.splitlines()[0].endswith("; 1 run ended early, left out")
    assert "| HDM | test-2 |  | collision | 14.0 | 20 |" in text and "--include-early keeps them" in text
    # a run that ran to its end: nothing said, the table as before
    assert "ended early" not in write_table_md(tmp_path, compute_table(runs[:3], "ice", ["acc", "human"], LABELS, "corolla")).read_text()


def test_a_lost_lead_is_said_so(tmp_path):
    path = tmp_path / "x.csv"
    _log(path, 50)
    text = path.read_text().splitlines()
    text[-1] = text[-1].replace(text[-1].split(",")[4], "300.5")
    path.write_text("\n".join(text) + "\n")
    assert early_end(read_run_log(path), None).how == "lost the lead (gap past 300 m)"


def test_model_of_the_other_scenario_is_refused_in_one_line(tmp_path):
    with pytest.raises(click.BadParameter, match=r"models/ev-eco.pt was trained for the ev scenario, not ice: add --scenario ev"):
        parse_models(("eco=models/ev-eco.pt",), "ice")
    assert parse_models(("eco=models/ev-eco.pt",), "ev") == {"eco": "models/ev-eco.pt"}
    for bad, message in (("acc=models/ice-eco.pt", "which is taken"), ("x", "is not NAME=PATH"), ("x=nope.pt", "no such checkpoint")):
        with pytest.raises(click.BadParameter, match=message):
            parse_models((bad,), "ice")
    result = vacc("evaluate", "--out", str(tmp_path), "--model", "eco=models/ev-eco.pt", "--methods", "acc")
    assert result.returncode == 2 and result.stderr.strip().splitlines()[-1].startswith("Error: Invalid value for --model: models/ev-eco.pt")
    result = vacc("evaluate", "--out", str(tmp_path), "--suite", "safety", "--videos")
    assert result.returncode == 2 and "--videos works with --suite paper only" in result.stderr
    result = vacc("evaluate", "--out", str(tmp_path), "--suite", "random", "--no-figures")
    assert result.returncode == 2 and "--no-figures works with --suite paper only" in result.stderr
