"""vacc gates' figures over runs: a run without a comfort figure (it ended before the settle,
e.g. a collision in the first 15 s) fails the check and says so, never a traceback."""

from __future__ import annotations

import math

from vacc.gates import _comfort_checks, _measures
from vacc.random_suite import random_table

BOUNDS = {"max_jerk_rms_mps3": 1.0, "max_iso_jerk_share": 0.01}


def _run(jerk: float | None, iso: float | None, rmse: float = 3.0) -> dict:
    return {"gap_rmse_55m_m": rmse, "jerk_rms_mps3": jerk, "iso_jerk_window_share": iso, "fuel_g_per_mi": 66.0,
            "collisions": 0, "gap_min_m": 20.0}  # fmt: skip


def test_comfort_passes_on_figures_within_bounds_and_fails_where_a_run_has_none():
    good = _comfort_checks(BOUNDS, [_run(0.5, 0.0), _run(0.7, 0.002)])
    assert [c.passed for c in good] == [True, True] and good[0].figure == 0.6 and not good[0].detail
    short = _comfort_checks(BOUNDS, [_run(0.5, 0.0), _run(None, None)])
    assert [c.passed for c in short] == [False, False] and all(math.isnan(c.figure) for c in short)
    assert short[0].detail == "1 run(s) ended before the settle: no figure"


def test_measures_and_the_random_table_carry_a_missing_figure_as_nan():
    runs = [_run(0.5, 0.0), _run(None, None, 40.0)]
    iso = {m.what: m.figure for m in _measures("random", runs, [_run(0.4, 0.0)], "fuel_g_per_mi")}
    assert any(math.isnan(x) for x in iso.values()) and 1.0 in iso.values()  # the energy ratio 66/66
    line = random_table({"m": runs}, "ice")[0]
    assert "jerk RMS nan m/s^3" in line and "worst ISO jerk share nan %" in line and "worst 40.00 m" in line
