"""The figure flaws of issue 56, each checked on the figure's own data (limits, label text), not its pixels."""

from __future__ import annotations

import numpy as np
import pytest

from energy import evaluate_run, read_run_log
from vacc import figures
from vacc.runs import Run, log_path

LABELS = {"acc": "ACC", "ddqn-force": "Force-based DDQN", "lead": "Lead"}


@pytest.fixture
def drawn(monkeypatch):
    """Every figure the plot functions save, by name (its data kept after it is closed)."""
    saved = {}
    real = figures._save

    def keep(fig, out, name):
        saved[name] = fig
        return real(fig, out, name)

    monkeypatch.setattr(figures, "_save", keep)
    return saved


def _log(path, v, a, gap) -> None:
    t = np.arange(v.size) / 10
    with path.open("w") as f:
        f.write("t,frame,v_host,v_lead,gap,accel,force,collision,a_lead\n")
        for k in range(t.size):
            f.write(f"{t[k]:.1f},{k},{float(v[k])!r},20.0,{float(gap[k])!r},{float(a[k])!r},0.0,0,0.0\n")


def _runs(out) -> list[Run]:
    """An ACC that rides smoothly at ~2.5 s headway, and a force policy that holds 0 m/s^2 most of
    the time (its acceleration quartiles coincide), each on test-1 and test-2."""
    (out / "logs").mkdir(parents=True, exist_ok=True)
    runs = []
    n = 301
    for m in ("acc", "ddqn-force"):
        for traj in ("test-1", "test-2"):
            if m == "acc":
                a = 0.3 * np.sin(np.arange(n) / 10)
            else:
                a = np.where(np.arange(n) % 20 == 0, 1.5, 0.0)
            v = 20.0 + np.cumsum(a) * 0.01
            gap = 2.5 * v
            path = log_path(out, m, traj)
            _log(path, v, a, gap)
            log = read_run_log(path)
            runs.append(Run(m, traj, None, log, evaluate_run(log, "corolla", settle_s=1.0)))
    return runs


def test_emission_labels_stand_upright_and_never_overlap(tmp_path, drawn):
    runs = _runs(tmp_path)
    figures.plot_emissions(tmp_path, runs, LABELS, "ice")
    fig = drawn["fig_emissions"]
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    for ax in fig.axes:
        labels = [t for t in ax.texts if t.get_text()]
        assert labels and all(t.get_rotation() == 90 for t in labels)
        boxes = [t.get_window_extent(renderer) for t in labels]
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                assert not boxes[i].overlaps(boxes[j]), (ax.get_ylabel(), labels[i].get_text(), labels[j].get_text())


def test_energy_labels_are_never_in_exponent_form(tmp_path, drawn):
    runs = [r._replace(metrics=evaluate_run(r.log, "leaf")) for r in _runs(tmp_path)]
    figures.plot_emissions(tmp_path, runs, LABELS, "ev")
    texts = [t.get_text() for t in drawn["fig_energy"].axes[0].texts]
    assert texts and not any("e+" in t or "e-" in t for t in texts), texts
    assert figures.value_label(1513.2) == "1513" and figures.value_label(0.01094) == "0.0109" and figures.value_label(1.2e-5) == "0.000012"


def test_headway_axis_ends_near_the_data(tmp_path, drawn):
    figures.plot_headway(tmp_path, _runs(tmp_path), LABELS, "ice")
    ax = drawn["fig_headway"].axes[0]
    right = ax.get_xlim()[1]
    assert right < figures.HEADWAY_MAX_S  # the data stop near 2.5 s; the axis no longer runs to 6 s
    last = max(float(np.max(np.where(st.get_data().values > 0, st.get_data().edges[1:], 0.0))) for st in ax.patches)
    assert last <= right <= last + 3 * figures.HEADWAY_BIN_S + 1.0


def test_a_collapsed_comfort_box_is_labelled_and_shows_its_values(tmp_path, drawn):
    figures.plot_comfort(tmp_path, _runs(tmp_path), LABELS, "ice", settle=1.0)
    ax = drawn["fig_comfort"].axes[0]
    notes = {t.get_gid(): t.get_text() for t in ax.texts}
    assert "collapsed-ddqn-force" in notes and notes["collapsed-ddqn-force"].startswith("95 % at 0"), notes
    assert "collapsed-acc" not in notes
    strips = {c.get_gid(): c.get_offsets() for c in ax.collections if c.get_gid()}
    assert np.ptp(strips["strip-ddqn-force"][:, 1]) > 1.0  # the spikes are drawn, not only the line at 0


def test_titles_say_the_runs_were_cut_short(tmp_path, drawn):
    runs = _runs(tmp_path)
    figures.plot_runs(tmp_path, runs, LABELS, "ice", duration=30.0)
    figures.plot_comfort(tmp_path, runs, LABELS, "ice", settle=1.0, duration=30.0)
    figures.plot_emissions(tmp_path, runs, LABELS, "ice", duration=30.0)
    figures.plot_headway(tmp_path, runs, LABELS, "ice", duration=30.0)
    figures.plot_pareto(tmp_path, "ice", ["acc", "ddqn-force"], LABELS, "corolla", 1.0, runs=runs, duration=30.0)
    for name, fig in drawn.items():
        titles = [fig._suptitle.get_text() if fig._suptitle else ""] + [ax.get_title() for ax in fig.axes]
        assert any("--duration 30" in t for t in titles), name
    drawn.clear()
    figures.plot_headway(tmp_path, runs, LABELS, "ice")
    assert "--duration" not in drawn["fig_headway"].axes[0].get_title()


def test_the_learning_curve_keeps_the_evaluation_inside_the_plot(tmp_path):
    from agent_client import curves

    scalars = tmp_path / "scalars.csv"
    rows = ["step,name,value,wall_s"] + [f"{s},charts/mean_reward,0.1,0" for s in (1000, 2000, 3000)]
    rows += [f"{s},eval/gap_rmse_mean_m,5.0,0" for s in (2500, 5000)] + [f"{s},eval/gap_rmse_m,8.0,0" for s in (2500, 5000)]
    scalars.write_text("\n".join(rows) + "\n")
    series = curves.read_scalars(scalars)
    assert curves.x_extent(series) == 5000.0  # the evaluation at 5000 past the last episode at 3000
    curves.plot_learning_curve(scalars, tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 1000
