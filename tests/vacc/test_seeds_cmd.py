"""vacc seeds: gate reports over training seeds -> pass share and IQM intervals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vacc.cli import main
from vacc.seeds_cmd import seed_summary
from vacc.stats import iqm

RMSE = {  # per seed: test-1..4 gap RMSE
    0: [2.5, 2.6, 2.4, 2.7],
    1: [2.9, 3.0, 2.8, 3.6],  # test-4 over the 3.4 m bound
    2: [2.4, 2.5, 2.3, 2.6],
}


def _report(folder: Path, seed: int, **change) -> Path:
    checks = [{"gate": "tests", "what": f"test-{i + 1} gap RMSE (m)", "figure": x, "bound": 3.4, "passed": x <= 3.4} for i, x in enumerate(RMSE[seed])]
    checks.append({"gate": "safety", "what": "stopped: runs passed", "figure": 10.0, "bound": 10.0, "passed": True, "detail": "min gap 3.1 m"})
    report = {"recipe": "ice-gap", "recipe_digest": "a" * 64, "sha256": f"{seed:064d}", "quick": False, "checks": checks, **change}
    path = folder / f"seed{seed}" / "gates.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report))
    return path


def test_the_summary_counts_passing_seeds_and_gives_each_checks_iqm_over_seeds(tmp_path):
    reports = [json.loads(_report(tmp_path, s).read_text()) for s in RMSE]
    s = seed_summary(reports)
    assert s["seeds"] == 3 and s["passed_every_gate"] == 2
    row = next(c for c in s["checks"] if c["what"] == "test-4 gap RMSE (m)")
    assert row["passed"] == 2 and row["n"] == 3
    assert row["iqm"] == pytest.approx(float(iqm(np.array([2.7, 3.6, 2.6]))))
    assert row["low"] <= row["iqm"] <= row["high"]
    pooled = s["pooled_tests"]
    assert pooled["n"] == 12 and pooled["low"] <= pooled["iqm"] <= pooled["high"]
    assert pooled["iqm"] == pytest.approx(float(iqm(np.array([x for xs in RMSE.values() for x in xs]))))


def test_the_command_prints_the_table_and_refuses_mixed_quick_or_repeated_reports(tmp_path):
    paths = [str(_report(tmp_path, s)) for s in RMSE]
    done = CliRunner().invoke(main, ["seeds", *paths, "--json", str(tmp_path / "s.json")])
    assert done.exit_code == 0, done.output
    assert done.output.startswith("ice-gap: 2 of 3 seeds pass every gate")
    assert "| tests | test-4 gap RMSE (m) | 2/3 |" in done.output and "stratified by trajectory" in done.output
    assert json.loads((tmp_path / "s.json").read_text())["passed_every_gate"] == 2
    other = tmp_path / "other"
    for extra, words in (
        (_report(other, 0, recipe_digest="b" * 64), "summarise one recipe's seeds at a time"),
        (_report(other, 1, quick=True), "a --quick report"),
        (_report(other, 2, measures=[{"gate": "random", "figure": 1.0}]), "not a gates report of `vacc gates` ('what')"),
        (Path(paths[0]), "the same checkpoint as"),
    ):
        done = CliRunner().invoke(main, ["seeds", *paths, str(extra)])
        assert done.exit_code == 1 and words in done.output and done.output.count("\n") == 1, done.output


def test_a_non_finite_figure_is_left_out_of_the_interval_and_said(tmp_path):
    paths = [_report(tmp_path, s) for s in RMSE]
    report = json.loads(paths[0].read_text())
    report["checks"].append({"gate": "comfort", "what": "mean jerk_rms_mps3", "figure": float("nan"), "bound": 0.7, "passed": False})
    paths[0].write_text(json.dumps(report))
    for p in paths[1:]:
        r = json.loads(p.read_text())
        r["checks"].append({"gate": "comfort", "what": "mean jerk_rms_mps3", "figure": 0.6, "bound": 0.7, "passed": True})
        p.write_text(json.dumps(r))
    done = CliRunner().invoke(main, ["seeds", *map(str, paths)])
    assert done.exit_code == 0, done.output
    assert "| comfort | mean jerk_rms_mps3 | 2/3 | 0.600 [0.600, 0.600] (1 non-finite left out) |" in done.output


def test_reports_that_named_the_closest_gap_in_the_check_group_with_the_new_ones(tmp_path):
    paths = [_report(tmp_path, s) for s in RMSE]
    old = json.loads(paths[0].read_text())
    old["checks"][-1] = {"gate": "safety", "what": "stopped: runs passed (min gap 2.9 m)", "figure": 10.0, "bound": 10.0, "passed": True}
    paths[0].write_text(json.dumps(old))
    s = seed_summary([json.loads(p.read_text()) for p in paths])
    assert [c["n"] for c in s["checks"] if c["gate"] == "safety"] == [3]


def test_measures_no_gate_bounds_are_summarised_over_the_reports_that_hold_them(tmp_path):
    """A report from before gates measured (seed 0) is left out of a measure's row, and said."""
    share = {1: 0.4, 2: 0.6}
    start_gap = {"gate": "random", "what": "closest gap (m)", "figure": 27.0}  # once measured, the start gap: left out
    paths = [_report(tmp_path, 0)] + [_report(tmp_path, s, measures=[{"gate": "random", "what": "mean ISO jerk share", "figure": share[s]}, start_gap]) for s in share]
    s = seed_summary([json.loads(p.read_text()) for p in paths])
    (row,) = s["measures"]
    assert (row["gate"], row["what"], row["n"]) == ("random", "mean ISO jerk share", 2)
    assert row["iqm"] == pytest.approx(0.5) and 0.4 <= row["low"] <= row["iqm"] <= row["high"] <= 0.6
    result = CliRunner().invoke(main, ["seeds", *map(str, paths)])
    assert result.exit_code == 0 and "| random | mean ISO jerk share | 2 | 0.500 [" in result.output


