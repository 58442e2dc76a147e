"""Statistics over seeds: means and rliable's interquartile mean with bootstrap CIs.

Agarwal et al. (2021, "Deep RL at the edge of the statistical precipice", the
``rliable`` library) recommend the interquartile mean (IQM) and stratified bootstrap
confidence intervals over few runs. Both are written out here with numpy:

* :func:`iqm` is ``scipy.stats.trim_mean(x, 0.25)`` on the pooled scores: sort,
  drop ``floor(n / 4)`` scores at each end, average the rest (rliable's
  ``aggregate_iqm``).
* :func:`bootstrap_ci` resamples runs with replacement *within* each task (here: each
  trajectory), pools the resample and applies the statistic, ``n_resamples`` times;
  the interval is the percentile interval (rliable's ``StratifiedBootstrap``,
  ``method="percentile"``). With one task it is the ordinary percentile bootstrap.

The generator is seeded (:data:`BOOTSTRAP_SEED` by default), so a table is the same
on every machine and every run.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["BOOTSTRAP_SEED", "N_RESAMPLES", "CONFIDENCE", "Estimate", "mean", "iqm", "bootstrap_ci"]

BOOTSTRAP_SEED = 0  # [-] fixed, so that a table is reproducible
N_RESAMPLES = 2000  # [-] bootstrap resamples per interval
CONFIDENCE = 0.95  # [-] coverage of every interval

Statistic = Callable[[np.ndarray], np.ndarray]
"""Maps scores ``[R, N]`` (R resamples of N pooled scores) to ``[R]``."""


class Estimate(NamedTuple):
    """A point estimate and its bootstrap confidence interval, in the scores' unit."""

    value: float
    low: float
    high: float
    n: int
    """Scores it is over."""


def mean(x: np.ndarray) -> np.ndarray:
    """Mean over the last axis."""
    return np.asarray(np.mean(x, axis=-1))


def iqm(x: np.ndarray) -> np.ndarray:
    """Interquartile mean over the last axis: the mean of the middle scores after
    dropping ``floor(n / 4)`` at each end (``scipy.stats.trim_mean(x, 0.25)``).

    Raises:
        ValueError: no scores.
    """
    x = np.sort(np.asarray(x, dtype=float), axis=-1)
    n = x.shape[-1]
    if n == 0:
        raise ValueError("the interquartile mean of no scores is undefined")
    cut = n // 4
    return np.asarray(np.mean(x[..., cut:n - cut], axis=-1))


def bootstrap_ci(
    tasks: Sequence[Sequence[float] | np.ndarray],
    statistic: Statistic = mean,
    *,
    rng: np.random.Generator | None = None,
    n_resamples: int = N_RESAMPLES,
    confidence: float = CONFIDENCE,
) -> Estimate:
    """The statistic of the pooled scores and its stratified percentile bootstrap interval.

    Args:
        tasks: the scores of each task (e.g. one list per trajectory, one score per
            seed; lists may differ in length). ``[scores]`` is one task.
        statistic: :func:`mean` or :func:`iqm` (any ``[R, N] -> [R]`` function).
        rng: the resampling generator; default ``default_rng(BOOTSTRAP_SEED)``.
        n_resamples: bootstrap resamples.
        confidence: coverage of the interval, in (0, 1).

    Returns:
        The statistic on the data as given, and the interval. One score gives a
        zero-width interval.

    Raises:
        ValueError: no scores, a task without scores, a non-finite score, or a bad
            ``n_resamples`` or ``confidence``.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if n_resamples < 1:
        raise ValueError(f"n_resamples must be >= 1, got {n_resamples}")
    groups = [np.asarray(t, dtype=float).reshape(-1) for t in tasks]
    if not groups or any(g.size == 0 for g in groups):
        raise ValueError("every task needs at least one score")
    pooled = np.concatenate(groups)
    if not np.all(np.isfinite(pooled)):
        raise ValueError("scores must be finite")
    rng = rng if rng is not None else np.random.default_rng(BOOTSTRAP_SEED)
    resampled = np.concatenate(
        [g[rng.integers(0, g.size, size=(n_resamples, g.size))] for g in groups], axis=1
    )  # [R, N]
    stats = statistic(resampled)  # [R]
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(stats, [tail, 100.0 - tail])
    value = float(statistic(pooled[None, :])[0])
    # the percentile interval of a constant statistic can miss its value by rounding
    return Estimate(value, float(min(low, value)), float(max(high, value)), int(pooled.size))
