"""Statistics for lap times over seeds: bootstrap CIs, probability of being faster, IQM.

A tournament has few seeds per entrant (5-10 in the paper, 2-3 in the quick one), so the report
pairs every mean with a 95% bootstrap interval and compares entrants by the probability that one
run of A beats one run of B (the Mann-Whitney U statistic scaled to [0, 1], as rliable's
"probability of improvement"; rliable itself does not import with pandas 3). Every resampling uses
a fixed seed so that the same results always print the same report.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

DEFAULT_SEED = 20240611
"""Seed of every bootstrap in the report: reproducible intervals across runs of ``report``."""
DEFAULT_RESAMPLES = 5000
"""Bootstrap resamples: the CI endpoints of a 5-seed mean move < 0.5% between seeds at 5000."""


def _clean(values: Sequence[float] | np.ndarray) -> np.ndarray:
    arr = np.asarray(values, dtype=float).ravel()
    return arr[np.isfinite(arr)]


@dataclass(frozen=True)
class Interval:
    """A point estimate with its 95% confidence interval (nan where it cannot be computed)."""

    value: float
    low: float
    high: float

    def as_dict(self) -> dict[str, float]:
        return {"value": self.value, "low": self.low, "high": self.high}


def mean_ci(values: Sequence[float] | np.ndarray, confidence: float = 0.95,
            seed: int = DEFAULT_SEED, n_resamples: int = DEFAULT_RESAMPLES) -> Interval:
    """Mean (the paper's aLT when ``values`` are per-run best laps) with a percentile bootstrap CI.

    The percentile method is used rather than BCa: with 2-5 seeds BCa's acceleration estimate is
    unstable and scipy returns nan for it. One value gives no interval (nan); identical values
    give a zero-width interval.
    """
    arr = _clean(values)
    if arr.size == 0:
        return Interval(float("nan"), float("nan"), float("nan"))
    mean = float(arr.mean())
    if arr.size == 1:
        return Interval(mean, float("nan"), float("nan"))
    if np.ptp(arr) == 0.0:
        return Interval(mean, mean, mean)
    res = stats.bootstrap(
        (arr,), np.mean, confidence_level=confidence, n_resamples=n_resamples,
        method="percentile", rng=np.random.default_rng(seed), vectorized=True,
    )
    return Interval(mean, float(res.confidence_interval.low),
                    float(res.confidence_interval.high))


def iqm(values: Sequence[float] | np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50% of runs (Agarwal et al. 2021).

    Robust to the one collapsed seed that drags a mean (a run's late tests can collapse); with
    fewer than 4 values nothing is trimmed and it equals the mean.
    """
    arr = _clean(values)
    if arr.size == 0:
        return float("nan")
    return float(stats.trim_mean(arr, 0.25))


def prob_faster(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> float:
    """P(a run of A has a lower lap time than a run of B), ties counting one half.

    This is the Mann-Whitney U statistic of B against A divided by ``n_a * n_b``: the share of
    (A, B) pairs in which A is faster.
    """
    xa, xb = _clean(a), _clean(b)
    if xa.size == 0 or xb.size == 0:
        return float("nan")
    # mannwhitneyu(x, y).statistic counts pairs with x > y (+ half the ties): B slower than A.
    return float(stats.mannwhitneyu(xb, xa, alternative="two-sided").statistic
                 / (xa.size * xb.size))


@dataclass(frozen=True)
class Comparison:
    """How A compares with B: P(A faster) with its bootstrap CI, and the U test's p-value."""

    prob: float
    low: float
    high: float
    p_value: float
    n_a: int
    n_b: int

    def as_dict(self) -> dict[str, float | int]:
        return {"prob_faster": self.prob, "low": self.low, "high": self.high,
                "p_value": self.p_value, "n_a": self.n_a, "n_b": self.n_b}


def compare(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray,
            confidence: float = 0.95, seed: int = DEFAULT_SEED,
            n_resamples: int = DEFAULT_RESAMPLES) -> Comparison:
    """P(A faster than B) with a percentile bootstrap CI resampling A and B independently."""
    xa, xb = _clean(a), _clean(b)
    prob = prob_faster(xa, xb)
    if xa.size == 0 or xb.size == 0:
        nan = float("nan")
        return Comparison(nan, nan, nan, nan, int(xa.size), int(xb.size))
    p_value = float(stats.mannwhitneyu(xa, xb, alternative="two-sided").pvalue)
    if xa.size < 2 or xb.size < 2:
        return Comparison(prob, float("nan"), float("nan"), p_value, int(xa.size), int(xb.size))
    rng = np.random.default_rng(seed)
    ia = rng.integers(0, xa.size, size=(n_resamples, xa.size))
    ib = rng.integers(0, xb.size, size=(n_resamples, xb.size))
    boot = _prob_faster_batch(xa[ia], xb[ib])
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(boot, [alpha, 1.0 - alpha])
    return Comparison(prob, float(low), float(high), p_value, int(xa.size), int(xb.size))


def _prob_faster_batch(sa: np.ndarray, sb: np.ndarray) -> np.ndarray:
    """P(A faster) for each row of resampled A (r, n_a) and B (r, n_b), ties counting one half."""
    diff = sa[:, :, None] - sb[:, None, :]
    return ((diff < 0).sum(axis=(1, 2)) + 0.5 * (diff == 0).sum(axis=(1, 2))) / (
        sa.shape[1] * sb.shape[1]
    )


def band(values: np.ndarray, confidence: float = 0.95, seed: int = DEFAULT_SEED,
         n_resamples: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and percentile-bootstrap band over seeds for a (seeds, points) array with nans.

    Used for learning curves: one vectorised resampling of whole seeds (rows), so that the band
    of a 500-episode curve costs one array operation instead of 500 scipy calls.
    """
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise ValueError("band() needs a (seeds, points) array")
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", category=RuntimeWarning)
        mean = np.nanmean(arr, axis=0)
        if arr.shape[0] < 2:
            return mean, np.full_like(mean, np.nan), np.full_like(mean, np.nan)
        rng = np.random.default_rng(seed)
        idx = rng.integers(0, arr.shape[0], size=(n_resamples, arr.shape[0]))
        boot = np.nanmean(arr[idx], axis=1)
        alpha = (1.0 - confidence) / 2.0
        low = np.nanquantile(boot, alpha, axis=0)
        high = np.nanquantile(boot, 1.0 - alpha, axis=0)
    return mean, low, high