def test_summaries_of_several_recipes_give_one_row_each(tmp_path):
    """--across-recipes: the table of docs/results.md, from the summaries --json wrote."""
    measured = [{"gate": "tests", "what": "energy / the ACC's", "figure": 0.98}, {"gate": "safety", "what": "closest gap (m)", "figure": 2.5}]
    paths = [str(_report(tmp_path, s, measures=measured if s else [])) for s in RMSE]
    summary = tmp_path / "ice-gap-seeds.json"
    assert CliRunner().invoke(main, ["seeds", *paths, "--json", str(summary)]).exit_code == 0
    done = CliRunner().invoke(main, ["seeds", "--across-recipes", str(summary)])
    assert done.exit_code == 0, done.output
    head, rule, row = done.output.splitlines()
    assert head.startswith("| model | seeds | pass every gate | tests: gap RMSE | tests: energy / ACC |") and rule.count("---") == head.count("|") - 1
    cells = [c.strip() for c in row.split("|")]
    # seed 0's report predates the measures
    assert cells[1:4] == ["ice-gap", "3 (2 measured)", "2 of 3"] and cells[5] == "0.980 [0.980, 0.980]" and cells[6] == "–"
    bad = CliRunner().invoke(main, ["seeds", "--across-recipes", paths[0]])  # a report, not a summary
    assert bad.exit_code == 1 and "not a summary of `vacc seeds --json`" in bad.output and bad.output.count("\n") == 1


def test_reports_gated_on_different_kernels_are_said_to_be(tmp_path):
    """A report before the gates pinned their kernels drove on the CPU's own; one run beside
    others on AVX2 can differ in its last digits, so the summary and the row say so."""
    paths = [str(_report(tmp_path, s, **({"cpu_path": "avx2"} if s else {}))) for s in RMSE]
    summary = tmp_path / "s.json"
    done = CliRunner().invoke(main, ["seeds", *paths, "--json", str(summary)])
    assert done.exit_code == 0 and "gated on mixed CPU kernels (2 on avx2, 1 on native)" in done.output, done.output
    assert json.loads(summary.read_text())["cpu_paths"] == {"avx2": 2, "native": 1}
    row = CliRunner().invoke(main, ["seeds", "--across-recipes", str(summary)]).output.splitlines()[2]
    assert "| 3 (0 measured) (2 avx2, 1 native kernels) |" in row
    one = CliRunner().invoke(main, ["seeds", *paths[1:]])
    assert one.exit_code == 0 and "mixed" not in one.output


def test_the_same_reports_in_another_order_give_the_same_summary(tmp_path):
    rng = np.random.default_rng(3)
    paths = []
    for seed in range(8):  # spread figures: the bootstrap draws by position
        checks = [{"gate": "tests", "what": f"test-{i + 1} gap RMSE (m)", "figure": float(x), "bound": 3.4, "passed": bool(x <= 3.4)} for i, x in enumerate(rng.uniform(2, 5, 4))]
        paths.append(str(_report(tmp_path, seed % 3, checks=checks, sha256=f"{seed:064d}").rename(tmp_path / f"r{seed}.json")))
    a = CliRunner().invoke(main, ["seeds", *paths])
    b = CliRunner().invoke(main, ["seeds", *reversed(paths)])
    assert a.exit_code == b.exit_code == 0 and a.output == b.output


def test_reports_that_skipped_runs_are_summarised_only_together_and_named(tmp_path):
    """An ablation's reports (`vacc gates --skip safety`): their pass share is over the checks
    run and says so; a full report is refused beside them; --name labels the row."""
    def skipped(seed: int) -> Path:
        path = _report(tmp_path / "abl", seed, skipped=["safety"])
        report = json.loads(path.read_text())
        report["checks"] = [c for c in report["checks"] if c["gate"] != "safety"]
        path.write_text(json.dumps(report))
        return path

    paths = [str(skipped(s)) for s in RMSE]
    summary = tmp_path / "noaug.json"
    done = CliRunner().invoke(main, ["seeds", *paths, "--name", "no-aug", "--json", str(summary)])
    assert done.exit_code == 0, done.output
    assert done.output.startswith("no-aug (ice-gap): 2 of 3 seeds pass every gate checked; safety not checked")
    row = CliRunner().invoke(main, ["seeds", "--across-recipes", str(summary)]).output.splitlines()[2]
    assert row.startswith("| no-aug | 3 (0 measured) | 2 of 3 (safety not checked) |"), row
    full = _report(tmp_path / "full", 0, sha256="f" * 64)
    mixed = CliRunner().invoke(main, ["seeds", *paths, str(full)])
    assert mixed.exit_code == 1 and "summarise reports of the same checks" in mixed.output and mixed.output.count("\n") == 1, mixed.output
    both = CliRunner().invoke(main, ["seeds", "--across-recipes", str(summary), "--name", "x"])
    assert both.exit_code == 2 and "--across-recipes reads them" in both.output
