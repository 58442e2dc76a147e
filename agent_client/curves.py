"""Learning-curve PNG from a run's ``scalars.csv`` (like the paper's Fig. 5a/5b).

Drawn with OpenCV, which the project already needs, so no plotting library is
required::

    python -m agent_client.curves runs/ice-gap/scalars.csv docs/img/training-ice-gap.png \
        [TITLE] [--curve-csv models/ice-gap.curve.csv]
"""

from __future__ import annotations

import csv
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

__all__ = ["read_scalars", "plot_learning_curve", "export_curve", "x_extent"]

W, H = 900, 650  # [px] image
PANEL_H = 250  # [px] each panel's plot area
LEFT, RIGHT = 80, 30  # [px] margins
INK, GRID, RAW, AVG, EVAL = (30, 30, 30), (220, 220, 220), (200, 170, 140), (160, 60, 10), (20, 20, 200)  # BGR
FONT = cv2.FONT_HERSHEY_SIMPLEX


def read_scalars(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{name: (steps, values)}`` from a ``step,name,value,wall_s`` CSV."""
    series: dict[str, tuple[list[float], list[float]]] = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            s, v = series.setdefault(row["name"], ([], []))
            s.append(float(row["step"]))
            v.append(float(row["value"]))
    return {k: (np.array(s), np.array(v)) for k, (s, v) in series.items()}


def _nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    span = max(hi - lo, 1e-9)
    step = 10 ** np.floor(np.log10(span / n))
    for m in (1, 2, 5, 10):
        if span / (m * step) <= n:
            step *= m
            break
    return np.arange(np.ceil(lo / step) * step, hi + 1e-9, step)


def _panel(img: np.ndarray, top: int, x_max: float, y_lo: float, y_hi: float, title: str, ylabel: str) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    x0, x1, y0, y1 = LEFT, W - RIGHT, top, top + PANEL_H

    def to_px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        px = x0 + (x / x_max) * (x1 - x0)
        py = y1 - (np.clip(y, y_lo, y_hi) - y_lo) / (y_hi - y_lo) * (y1 - y0)
        return np.stack([px, py], axis=1).round().astype(np.int32)

    for t in _nice_ticks(y_lo, y_hi):
        (_, py), = to_px(np.array([0.0]), np.array([t]))
        cv2.line(img, (x0, int(py)), (x1, int(py)), GRID, 1)
        cv2.putText(img, f"{t:g}", (8, int(py) + 4), FONT, 0.4, INK, 1, cv2.LINE_AA)
    for t in _nice_ticks(0, x_max):
        (px, _), = to_px(np.array([t]), np.array([y_lo]))
        cv2.line(img, (int(px), y1), (int(px), y1 + 4), INK, 1)
        label = f"{t / 1000:g}k" if t else "0"
        cv2.putText(img, label, (int(px) - 10, y1 + 18), FONT, 0.4, INK, 1, cv2.LINE_AA)
    cv2.rectangle(img, (x0, y0), (x1, y1), INK, 1)
    cv2.putText(img, title, (x0, y0 - 10), FONT, 0.55, INK, 1, cv2.LINE_AA)
    cv2.putText(img, ylabel, (x0 + 6, y0 + 16), FONT, 0.4, INK, 1, cv2.LINE_AA)
    return to_px


def x_extent(series: dict[str, tuple[np.ndarray, np.ndarray]]) -> float:
    """The step axis' right end: the last step of any series drawn (training or evaluation), at least 1."""
    names = ("charts/mean_reward", "eval/gap_rmse_mean_m", "eval/gap_rmse_m")
    return max([1.0] + [float(series[n][0].max()) for n in names if n in series and len(series[n][0])])


def plot_learning_curve(scalars_csv: str | Path, out_png: str | Path, title: str = "", window: int = 20) -> None:
    """Average reward per step of each training episode vs training steps (top), and
    the test evaluation's gap RMSE to 55 m (bottom), as a PNG.

    Args:
        scalars_csv: the run's ``scalars.csv``.
        out_png: where to write the image.
        title: shown above the top panel.
        window: episodes in the moving average.
    """
    s = read_scalars(scalars_csv)
    img = np.full((H, W, 3), 255, np.uint8)
    steps, reward = s.get("charts/mean_reward", (np.zeros(0), np.zeros(0)))
    x_max = x_extent(s)  # an evaluation after the last training episode stays inside the plot
    to_px = _panel(img, 40, x_max, -1.0, 1.0, title or "training", f"average reward per step (episodes; moving average of {window})")
    if len(steps):
        for p in to_px(steps, reward):
            cv2.circle(img, (int(p[0]), int(p[1])), 1, RAW, -1, cv2.LINE_AA)
        k = min(window, len(reward))
        avg = np.convolve(reward, np.ones(k) / k, mode="valid")
        cv2.polylines(img, [to_px(steps[k - 1 :], avg)], False, AVG, 2, cv2.LINE_AA)
    e_steps, rmse = s.get("eval/gap_rmse_mean_m", (np.zeros(0), np.zeros(0)))
    w_steps, worst = s.get("eval/gap_rmse_m", (np.zeros(0), np.zeros(0)))
    hi = float(max(np.max(worst) if len(worst) else 10.0, 10.0))
    hi = min(hi, 100.0)
    to_px2 = _panel(img, 40 + PANEL_H + 60, x_max, 0.0, hi, "evaluation on the run's --eval-trajectories (greedy)", "gap RMSE to 55 m [m]: mean (blue), worst (red)")
    for xs, ys, color in ((e_steps, rmse, AVG), (w_steps, worst, EVAL)):
        if len(xs):
            pts = to_px2(xs, ys)
            cv2.polylines(img, [pts], False, color, 2, cv2.LINE_AA)
            for p in pts:
                cv2.circle(img, (int(p[0]), int(p[1])), 3, color, -1, cv2.LINE_AA)
    cv2.putText(img, "training steps (0.1 s each)", (W // 2 - 100, H - 8), FONT, 0.45, INK, 1, cv2.LINE_AA)
    Path(out_png).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out_png), img):
        raise OSError(f"could not write {out_png}")


def export_curve(scalars: str | Path, out_csv: str | Path, bin_steps: int = 5000, offset: int = 0) -> int:
    """Write ``step,avg_reward`` (reward per step of the training episodes that ended in
    each ``bin_steps`` bin; the shipped ``models/<name>.curve.csv`` files) and return the rows.

    ``offset`` shifts the steps, e.g. by the steps of the run a fine-tune started from.
    """
    s = read_scalars(scalars)
    steps, returns = s.get("charts/episodic_return", (np.zeros(0), np.zeros(0)))
    _, lengths = s.get("charts/episodic_length", (np.zeros(0), np.zeros(0)))
    rows = []
    for hi in range(bin_steps, int(steps.max()) + bin_steps if len(steps) else 0, bin_steps):
        sel = (steps > hi - bin_steps) & (steps <= hi)
        if lengths[sel].sum() > 0:
            rows.append((hi + offset, returns[sel].sum() / lengths[sel].sum()))
    with open(out_csv, "w", newline="") as f:
        f.write(f"# average reward per step of training episodes, in {bin_steps:,}-step bins; from the run's scalars.csv\n")
        f.write("step,avg_reward\n")
        f.writelines(f"{st},{v:.4f}\n" for st, v in rows)
    return len(rows)


if __name__ == "__main__":
    args = sys.argv[1:]
    curve_csv = None
    if "--curve-csv" in args:
        i = args.index("--curve-csv")
        curve_csv = args[i + 1] if i + 1 < len(args) else sys.exit("--curve-csv needs a path")
        del args[i : i + 2]
    if len(args) not in (2, 3):
        sys.exit("usage: python -m agent_client.curves SCALARS.csv OUT.png [TITLE] [--curve-csv OUT.curve.csv]")
    plot_learning_curve(args[0], args[1], args[2] if len(args) == 3 else "")
    if curve_csv is not None:
        export_curve(args[0], curve_csv)
