"""`vacc evaluate` on short trajectories: every file, one column per method, numbers recomputable."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest


def vacc(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    result = vacc("evaluate", "--scenario", "ice", "--out", str(out), "--methods", "lead,acc,human", "--duration", "5", "--jobs", "2", "--settle", "1")
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
        m = json.loads(vacc("metrics", str(out / "logs" / f"acc-{traj}.csv"), "--json", "--settle", "1").stdout)
        assert float(rows[(traj, "Jerk RMS")]["Traditional ACC"]) == pytest.approx(m["jerk_rms_mps3"], abs=1e-6)
        assert float(rows[(traj, "ISO jerk: 1-s windows over 2.5 m/s^3")]["Traditional ACC"]) == pytest.approx(100 * m["iso_jerk_window_share"], abs=1e-6)
        assert float(rows[(traj, "Max speed")]["Traditional ACC"]) == pytest.approx(m["speed_max_mps"], abs=1e-6)
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
    from agent_client.rl.checkpoint import save_policy
    from agent_client.rl.config import Config
    from agent_client.rl.network import QNetwork

    models = tmp_path / "models"
    models.mkdir()
    save_policy(QNetwork(), Config(zoom=zoom), models / "ice-gap.pt")
    out = tmp_path / "out"
    result = vacc("evaluate", "--out", str(out), "--models", str(models), "--methods", "ddqn-gap", "--duration", "2", "--jobs", "2", "--no-figures")
    assert result.returncode == 0, result.stderr
    assert not list(out.glob("fig_*")) and "None drawn (vacc evaluate --no-figures)" in (out / "report.html").read_text()
    rows = list(csv.reader((out / "logs" / "ddqn-gap-test-2.csv").open()))
    assert len(rows) == 1 + 21
    assert "Gap-based DDQN" in (out / "table.md").read_text()


def test_eco_model_joins_the_default_methods_with_a_pareto_figure(tmp_path):
    """A shipped <scenario>-eco.pt is a column of the default table; fig_pareto plots every method."""
    from agent_client.rl.checkpoint import save_policy
    from agent_client.rl.config import Config
    from agent_client.rl.network import QNetwork

    models = tmp_path / "models"
    models.mkdir()
    out = tmp_path / "out"
    result = vacc("evaluate", "--out", str(out), "--models", str(models), "--duration", "2", "--jobs", "2", "--methods", "ddqn-eco")
    assert result.returncode != 0 and "ice-eco.pt" in result.stderr and "--reward eco" in result.stderr
    cfg = Config(reward="eco", action="steps", zoom=2)
    save_policy(QNetwork.of(cfg), cfg, models / "ice-eco.pt")
    for name in ("gap", "force"):
        save_policy(QNetwork(), Config(reward=name), models / f"ice-{name}.pt")
    result = vacc("evaluate", "--out", str(out), "--models", str(models), "--duration", "2", "--jobs", "2")
    assert result.returncode == 0, result.stderr
    header = next(csv.reader((out / "table.csv").open()))
    assert "Eco DDQN" in header and "Traditional ACC" in header
    forces = np.loadtxt(out / "logs" / "ddqn-eco-test-1.csv", delimiter=",", skiprows=1, usecols=6)
    assert np.all(np.abs(np.diff(forces)) <= 0.5 + 1e-9)  # it holds its force between steps
    for ext in ("png", "pdf"):
        assert (out / f"fig_pareto.{ext}").stat().st_size > 1000


def test_traffic_is_named_and_leaves_the_accs_drive_alone(evaluated, tmp_path):
    # The ACC reads the gap, not the picture: an empty road drives it the same, and the
    # table says which road it was. The module's evaluation is of the default road.
    default, _ = evaluated
    out = tmp_path / "0"
    result = vacc("evaluate", "--out", str(out), "--methods", "acc", "--duration", "5", "--jobs", "2", "--settle", "1", "--traffic", "0", "--no-figures")
    assert result.returncode == 0, result.stderr
    for folder, empty in ((out, True), (default, False)):
        title = (folder / "table.md").read_text().splitlines()[0]
        assert title.endswith(", 0 cars in each adjacent lane (default 3)") == empty, title
    for k in range(1, 5):
        assert (out / "logs" / f"acc-test-{k}.csv").read_bytes() == (default / "logs" / f"acc-test-{k}.csv").read_bytes()


def _write_log(path, gap: float, v_max: float, flips: bool, phantom: bool = False) -> None:
    """A 30 s log at 0.1 s: steady at 20 m/s with one row at v_max and gap; ±1.5 m/s²
    flips every second over 20-25 s when flips; one row braking at 4 m/s² at 26 s, 55 m
    behind the steady lead, when phantom."""
    with path.open("w") as f:
        f.write("t,frame,v_host,v_lead,gap,accel,force,collision,a_lead\n")
        for k in range(301):
            t = k / 10
            accel = (1.5 if k // 10 % 2 == 0 else -1.5) if flips and 200 <= k < 250 else -4.0 if phantom and k == 260 else 0.0
            v, g = (v_max, gap) if k == 100 else (20.0, 55.0)
            f.write(f"{t},{k},{v},20.0,{g},{accel},0.0,0,0.0\n")


def test_comfort_and_safety_rows_combine_per_their_rule(tmp_path):
    """Minima are minima over the runs, the maximum speed a maximum, shares are shown in %."""
    from vacc.tables import build_tables

    logs = tmp_path / "logs"
    logs.mkdir()
    for i in range(1, 5):
        _write_log(logs / f"acc-test-{i}.csv", gap=40.0 - i, v_max=20.0 + i, flips=i == 2, phantom=i >= 3)
        _write_log(logs / f"lead-test-{i}.csv", gap=55.0, v_max=25.0, flips=False)
    res = build_tables(tmp_path, "ice", ["lead", "acc"], {"lead": "Lead", "acc": "ACC"}, "corolla")
    acc = res["acc"]
    assert acc["gap_min_m"] == 36.0 and acc["speed_max_mps"] == 24.0
    assert acc["headway_min_s"] == pytest.approx(36.0 / 24.0)
    assert res["lead"]["gap_min_m"] is None and res["lead"]["speed_max_mps"] == 25.0
    # test-2: 4 flips in the 15 s after the 15 s settle; the others none
    assert acc["accel_sign_changes_per_min"] == pytest.approx((4 / 0.25) / 4)
    rows = {(r["trajectory"], r["metric"]): r for r in csv.DictReader((tmp_path / "table.csv").open())}
    share = float(rows[("test-2", "ISO jerk: 1-s windows over 2.5 m/s^3")]["ACC"])
    assert share == pytest.approx(100 * 40 / 141)  # windows from s = 20.0 .. 23.9 flip 3 m/s²
    assert float(rows[("mean", "Min gap")]["ACC"]) == 36.0
    assert rows[("mean", "Min gap")]["Lead"] == "—"
    md = (tmp_path / "table.md").read_text()
    assert "leave out the first 15 s" in md and "| Accel sign changes (1/min) |" in md
    assert rows[("mean", "Unprompted hard brakes (past 3.5 m/s^2, no threat ahead)")]["ACC"] == "2"  # summed: test-3 and test-4
    assert rows[("test-3", "Unprompted hard brakes (past 3.5 m/s^2, no threat ahead)")]["ACC"] == "1"
    assert rows[("mean", "Unprompted hard brakes (past 3.5 m/s^2, no threat ahead)")]["Lead"] == "—"
    assert res["lead"]["fuel_g_per_mi_vs_acc"] == pytest.approx(res["lead"]["fuel_g_per_mi"] / acc["fuel_g_per_mi"], rel=0.5)
    assert res["acc"]["fuel_g_per_mi_vs_acc"] is None
    whole = build_tables(tmp_path, "ice", ["acc"], {"acc": "ACC"}, "corolla", settle=0.0)["acc"]
    assert "fuel_g_per_mi_vs_acc" not in whole  # no other method: no row
    # the same jerk, spread over 300 intervals instead of the last 150
    assert whole["jerk_rms_mps3"] == pytest.approx(acc["jerk_rms_mps3"] * np.sqrt(150 / 300))
    assert whole["gap_min_m"] == acc["gap_min_m"] and "first 0 s" in (tmp_path / "table.md").read_text()


@pytest.mark.parametrize("value", ["-1", "nan"])
def test_bad_settle_is_a_one_line_error(tmp_path, value):
    result = vacc("evaluate", "--out", str(tmp_path / "o"), "--methods", "acc", "--settle", value)
    assert result.returncode == 2 and "Invalid value for '--settle': must be a finite number >= 0" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "o").exists()


def test_seeds_give_intervals_and_the_iqm(tmp_path):
    """--seeds 0-1: a log per seed, means with bootstrap intervals equal to the logs' own, the same tables twice."""
    from energy import evaluate_run
    from vacc.evaluate import LABELS
    from vacc.stats import iqm
    from vacc.tables import build_tables

    out = tmp_path / "o"
    result = vacc("evaluate", "--out", str(out), "--methods", "lead,acc", "--seeds", "0-1", "--duration", "2", "--jobs", "2", "--settle", "0.5")
    assert result.returncode == 0, result.stderr
    logs = sorted(p.name for p in (out / "logs").iterdir())
    assert logs == sorted(f"{m}-test-{i}-seed{s}.csv" for m in ("lead", "acc") for i in range(1, 5) for s in (0, 1))
    md = (out / "table.md").read_text()
    assert "average of 4 trajectories × 2 seeds (0-1)" in md and "## Interquartile mean (rliable)" in md
    assert "| Fuel (g/mi) | lower | " in md and "stratified bootstrap" in md
    fuel = {(t, s): float(evaluate_run(out / "logs" / f"acc-{t}-seed{s}.csv", "corolla")["fuel_g_per_mi"]) for t in ("test-1", "test-2", "test-3", "test-4") for s in (0, 1)}  # type: ignore[arg-type]
    stats = {(r["trajectory"], r["metric"], r["method"], r["statistic"]): r for r in csv.DictReader((out / "stats.csv").open())}
    mean = stats[("mean", "Fuel", "Traditional ACC", "mean")]
    assert float(mean["value"]) == pytest.approx(np.mean(list(fuel.values())), rel=1e-5)
    assert float(mean["ci_low"]) <= float(mean["value"]) <= float(mean["ci_high"]) and mean["runs"] == "8"
    assert float(stats[("mean", "Fuel", "Traditional ACC", "iqm")]["value"]) == pytest.approx(float(iqm(np.array(list(fuel.values())))), rel=1e-5)
    assert float(stats[("test-2", "Fuel", "Traditional ACC", "mean")]["value"]) == pytest.approx((fuel["test-2", 0] + fuel["test-2", 1]) / 2, rel=1e-5)
    assert stats[("mean", "Min gap", "Traditional ACC", "min")]["runs"] == "8"
    # paired: each lead run's fuel over the ACC's of the same trajectory and seed
    lead = {k: float(evaluate_run(out / "logs" / f"lead-{k[0]}-seed{k[1]}.csv", "corolla")["fuel_g_per_mi"]) for k in fuel}  # type: ignore[arg-type]
    ratio = stats[("mean", "Fuel against the ACC, per run", "Lead vehicle", "mean")]
    paired = [lead[k] / fuel[k] for k in fuel if fuel[k]]  # a ratio to no fuel (2 s of coasting) is undefined: left out
    assert float(ratio["value"]) == pytest.approx(np.mean(paired), rel=1e-5) and ratio["runs"] == str(len(paired))
    assert not any(k[1] == "Fuel against the ACC, per run" and k[2] == "Traditional ACC" for k in stats)  # not against itself
    assert "| Fuel against the ACC, per run (×) | lower | " in md and "on the same trajectory and seed" in md
    for name in ("fig_gap", "fig_speed", "fig_comfort", "fig_emissions", "fig_headway", "fig_pareto", "fig_training"):
        for ext in ("png", "pdf"):
            assert (out / f"{name}.{ext}").stat().st_size > 1000, (name, ext)
    build_tables(out, "ice", ["lead", "acc"], LABELS, "corolla", settle=0.5, seeds=[0, 1])
    assert (out / "table.md").read_text() == md  # the seeded bootstrap gives the same intervals


def test_seed_options():
    from vacc.evaluate import _seed_list

    assert _seed_list(None, None, "paper") == [0]
    assert _seed_list(None, None, "safety") == list(range(10))
    assert _seed_list(3, None, "safety") == [3]
    assert _seed_list(None, "0-2,7", "paper") == [0, 1, 2, 7]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seed", "1", "--seeds", "0-3"], "give --seed 1 or --seeds 0-3, not both"),
        (["--seeds", "3-1"], "increasing range"),
        (["--seeds", "x"], "not a seed list"),
        (["--seed", "-1"], "negative"),
        (["--suite", "safety", "--seeds", "1-"], "not a seed list"),
    ],
)
def test_bad_seeds_are_one_line_errors(tmp_path, args, message):
    result = vacc("evaluate", "--out", str(tmp_path / "o"), "--methods", "acc", *args)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "o").exists()


def test_a_recorded_drive_is_one_seed(tmp_path):
    drive = tmp_path / "drive.csv"
    drive.write_text("")
    result = vacc("evaluate", "--out", str(tmp_path / "o"), "--methods", "human", "--seeds", "0-1", "--human-file", f"test-1={drive}")
    assert result.returncode == 2 and "a recorded drive is of one seed" in result.stderr
