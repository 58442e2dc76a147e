"""Every script of scripts/: documented at its top, importing public names only, and run
on a tiny input (the whole script, as a user runs it)."""

from __future__ import annotations

import ast
import csv
import importlib
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from agent_client.runlog import write_card

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))
PRODUCT = ("vacc", "agent_client", "sim_server", "protocol", "energy")


def run(script: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    # the checkout's packages first: a script's own folder, not the checkout, is its sys.path[0]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, str(ROOT / "scripts" / script), *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env)


def _public(module: str, name: str) -> bool:
    """``name`` is public in ``module``: in its ``__all__`` (or, without one, no leading
    underscore), or a public submodule; and no part of the module's path is private."""
    if any(part.startswith("_") for part in module.split(".")) or name.startswith("_"):
        return False
    mod = importlib.import_module(module)
    if hasattr(mod, "__path__") and importlib.util.find_spec(f"{module}.{name}") is not None:
        return True
    exported = getattr(mod, "__all__", None)
    return name in exported if exported is not None else True


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_a_script_imports_only_public_names(script):
    private = []
    for node in ast.walk(ast.parse(script.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PRODUCT:
            private += [f"{node.module}.{a.name}" for a in node.names if not _public(node.module, a.name)]
        elif isinstance(node, ast.Import):
            private += [a.name for a in node.names if a.name.split(".")[0] in PRODUCT and any(p.startswith("_") for p in a.name.split("."))]
    assert private == [], f"{script.name} imports private names"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_a_script_says_at_its_top_what_it_answers_and_how_to_run_it(script):
    doc = ast.get_docstring(ast.parse(script.read_text()))
    assert doc and len(doc.splitlines()) >= 5, script.name
    assert f"scripts/{script.name}" in doc, f"{script.name}: no command line in its docstring"


def test_every_script_has_a_run_test_here():
    tested = {"calibrate_cmem.py", "energy_frontier.py", "fit_ev_model.py", "model_curve.py", "openacc_platoons.py", "reward_ablation.py"}
    assert {p.name for p in SCRIPTS} == tested


def test_calibrate_cmem_prints_the_fit_and_writes_nothing_without_write():
    shipped = (ROOT / "energy" / "data" / "corolla_cmem_calibration.csv").read_bytes()
    result = run("calibrate_cmem.py")
    assert result.returncode == 0, result.stderr
    assert "hwfet" in result.stdout and "udds_bag2" in result.stdout
    assert (ROOT / "energy" / "data" / "corolla_cmem_calibration.csv").read_bytes() == shipped


def test_fit_ev_model_prints_the_fit_and_the_held_out_cycle():
    result = run("fit_ev_model.py")
    assert result.returncode == 0, result.stderr
    assert "eq. 6 fitted to VT-CPEM on udds, hwfet, us06" in result.stdout and "R^2 = " in result.stdout
    assert "wltc_3b" in result.stdout and "(held out)" in result.stdout
    assert "wrote" not in result.stdout


def _log(path: Path, v: float, gap: float, scenario: str | None = "ice") -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "frame", "v_host", "v_lead", "gap", "accel", "force", "collision", "a_lead"])
        w.writerows([k / 10, k, v, v, gap, 0.0, 0.0, 0, 0.0] for k in range(50))
    if scenario is not None:
        write_card(path, {"episode": {"scenario": scenario, "trajectory": "test-1", "seed": 0}})


def test_reward_ablation_reads_the_scenario_from_the_run_cards_not_the_folder_name(tmp_path):
    """A folder named eval-ev... of ICE runs is scored as ICE; a log without a card is refused."""
    run_dir = tmp_path / "eval-every-method"
    (run_dir / "logs").mkdir(parents=True)
    _log(run_dir / "logs" / "acc-test-1.csv", 20.0, 40.0, scenario=None)
    result = run("reward_ablation.py", str(run_dir))
    assert result.returncode == 1 and "its run card does not say the scenario" in result.stderr
    _log(run_dir / "logs" / "acc-test-1.csv", 20.0, 40.0, scenario="ice")
    ice = run("reward_ablation.py", str(run_dir))
    _log(run_dir / "logs" / "acc-test-1.csv", 20.0, 40.0, scenario="ev")
    ev = run("reward_ablation.py", str(run_dir))
    assert ice.returncode == ev.returncode == 0 and ice.stdout != ev.stdout  # the energy term is the vehicle's


def test_reward_ablation_scores_groups_of_cardless_logs_given_their_scenario(tmp_path):
    for name, gap in (("close", 40.0), ("far", 150.0)):
        for k in (1, 2):
            _log(tmp_path / f"{name}-{k}.csv", 20.0, gap, scenario=None)
    groups = ["--group", f"near={tmp_path}/close-*.csv", "--group", f"away={tmp_path}/far-*.csv"]
    refused = run("reward_ablation.py", *groups)
    assert refused.returncode == 1 and "give --scenario" in refused.stderr
    result = run("reward_ablation.py", "--scenario", "ice", *groups)
    assert result.returncode == 0, result.stderr
    gap_only = next(line for line in result.stdout.splitlines() if line.startswith("gap only"))
    assert gap_only.split()[2] == "near" and gap_only.split()[4] == "away"
    none = run("reward_ablation.py", "--scenario", "ice", "--group", f"x={tmp_path}/nothing-*.csv")
    assert none.returncode == 1 and "no file matches" in none.stderr


def test_reward_ablation_ranks_a_close_follower_above_a_far_one(tmp_path):
    run_dir = tmp_path / "eval-ice"
    (run_dir / "logs").mkdir(parents=True)
    _log(run_dir / "logs" / "acc-test-1.csv", 20.0, 40.0)  # the eco gap at 20 m/s
    _log(run_dir / "logs" / "ddqn-gap-test-1.csv", 20.0, 150.0)
    result = run("reward_ablation.py", str(run_dir))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "mean terms per step (gap/10, -energy, -comfort, -closing):"
    gap_only = next(line for line in lines if line.startswith("gap only"))
    assert gap_only.split()[2] == "acc" and gap_only.split()[4] == "ddqn-gap"  # best first
    assert len(lines) == 1 + 2 + 7  # the terms, one line per method, one per weighting


def test_reward_ablation_without_logs_says_so(tmp_path):
    result = run("reward_ablation.py", str(tmp_path))
    assert result.returncode == 1 and "no run logs" in result.stderr


@pytest.mark.timeout(600)
def test_energy_frontier_on_one_episode_and_a_one_point_grid(tmp_path):
    out = tmp_path / "ef"
    result = run("energy_frontier.py", "--seeds", "200", "--betas", "0.1", "--gammas", "0.5", "--lams", "1", "--out", str(out), timeout=540)
    assert result.returncode == 0, result.stderr
    assert (out / "summary.json").stat().st_size > 0 and (out / "energy-frontier.png").stat().st_size > 0
    rows = [line.split("  ")[0] for line in result.stdout.splitlines()]
    assert {"acc", "law beta 0.1 gamma 0.5", "preview lam 1"} <= set(rows)
    assert "x1.000 of the ACC" in result.stdout


@pytest.mark.slow  # about a minute: ten followers fitted
def test_openacc_platoons_on_one_file(tmp_path):
    out = run("openacc_platoons.py", "--files", "long_setting_dynamic_part19.csv", "--calibrate", "--followers", "3", "--figures", str(tmp_path))
    assert out.returncode == 0, out.stderr
    rows = out.stdout.splitlines()
    assert rows[1].startswith("long_setting_dynamic_part19.csv,11,1.12,1.09,")  # the real platoon, whole run and after a fifth
    fits = [r.split(",") for r in rows[3:]]
    assert [f[1:3] for f in fits] == [["1", "MAZDA_3"], ["2", "TOYOTA_RAV4"], ["3", "AUDI_E_TRON"]]
    assert all(float(f[6]) < 2.0 for f in fits), fits  # each of the three fitted within 2 m RMSE
    assert (tmp_path / "long_setting_dynamic_part19_time_space.png").exists()


def test_model_curve_bins_a_runs_episodes_by_reward_per_step(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    rows = [(400, "charts/episodic_return", 100.0), (400, "charts/episodic_length", 400), (400, "losses/td_loss", 9.0),
            (4_800, "charts/episodic_return", 300.0), (4_800, "charts/episodic_length", 600), (5_200, "charts/episodic_return", -50.0),
            (5_200, "charts/episodic_length", 100)]  # fmt: skip
    (run_dir / "scalars.csv").write_text("step,name,value,wall_s\n" + "".join(f"{s},{n},{v},1.0\n" for s, n, v in rows))
    out = tmp_path / "x.curve.csv"
    result = run("model_curve.py", str(run_dir), "--offset", "1000", "--note", "a test run", "--out", str(out))
    assert result.returncode == 0, result.stderr
    lines = out.read_text().splitlines()
    assert lines[0].startswith("#") and lines[0].endswith("; a test run") and lines[1] == "step,avg_reward"
    assert lines[2:] == ["1000,0.4000", "6000,-0.5000"]  # (100 + 300) / 1000 steps; -50 / 100
    result = run("model_curve.py", str(tmp_path), "--out", str(tmp_path / "y.csv"))
    assert result.returncode == 1 and "scalars.csv: no such file" in result.stderr and not (tmp_path / "y.csv").exists()
