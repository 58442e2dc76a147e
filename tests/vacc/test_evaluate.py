"""`vacc evaluate` on short trajectories: every file, one column per method, numbers recomputable."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import pytest


def vacc(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    result = vacc("evaluate", "--scenario", "ice", "--out", str(out), "--methods", "lead,acc,human", "--duration", "5", "--jobs", "2")
    assert result.returncode == 0, result.stderr
    return out, result


def test_every_file_is_written(evaluated):
    out, result = evaluated
    for name in ("table.md", "table.csv", "fig_gap.png", "fig_speed.png", "fig_training.png"):
        assert (out / name).stat().st_size > 0, name
    logs = sorted(p.name for p in (out / "logs").iterdir())
    assert logs == sorted(f"{m}-test-{i}.csv" for m in ("lead", "acc", "human") for i in range(1, 5))
    assert "Traditional ACC" in result.stdout


def test_one_column_per_method_and_paper_table(evaluated):
    out, _ = evaluated
    header = next(csv.reader((out / "table.csv").open()))
    assert header == ["trajectory", "metric", "unit", "Lead vehicle", "Traditional ACC", "Human Driver Model (Treiber et al. 2006)"]
    md = (out / "table.md").read_text()
    assert "The paper's Table 3" in md and "169.3" in md
    assert "## test-4" in md


def test_numbers_equal_vacc_metrics_on_the_logs(evaluated):
    out, _ = evaluated
    rows = {(r["trajectory"], r["metric"]): r for r in csv.DictReader((out / "table.csv").open())}
    for traj in ("test-1", "test-3"):
        result = vacc("metrics", str(out / "logs" / f"acc-{traj}.csv"), "--vehicle", "corolla", "--json")
        assert result.returncode == 0, result.stderr
        m = json.loads(result.stdout)
        assert float(rows[(traj, "Fuel")]["Traditional ACC"]) == pytest.approx(m["fuel_g_per_mi"], abs=1e-6)
        assert float(rows[(traj, "Gap RMSE to 55 m")]["Traditional ACC"]) == pytest.approx(m["gap_rmse_55m_m"], abs=1e-6)
    fuels = [json.loads(vacc("metrics", str(out / "logs" / f"acc-test-{i}.csv"), "--json").stdout)["fuel_g_per_mi"] for i in range(1, 5)]
    assert float(rows[("mean", "Fuel")]["Traditional ACC"]) == pytest.approx(sum(fuels) / 4, abs=1e-6)


def test_missing_model_names_file_and_how_to_train(tmp_path):
    result = vacc("evaluate", "--out", str(tmp_path / "o"), "--models", str(tmp_path / "nomodels"), "--methods", "ddqn-gap")
    assert result.returncode != 0
    assert "ice-gap.pt" in result.stderr and "vacc train --reward gap" in result.stderr
    assert "Traceback" not in result.stderr


def test_bad_methods_and_human_files(tmp_path):
    result = vacc("evaluate", "--out", str(tmp_path / "o"), "--methods", "acc,robot")
    assert result.returncode != 0 and "robot" in result.stderr
    result = vacc("evaluate", "--out", str(tmp_path / "o"), "--human-file", "test-9=x.csv")
    assert result.returncode != 0 and "TRAJ=PATH" in result.stderr


@pytest.mark.parametrize("zoom", [1, 2])
def test_ddqn_methods_drive_from_the_models_folder(tmp_path, zoom):
    """Each checkpoint gets the camera its zoom needs (zoom 2: 400x400, else preprocess raises)."""
    from agent_client.ddqn import Config, QNetwork, save_policy

    models = tmp_path / "models"
    models.mkdir()
    save_policy(QNetwork(), Config(zoom=zoom), models / "ice-gap.pt")
    out = tmp_path / "out"
    result = vacc("evaluate", "--out", str(out), "--models", str(models), "--methods", "ddqn-gap", "--duration", "2", "--jobs", "2")
    assert result.returncode == 0, result.stderr
    rows = list(csv.reader((out / "logs" / "ddqn-gap-test-2.csv").open()))
    assert len(rows) == 1 + 21
    assert "Gap-based DDQN" in (out / "table.md").read_text()
