"""The platoon figures are written and read the platoon right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vacc.platoon_figures import plot_amplification, plot_time_space, positions


def test_positions_stack_gaps_and_car_lengths() -> None:
    t = np.arange(0.0, 10.0, 0.1)
    v = np.full_like(t, 10.0)
    gaps = np.full((2, t.size), 20.0)
    x = positions(t, v, gaps, car_length=4.5)
    assert x[0, -1] == pytest.approx(10.0 * t[-1])
    assert x[:, 0] == pytest.approx([0.0, -24.5, -49.0])


def test_both_figures_are_written(tmp_path: Path) -> None:
    t = np.arange(0.0, 100.0, 0.1)
    v = np.stack([10 + np.sin(0.3 * t * (1 + 0.1 * i)) * (1 + 0.2 * i) for i in range(4)])
    x = positions(t, v[0], np.full((3, t.size), 15.0), 4.5)
    for w in (plot_time_space(tmp_path, t, x, v), plot_amplification(tmp_path, t, v)):
        assert w.empty is None
        assert (tmp_path / f"{w.name}.png").stat().st_size > 1000
        assert (tmp_path / f"{w.name}.pdf").exists()
