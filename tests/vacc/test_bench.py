"""`vacc bench --quick --json` reports every figure. Timings are never asserted."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def _positive_numbers(node, path=""):
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _positive_numbers(value, f"{path}/{key}")
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path, node


# --smoke: every row at its smallest (its figures mean little; the sizes are the only
# difference from --quick and the full bench, checked below). A loaded host is slow.
@pytest.mark.timeout(600)
def test_smoke_bench_reports_every_figure(tmp_path):
    out = tmp_path / "bench.json"
    result = subprocess.run(
        [sys.executable, "-m", "vacc", "bench", "--smoke", "--json", str(out)],
        capture_output=True, text=True, timeout=540,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    data = json.loads(out.read_text())
    assert {"date", "cpu", "cores", "versions"} <= set(data["header"]) and data["header"]["size"] == "smoke"
    figures = data["figures"]
    for key in ("udp_echo", "lockstep_no_image", "lockstep_rgb400", "lockstep_gray200", "lockstep_key", "flood_rtt", "platoon_lockstep", "render_rgb400", "agent_env", "decision_latency", "replay_sample", "update_cost", "ddqn_training", "ddqn_training_parallel", "replay", "training_peak_rss"):
        assert key in figures, key
    # each training row measures the schedule its label names (the serial row once ran the parallel one)
    assert (figures["ddqn_training"]["schedule"], figures["ddqn_training_parallel"]["schedule"]) == ("serial", "parallel")
    assert 0 < figures["decision_latency"]["forward_ms"] < 2 * figures["decision_latency"]["ms"]["median"]  # a part of the decision, measured apart
    eco = figures["eco_decision_latency"]  # the shipped eco model's whole path
    assert eco["model"] == "ice-eco.pt" and 0 < eco["forward_ms"] < 2 * eco["ms"]["median"]
    assert "the shipped ice-eco.pt" in result.stdout
    gru = figures["gru_decision_latency"]  # the recurrent trunk's decision beside the stack's, in the same run
    assert 0 < gru["forward_ms"] < 2 * gru["ms"]["median"] and gru["x_stack"] > 0 and "GRU trunk, 2-frame stack" in result.stdout
    assert figures["lockstep_rgb400"]["image_bytes"] == 400 * 400 * 3
    assert figures["lockstep_gray200"]["image_bytes"] == 200 * 200
    # The peer is optional (the bench extra); when absent it says how to install it.
    for name in ("highway_env_peer", "sb3_dqn_peer", "sb3_replay_peer", "sb3_decision_peer"):
        peer = figures[name]
        assert "error" not in peer or "vacc[bench]" in peer["error"], name
    assert "error" not in figures["training_peak_rss"]
    assert figures["replay"]["bytes_per_transition"] < 1.1 * (105 * 150 + 64)
    values = dict(_positive_numbers(figures))
    assert len(values) > 20
    for path, value in values.items():
        assert value > 0 or path == "/lockstep_no_image/image_bytes", path
    assert "lockstep, no image" in result.stdout
    assert figures["lockstep_key"]["keyed"]["reps"] == figures["lockstep_key"]["plain"]["reps"]


def test_the_sizes_grow_from_smoke_to_full_in_every_count():
    from vacc.bench import SIZES

    smoke, quick, full = SIZES["smoke"], SIZES["quick"], SIZES["full"]
    for field in smoke._fields[1:]:
        assert 0 < getattr(smoke, field) <= getattr(quick, field) <= getattr(full, field), field


def test_gpu_bench_rows_on_the_cpu():
    """The lent-machine learner bench runs without CUDA too, one row per batch size;
    each update row's sampling and step are parts of its rate."""
    from agent_client.bench.gpu import forward_latency, update_wall

    rows = update_wall("cpu", 1, batches=(4, 8), repeats=2)
    assert [r["batch"] for r in rows] == [4, 8]
    for r in rows:
        assert r["device"] == "cpu" and r["update_s"] > 0 and r["sample_s"] > 0
        assert abs(r["samples_per_s"] - r["batch"] / (r["update_s"] + r["sample_s"])) < 1e-9
    f = forward_latency("cpu", 1, repeats=3)
    assert 0 < f["median_s"] <= f["p90_s"]


@pytest.mark.slow  # over ~5 s alone
def test_scaling_bench_has_a_window_only_after_every_actor_delivered_often():
    """Two actors of the multi-server trainer (real servers): a run of a few deliveries per
    actor reports no window rate (it once counted steps taken before the window opened, and
    printed 48,000 steps/s at K = 15); a longer one does, inside the whole run's bounds."""
    from agent_client.bench.distributed import MIN_DELIVERIES, acting_rate
    from agent_client.rl.config import Config

    short = acting_rate(2, 2 * Config.actor_batch * 2)
    assert "window_steps_per_s" not in short and short["window"].startswith("none: 2.0 deliveries per actor")
    long = acting_rate(2, 2 * Config.actor_batch * MIN_DELIVERIES)
    assert "window" not in long and long["window_steps_per_s"] > 0 and long["cores_used"] > 0
    assert long["run_steps_per_s"] <= long["env_steps_per_s"]  # the whole run includes the start-up


def test_a_model_the_bench_cannot_load_is_a_row_that_says_why(tmp_path):
    from agent_client.bench.ddqn import model_decision_latency

    bad = tmp_path / "ice-eco.pt"
    bad.write_bytes(b"not a checkpoint")
    row = model_decision_latency(bad, repeats=1)
    assert set(row) == {"error"} and "ice-eco.pt" in row["error"]
    assert set(model_decision_latency(tmp_path / "absent.pt", repeats=1)) == {"error"}
