"""`vacc evaluate --suite random`: held-out random episodes; a road the server would refuse
is refused before anything is driven."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from energy import evaluate_run
from vacc.random_suite import driver_name, random_jobs, random_table


def vacc(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vacc", "evaluate", "--suite", "random", *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("traffic", ["-1", "11"])
def test_a_traffic_outside_the_servers_range_is_refused_in_one_line(tmp_path, traffic):
    out = tmp_path / "out"
    result = vacc("--traffic", traffic, "--out", str(out), timeout=60)
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert "'--traffic'" in last and f"{traffic} is not in the range 0<=x<=10" in last
    assert not out.exists()  # refused before anything was written


@pytest.mark.parametrize(("sun", "why"), [("0.01,0.5", "must have 0.05 <= LOW <= HIGH <= 1.5 rad"), ("low", "is not LOW,HIGH in radians"), ("0.7,0.4", "got 0.7,0.4")])
def test_a_sun_outside_the_servers_range_is_refused_in_one_line(tmp_path, sun, why):
    out = tmp_path / "out"
    result = vacc("--sun-elevation", sun, "--out", str(out), timeout=60)
    assert result.returncode == 2
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("Error: Invalid value for '--sun-elevation': ") and why in last
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--methods", "acc,human"], "--methods"),  # the suite has no human driver
        (["--methods", "ddqn-eco", "--models", "no-such-models"], "--methods"),
        (["--lead-scenarios", "stopped"], "--lead-scenarios"),  # only the safety suite drives them
        (["--seeds", "107-100"], "--seeds"),
    ],
)
def test_bad_options_fail_naming_the_option(tmp_path, args, option):
    result = vacc(*args, "--out", str(tmp_path / "o"), timeout=60)
    assert result.returncode == 2 and option in result.stderr, result.stderr
    assert not (tmp_path / "o").exists()


def test_the_jobs_are_the_acc_and_each_model_on_each_seed(tmp_path):
    jobs = random_jobs(tmp_path, {"ice-gap": "m/ice-gap.pt", "ice-eco": "m/ice-eco.pt"}, "ice", [100, 101])
    assert [(driver_name(j), j.seed) for j in jobs] == [(d, s) for d in ("acc", "ice-eco", "ice-gap") for s in (100, 101)]
    assert {j.trajectory for j in jobs} == {"random"} and {j.scenario for j in jobs} == {"ice"}
    assert jobs[2].method == "ddqn" and jobs[2].checkpoint == "m/ice-eco.pt"
    assert jobs[0].log == str(tmp_path / "logs" / "acc-seed100.csv") and jobs[0].duration is None
    assert [driver_name(j) for j in random_jobs(tmp_path, {"ice-gap": "m/ice-gap.pt"}, "ice", [1], acc=False)] == ["ice-gap"]


def test_the_table_gives_mean_and_worst_per_driver():
    runs = [{"gap_rmse_55m_m": x, "fuel_g_per_mi": 100.0, "jerk_rms_mps3": 0.5, "iso_jerk_window_share": 0.01, "collisions": 0, "gap_min_m": 30.0}
            for x in (2.0, 4.0)]  # fmt: skip
    assert random_table({"acc": runs}, "ice") == [
        "acc: gap RMSE mean 3.00 m, worst 4.00 m; energy 100.0 g/mi; jerk RMS 0.50 m/s^3, worst ISO jerk share 1.0 %; collisions 0, min gap 30.0 m",
        "    RMSE per seed: 2.00 4.00",
    ]


def test_the_acc_on_two_short_random_episodes(tmp_path):
    out = tmp_path / "out"
    result = vacc("--methods", "acc", "--seeds", "100-101", "--duration", "2", "--jobs", "2", "--settle", "0.5", "--out", str(out))
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary) == ["acc"] and [r["seed"] for r in summary["acc"]] == [100, 101]
    for run in summary["acc"]:
        assert run["traffic"] == 3 and run["sun_elevation"] == [0.35, 1.2]
        m = evaluate_run(out / "logs" / f"acc-seed{run['seed']}.csv", "corolla", settle_s=0.5)
        assert run["gap_rmse_55m_m"] == m["gap_rmse_55m_m"] and run["fuel_g_per_mi"] == m["fuel_g_per_mi"]
        assert run["jerk_rms_mps3"] == m["jerk_rms_mps3"]
    table = (out / "random.md").read_text()
    assert table.startswith("acc: gap RMSE mean ") and table in result.stdout
    assert sorted(p.name for p in (out / "logs").iterdir()) == ["acc-seed100.csv", "acc-seed101.csv"]


def test_the_default_seeds_are_the_held_out_ones():
    from vacc.evaluate import _seed_list

    assert _seed_list(None, None, "random") == list(range(100, 108))


def test_any_checkpoint_drives_beside_the_acc_under_its_own_name(tmp_path):
    """--model NAME=PATH: a run folder's latest.pt drives as NAME (its logs and its row),
    beside the ACC; a NAME that a model in --models also has is refused in one line."""
    from agent_client.rl.checkpoint import save_policy
    from agent_client.rl.config import Config
    from agent_client.rl.network import QNetwork

    (tmp_path / "run").mkdir()
    save_policy(QNetwork(), Config(), tmp_path / "run" / "latest.pt")
    out = tmp_path / "out"
    result = vacc("--methods", "acc", "--model", f"mine={tmp_path / 'run' / 'latest.pt'}", "--seeds", "100", "--duration", "2", "--settle", "0.5",
                  "--jobs", "2", "--out", str(out))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert list(json.loads((out / "summary.json").read_text())) == ["acc", "mine"]
    assert sorted(p.name for p in (out / "logs").iterdir()) == ["acc-seed100.csv", "mine-seed100.csv"]
    (tmp_path / "models").mkdir()
    save_policy(QNetwork(), Config(), tmp_path / "models" / "ice-gap.pt")
    result = vacc("--models", str(tmp_path / "models"), "--model", f"ice-gap={tmp_path / 'run' / 'latest.pt'}", "--out", str(tmp_path / "o"), timeout=60)
    assert result.returncode == 2 and "--model" in result.stderr and "another NAME" in result.stderr, result.stderr
    assert not (tmp_path / "o").exists()
