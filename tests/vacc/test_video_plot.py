"""`vacc video` (a logged run replayed against a fresh server, every row checked) and `vacc plot`."""

from __future__ import annotations

import subprocess
import sys

import pytest

cv2 = pytest.importorskip("cv2")


def vacc(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "vacc", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def run5(tmp_path_factory):
    """A 5 s ACC run on test-1 with its card."""
    folder = tmp_path_factory.mktemp("video")
    log = folder / "acc.csv"
    result = vacc("drive", "--controller", "acc", "--trajectory", "test-1", "--duration", "5", "--log", str(log), "--quiet")
    assert result.returncode == 0, result.stderr
    return log


def _rows(log) -> int:
    return len(log.read_text().splitlines()) - 1


def test_video_has_one_frame_per_row(run5, tmp_path):
    out = tmp_path / "run.mp4"
    result = vacc("video", str(run5), "--out", str(out), "--network-view")
    assert result.returncode == 0, result.stderr
    assert f"{_rows(run5)} rows replayed, each as logged" in result.stdout
    assert "h264_v4l2m2m" not in result.stderr  # the codec probe stays quiet
    cap = cv2.VideoCapture(str(out))
    frames, shape = 0, None
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames, shape = frames + 1, frame.shape
    cap.release()
    assert frames == _rows(run5) == 51
    assert shape[1] > 400 + 2 * 150  # the camera and, beside it, the network input at twice its size


def test_gif_video(run5, tmp_path):
    from PIL import Image

    out = tmp_path / "run.gif"
    assert vacc("video", str(run5), "--out", str(out)).returncode == 0
    with Image.open(out) as gif:
        assert gif.n_frames == _rows(run5)


def test_a_tampered_log_is_refused_naming_the_row(run5, tmp_path):
    log = tmp_path / "acc.csv"
    lines = run5.read_text().splitlines()
    fields = lines[21].split(",")
    fields[2] = repr(float(fields[2]) + 0.001)  # v_host of data row 21
    lines[21] = ",".join(fields)
    log.write_text("\n".join(lines) + "\n")
    (tmp_path / "acc.card.json").write_text(run5.with_name("acc.card.json").read_text())
    out = tmp_path / "bad.mp4"
    result = vacc("video", str(log), "--out", str(out))
    assert result.returncode == 1
    assert f"{log}:22: row 21, column 'v_host'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not out.exists()


def test_a_log_without_its_card_is_refused(run5, tmp_path):
    log = tmp_path / "bare.csv"
    log.write_text(run5.read_text())
    result = vacc("video", str(log), "--out", str(tmp_path / "x.mp4"))
    assert result.returncode == 1 and "no run card beside it" in result.stderr


def test_plot_overlays_runs_with_targets_and_iso_limits(run5, tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from energy.comfort import ISO_DECEL_LIMIT_MPS2, ISO_JERK_LIMIT_MPS3
    from protocol.constants import MIN_GAP
    from vacc import plot

    runs = [plot.load_run(run5), plot.load_run(run5)._replace(label="again")]
    assert runs[0].vehicle == "corolla" and runs[0].label == "acc (acc)"
    monkeypatch.setattr(plt, "close", lambda fig: None)
    fig = plot.plot_logs(runs, tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 10_000
    speed, gap, accel, jerk, energy = fig.axes
    assert [t.get_text() for t in speed.get_legend().get_texts()][:2] == ["acc (acc)", "set speed"]
    hlines = lambda ax: sorted(round(line.get_ydata()[0], 6) for line in ax.lines if len(set(line.get_ydata())) == 1 and len(line.get_ydata()) == 2)  # noqa: E731
    assert 55.0 in hlines(gap) and MIN_GAP in hlines(gap)
    assert -ISO_DECEL_LIMIT_MPS2 in hlines(accel) and hlines(jerk) == [-ISO_JERK_LIMIT_MPS3, ISO_JERK_LIMIT_MPS3]
    assert energy.get_ylabel() == "fuel used [g]"
    used = [line.get_ydata() for line in energy.lines]
    assert len(used) == 2 and used[0][-1] > 0 and (used[0] == used[1]).all()
    assert vacc("plot", str(run5), "--out", str(tmp_path / "p.svg")).returncode == 1
