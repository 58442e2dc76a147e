"""vacc.figures on written logs: every figure as PNG and PDF, a message when there is nothing to plot."""

from __future__ import annotations

import click
import numpy as np
import pytest

from energy import evaluate_run, read_run_log
from vacc import figures
from vacc.runs import Run, log_path

METHODS = ["lead", "acc", "human"]
LABELS = {"lead": "Lead", "acc": "ACC", "human": "HDM"}
TRAJS = [f"test-{i}" for i in range(1, 5)]


def _write_log(path, wobble: float) -> None:
    """30 s at 0.1 s: speed 20 m/s plus a sine of amplitude ``wobble`` [m/s], gap 50 m plus its integral."""
    t = np.arange(301) / 10
    v = 20.0 + wobble * np.sin(t)
    a = wobble * np.cos(t)
    gap = 50.0 - wobble * (1 - np.cos(t))
    with path.open("w") as f:
        f.write("t,frame,v_host,v_lead,gap,accel,force,collision,a_lead\n")
        for k in range(t.size):
            f.write(f"{t[k]:.1f},{k},{v[k]},20.0,{gap[k]},{a[k]},0.0,0,0.0\n")


def _runs(out, seeds=(0, 1)) -> list[Run]:
    (out / "logs").mkdir(parents=True, exist_ok=True)
    runs = []
    for i, m in enumerate(METHODS):
        for j, traj in enumerate(TRAJS):
            for seed in seeds:
                path = log_path(out, m, traj, seed)
                _write_log(path, 0.5 + i + 0.1 * j + 0.05 * (seed or 0))
                log = read_run_log(path)
                runs.append(Run(m, traj, seed, log, evaluate_run(log, "corolla", settle_s=1.0)))
    return runs


def _written(out, w):
    for ext in ("png", "pdf"):
        assert (out / f"{w.name}.{ext}").stat().st_size > 1000, (w.name, ext)


@pytest.mark.slow  # over ~5 s alone
def test_every_figure_over_seeds(tmp_path):
    runs = _runs(tmp_path)
    written = [
        *figures.plot_runs(tmp_path, runs, LABELS, "ice"),
        figures.plot_comfort(tmp_path, runs, LABELS, "ice", settle=1.0),
        figures.plot_emissions(tmp_path, runs, LABELS, "ice"),
        figures.plot_emissions(tmp_path, [r._replace(metrics=evaluate_run(r.log, "leaf")) for r in runs], LABELS, "ev"),
        figures.plot_headway(tmp_path, runs, LABELS, "ice"),
        figures.plot_pareto(tmp_path, "ice", METHODS, LABELS, "corolla", 1.0, seeds=[0, 1], runs=runs),
    ]
    assert [w.name for w in written] == ["fig_gap", "fig_speed", "fig_comfort", "fig_emissions", "fig_energy", "fig_headway", "fig_pareto"]
    for w in written:
        assert w.empty is None, w
        _written(tmp_path, w)


def test_pareto_keeps_its_signature_and_reads_single_seed_logs(tmp_path):
    _runs(tmp_path, seeds=(None,))
    w = figures.plot_pareto(tmp_path, "ice", METHODS, LABELS, "corolla")
    assert w.empty is None
    _written(tmp_path, w)


def test_nothing_to_plot_is_said_in_words(tmp_path):
    for w in [
        *figures.plot_runs(tmp_path, [], LABELS, "ice"),
        figures.plot_comfort(tmp_path, [], LABELS, "ice"),
        figures.plot_emissions(tmp_path, [], LABELS, "ice"),
        figures.plot_headway(tmp_path, [], LABELS, "ice"),
        figures.plot_pareto(tmp_path, "ice", ["acc"], LABELS, "corolla", runs=[]),
        figures.plot_training(tmp_path, tmp_path / "no-models", "ice"),
    ]:
        assert w.empty, w.name
        _written(tmp_path, w)
    lead_only = [r for r in _runs(tmp_path) if r.method == "lead"]
    assert figures.plot_runs(tmp_path, lead_only, LABELS, "ice")[0].empty == "no follower runs to plot (only the lead, or no logs)"
    assert "settle" in (figures.plot_comfort(tmp_path, lead_only, LABELS, "ice", settle=60.0).empty or "")


def test_smoothing_is_debiased():
    assert figures.smooth([1.0, 1.0, 1.0]) == pytest.approx([1.0, 1.0, 1.0])
    # w = 0.5: s0 = 0.5 * 0 / (1 - 0.5) = 0; s1 = (0.5 * 0 + 0.5 * 1) / (1 - 0.25) = 2/3
    assert figures.smooth([0.0, 1.0], 0.5) == pytest.approx([0.0, 2.0 / 3.0])
    with pytest.raises(ValueError, match="smoothing"):
        figures.smooth([1.0], 1.0)


@pytest.mark.slow  # over ~5 s alone
def test_training_curves_late_start_and_bad_files(tmp_path):
    assert not figures.late_start([5000, 10000, 15000])
    assert figures.late_start([145507, 150507, 155507])
    models = tmp_path / "models"
    models.mkdir()
    (models / "ice-gap.curve.csv").write_text("# a comment\nstep,avg_reward\n" + "".join(f"{5000 * k},{0.1 * k}\n" for k in range(1, 20)))
    (models / "ice-force.curve.csv").write_text("step,avg_reward\n" + "".join(f"{145507 + 5000 * k},{0.5}\n" for k in range(10)))
    w = figures.plot_training(tmp_path, models, "ice")
    assert w == figures.Written("fig_training")
    _written(tmp_path, w)
    (models / "ice-gap.curve.csv").write_text("step,avg_reward\n")
    (models / "ice-force.curve.csv").write_text("step,avg_reward\n")
    assert "No training curves" in (figures.plot_training(tmp_path, models, "ice").empty or "")
    (models / "ice-gap.curve.csv").write_text("steps,reward\n1,2\n")
    with pytest.raises(click.ClickException, match="expected columns step,avg_reward"):
        figures.plot_training(tmp_path, models, "ice")
