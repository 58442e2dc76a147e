"""vacc.stats on hand-computed data: the interquartile mean and the stratified bootstrap."""

from __future__ import annotations

import numpy as np
import pytest

from vacc.stats import bootstrap_ci, iqm, mean


@pytest.mark.parametrize(
    ("scores", "expected"),
    [
        ([1, 2, 3], 2.0),  # n // 4 = 0: nothing dropped
        ([1, 2, 3, 100], 2.5),  # one dropped at each end: (2 + 3) / 2
        ([8, 1, 7, 2, 6, 3, 5, 4], 4.5),  # unsorted; two dropped at each end: (3 + 4 + 5 + 6) / 4
        ([1, 2, 3, 4, 5, 6, 7, 8, 9, 1000], 5.5),  # ten seeds, one outlier: (3 + ... + 8) / 6
    ],
)
def test_iqm_is_the_mean_of_the_middle_half(scores, expected):
    assert float(iqm(np.array(scores))) == pytest.approx(expected)


def test_iqm_over_the_last_axis_and_of_nothing():
    rows = np.array([[1, 2, 3, 100], [4, 0, 0, 4]])
    assert iqm(rows) == pytest.approx([2.5, 2.0])
    assert mean(rows) == pytest.approx([26.5, 2.0])
    with pytest.raises(ValueError, match="no scores"):
        iqm(np.array([]))


def test_one_score_and_equal_scores_give_a_zero_width_interval():
    assert tuple(bootstrap_ci([[3.0]])) == (3.0, 3.0, 3.0, 1)
    e = bootstrap_ci([[2.0, 2.0, 2.0]], iqm)
    assert (e.value, e.low, e.high, e.n) == (2.0, 2.0, 2.0, 3)


def test_resampling_is_stratified_by_task():
    """Task A always scores 1, task B 3: every resample keeps two of each, so the pooled
    mean is 2 in every resample (unstratified resampling would spread from 1 to 3)."""
    e = bootstrap_ci([[1.0, 1.0], [3.0, 3.0]])
    assert (e.value, e.low, e.high, e.n) == (2.0, 2.0, 2.0, 4)
    assert bootstrap_ci([[1.0, 2.0], [3.0, 10.0]], iqm).value == pytest.approx(2.5)  # iqm of 1, 2, 3, 10


def test_percentile_interval_of_two_scores():
    """Resampling (0, 1) gives means 0, 0.5, 1 with chances 1/4, 1/2, 1/4: the 2.5th
    percentile is 0 and the 97.5th 1; the central 40 % (30th to 70th) is 0.5 only."""
    e = bootstrap_ci([[0.0, 1.0]])
    assert (e.value, e.low, e.high) == (0.5, 0.0, 1.0)
    e = bootstrap_ci([[0.0, 1.0]], confidence=0.4)
    assert (e.low, e.high) == (0.5, 0.5)


def test_seeded_and_deterministic():
    data = [[0.3, 1.7, 2.2, 5.0], [4.0, 4.5, 9.0]]
    assert bootstrap_ci(data) == bootstrap_ci(data)
    a = bootstrap_ci(data, rng=np.random.default_rng(1))
    b = bootstrap_ci(data, rng=np.random.default_rng(2))
    assert a.value == b.value and (a.low, a.high) != (b.low, b.high)
    assert a.low <= a.value <= a.high


@pytest.mark.parametrize(
    ("tasks", "kwargs", "message"),
    [
        ([], {}, "at least one score"),
        ([[1.0], []], {}, "at least one score"),
        ([[1.0, float("nan")]], {}, "finite"),
        ([[1.0]], {"confidence": 1.0}, "confidence"),
        ([[1.0]], {"n_resamples": 0}, "n_resamples"),
    ],
)
def test_bad_input_raises(tasks, kwargs, message):
    with pytest.raises(ValueError, match=message):
        bootstrap_ci(tasks, **kwargs)
