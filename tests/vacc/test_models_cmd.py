"""`vacc models`: models/index.json lists every shipped model, with the SHA-256 of its file."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

from vacc.cli import main
from vacc.models_cmd import INDEX_NAME, check_models, read_index, write_index

CHECKOUT = Path(__file__).resolve().parents[2]
MODELS = CHECKOUT / "models"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_index_lists_every_shipped_model_with_its_files_sha256_and_size():
    index = read_index(MODELS)
    assert sorted(m["file"] for m in index["models"]) == sorted(p.name for p in MODELS.glob("*.pt"))
    for m in index["models"]:
        path = MODELS / m["file"]
        assert m["sha256"] == _sha256(path) and m["size"] == path.stat().st_size, m["name"]
        assert m["recipe"] == f"recipes/{m['name']}.toml" and m["scenario"] == m["name"].split("-")[0]
        gates = m["gates"]
        assert gates["source"].startswith("docs/results.md") and gates["gap_rmse_m"]["mean"] > 0
        assert gates["energy"]["model"] > 0 and gates["energy"]["acc"] > 0
        each = gates["gap_rmse_m"]["per_trajectory"]
        if each:  # the mean of the table is the mean of the four, to its rounding
            assert abs(sum(each.values()) / 4 - gates["gap_rmse_m"]["mean"]) < 0.005
    assert {m["name"]: m["action"] for m in index["models"]}["ice-eco"] == "ramp-fine"


def test_the_index_is_what_write_index_makes_of_the_models(tmp_path):
    assert write_index(MODELS, tmp_path / INDEX_NAME) == []
    assert (tmp_path / INDEX_NAME).read_text() == (MODELS / INDEX_NAME).read_text()


def _copy(tmp_path: Path) -> Path:
    folder = tmp_path / "models"
    folder.mkdir()
    for name in ("ice-gap.pt", "ice-force.pt", INDEX_NAME):
        shutil.copy(MODELS / name, folder / name)
    index = json.loads((folder / INDEX_NAME).read_text())
    index["models"] = [m for m in index["models"] if m["file"] in ("ice-gap.pt", "ice-force.pt")]
    (folder / INDEX_NAME).write_text(json.dumps(index, indent=2) + "\n")
    return folder


def test_the_table_shows_each_model_and_a_recipe_not_yet_written(tmp_path):
    folder = _copy(tmp_path)
    index = json.loads((folder / INDEX_NAME).read_text())
    force = next(m for m in index["models"] if m["name"] == "ice-force")
    force["gates"]["gap_rmse_m"]["per_trajectory"] = None  # as an index from the docs' ranges records it
    (folder / INDEX_NAME).write_text(json.dumps(index, indent=2) + "\n")
    done = CliRunner().invoke(main, ["models", "--models", str(folder)])
    assert done.exit_code == 0, done.output
    row = next(line for line in done.output.splitlines() if line.startswith("ice-gap "))
    for cell in ("ice", "levels", "2.78 MB", _sha256(MODELS / "ice-gap.pt")[:12], " ok ", "recipes/ice-gap.toml (not written yet)",
                 "2.642 (2.94/2.48/2.49/2.65)", "238.3 g/mi, ACC 68.1 (+249.9%)"):  # fmt: skip
        assert cell in row, cell
    force = next(line for line in done.output.splitlines() if line.startswith("ice-force "))
    assert "4.277 (3.70–4.85)" in force  # a range where the index has no figure per trajectory
    (tmp_path / "recipes").mkdir()
    (tmp_path / "recipes" / "ice-gap.toml").write_text("")
    row = next(line for line in CliRunner().invoke(main, ["models", "--models", str(tmp_path / "models")]).output.splitlines() if line.startswith("ice-gap "))
    assert "recipes/ice-gap.toml " in row + " " and "not written yet" not in row


def test_a_file_that_is_not_the_indexed_model_is_flagged(tmp_path):
    folder = _copy(tmp_path)
    shutil.copy(MODELS / "ice-eco.pt", folder / "ice-gap.pt")  # another model under the name
    shutil.copy(MODELS / "ev-gap.pt", folder / "ev-gap.pt")  # not indexed
    (folder / "ice-force.pt").unlink()
    assert [r["check"] for r in check_models(folder)] == ["missing", "MISMATCH", "not indexed"]  # index order (by name), then the strays
    done = CliRunner().invoke(main, ["models", "--models", str(folder)])
    assert done.exit_code == 1
    assert f"MISMATCH {folder / 'ice-gap.pt'}: its SHA-256 is {_sha256(MODELS / 'ice-eco.pt')}" in done.stderr
    assert f"MISSING {folder / 'ice-force.pt'}" in done.stderr and f"NOT INDEXED {folder / 'ev-gap.pt'}" in done.stderr
    # re-made: the changed file loses the figures measured on the other one, the new file has none
    notes = write_index(folder)
    assert notes == ["ev-gap: no gate figures", "ice-gap: its file changed; its gate figures and verdict were dropped (measure them again)"]
    entries = {m["name"]: m for m in read_index(folder)["models"]}
    assert sorted(entries) == ["ev-gap", "ice-gap"] and entries["ice-gap"]["gates"] is None
    assert entries["ice-gap"]["sha256"] == _sha256(MODELS / "ice-eco.pt") and entries["ice-gap"]["action"] == "ramp-fine"
    assert all(r["check"] == "ok" for r in check_models(folder))


def test_no_index_says_how_to_write_one(tmp_path):
    done = CliRunner().invoke(main, ["models", "--models", str(tmp_path)])
    assert done.exit_code == 1 and "vacc models --write-index" in done.stderr


def test_models_end_to_end():
    done = subprocess.run([sys.executable, "-m", "vacc", "models", "--json"], capture_output=True, text=True, timeout=180, cwd=CHECKOUT)
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    assert len(rows) == len(list(MODELS.glob("*.pt"))) and all(r["check"] == "ok" for r in rows)


def _report(tmp_path: Path, sha: str, *, quick: bool = False, failing: int = 1, skipped: tuple[str, ...] = ()) -> Path:
    checks = [{"gate": "tests", "what": f"test-{i} gap RMSE", "figure": 2.5, "bound": 3.4, "passed": True} for i in range(1, 5)]
    checks += [{"gate": "safety", "what": "distant-stop seed 3", "figure": 0.0, "bound": 1.0, "passed": False}] * failing
    path = tmp_path / "gates.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps({"recipe": "ice-gap", "recipe_digest": "d" * 64, "sha256": sha, "quick": quick, "skipped": list(skipped), "checks": checks, "passed": not failing}))
    return path


def test_a_gates_verdict_is_recorded_on_the_model_it_checked_and_kept_while_the_file_is_the_same(tmp_path):
    folder = _copy(tmp_path)
    report = _report(tmp_path, _sha256(folder / "ice-gap.pt"))
    before = CliRunner().invoke(main, ["models", "--models", str(folder)]).output
    done = CliRunner().invoke(main, ["models", "--models", str(folder), "--record-gates", str(report)])
    assert done.exit_code == 0, done.output
    assert "ice-gap: FAIL 4/5 gate checks recorded" in done.output
    row = next(line for line in done.output.splitlines() if line.startswith("ice-gap "))
    assert "FAIL 4/5" in row
    other = [next(line for line in text.splitlines() if line.startswith("ice-force ")) for text in (before, done.output)]
    assert other[0] == other[1], "recording ice-gap's verdict changed another model's row"
    verdict = {m["name"]: m["verdict"] for m in read_index(folder)["models"]}["ice-gap"]
    assert verdict["failed"] == ["safety: distant-stop seed 3"] and verdict["recipe_digest"] == "d" * 64
    assert write_index(folder) == [] and {m["name"]: m["verdict"] for m in read_index(folder)["models"]}["ice-gap"] == verdict
    shutil.copy(folder / "ice-force.pt", folder / "ice-gap.pt")  # another file: the verdict goes with the figures
    assert "ice-gap: its file changed" in write_index(folder)[0]
    assert {m["name"]: m["verdict"] for m in read_index(folder)["models"]}["ice-gap"] is None


def test_a_quick_foreign_or_unreadable_gates_report_is_refused_in_one_line(tmp_path):
    folder = _copy(tmp_path)
    before = (folder / INDEX_NAME).read_bytes()
    garbage = tmp_path / "junk.json"
    garbage.write_text("{")
    for report, words in (
        (_report(tmp_path, _sha256(folder / "ice-gap.pt"), quick=True), "a --quick report checks that the gates run"),
        (_report(tmp_path / "skip", _sha256(folder / "ice-gap.pt"), failing=0, skipped=("safety",)), "it skipped safety (--skip), so it is no verdict on the model"),
        (garbage, "not a gates report of `vacc gates`"),
    ):
        done = CliRunner().invoke(main, ["models", "--models", str(folder), "--record-gates", str(report)])
        assert done.exit_code == 1 and words in done.output and done.output.count("\n") == 1, done.output
    done = CliRunner().invoke(main, ["models", "--models", str(folder), "--record-gates", str(_report(tmp_path, "0" * 64))])
    assert done.exit_code == 1 and "which is no model of" in done.output
    other = _report(tmp_path, _sha256(folder / "ice-force.pt"))  # ice-force's file, against ice-gap's gates
    done = CliRunner().invoke(main, ["models", "--models", str(folder), "--record-gates", str(other)])
    assert done.exit_code == 1 and "it checked ice-force's file against the gates of ice-gap" in done.output
    assert (folder / INDEX_NAME).read_bytes() == before
