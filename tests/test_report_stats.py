"""report.stats against small cases computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formula_tourney.report import stats


def test_mean_ci_two_values_is_their_range() -> None:
    # Resampling two values: means a (1/4), (a+b)/2 (1/2), b (1/4); 2.5%/97.5% -> a and b.
    ci = stats.mean_ci([10.0, 12.0])
    assert ci.value == pytest.approx(11.0)
    assert ci.low == pytest.approx(10.0)
    assert ci.high == pytest.approx(12.0)


def test_mean_ci_degenerate_cases() -> None:
    one = stats.mean_ci([27.5])
    assert one.value == 27.5 and math.isnan(one.low) and math.isnan(one.high)
    same = stats.mean_ci([3.0, 3.0, 3.0])
    assert (same.value, same.low, same.high) == (3.0, 3.0, 3.0)
    empty = stats.mean_ci([float("nan")])
    assert math.isnan(empty.value)


def test_mean_ci_is_reproducible_and_ignores_nan() -> None:
    data = [27.1, 27.4, 27.2, 28.0, 26.9, float("nan")]
    a, b = stats.mean_ci(data), stats.mean_ci(data)
    assert a == b
    assert a.value == pytest.approx(np.mean([27.1, 27.4, 27.2, 28.0, 26.9]))
    assert 26.9 <= a.low < a.value < a.high <= 28.0
    # a different seed moves the endpoints only a little at 5000 resamples
    c = stats.mean_ci(data, seed=1)
    assert c.low == pytest.approx(a.low, abs=0.05)


def test_iqm_trims_a_quarter_each_side() -> None:
    assert stats.iqm([1, 2, 3, 4, 5, 6, 7, 8]) == pytest.approx(4.5)  # mean of 3..6
    assert stats.iqm([1, 2, 3, 4, 100]) == pytest.approx(3.0)  # drops 1 and 100
    assert stats.iqm([1.0, 2.0, 3.0]) == pytest.approx(2.0)  # nothing trimmed
    assert math.isnan(stats.iqm([]))


def test_prob_faster_counts_pairs() -> None:
    assert stats.prob_faster([1, 2], [3, 4]) == 1.0
    assert stats.prob_faster([3, 4], [1, 2]) == 0.0
    # pairs (1,2) (1,4) (3,4) faster, (3,2) slower -> 3/4
    assert stats.prob_faster([1, 3], [2, 4]) == pytest.approx(0.75)
    # ties count one half: (1,1) .5, (1,2) 1, (2,1) 0, (2,2) .5 -> 2/4
    assert stats.prob_faster([1, 2], [1, 2]) == pytest.approx(0.5)
    assert math.isnan(stats.prob_faster([], [1.0]))


def test_compare_bootstrap_interval_by_hand() -> None:
    sure = stats.compare([1, 2], [3, 4])
    assert (sure.prob, sure.low, sure.high) == (1.0, 1.0, 1.0)
    assert sure.p_value == pytest.approx(1 / 3)  # exact U test, n=2 vs 2: 2/6
    # A from {1,3}, B from {2,4}: P=0 has probability 1/16 > 2.5%, P=1 has 7/16 -> [0, 1]
    mixed = stats.compare([1, 3], [2, 4])
    assert mixed.prob == pytest.approx(0.75)
    assert (mixed.low, mixed.high) == (0.0, 1.0)
    single = stats.compare([1.0], [2.0, 3.0])
    assert single.prob == 1.0 and math.isnan(single.low)


def test_band_over_seeds() -> None:
    flat = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    mean, low, high = stats.band(flat)
    np.testing.assert_allclose(mean, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(low, mean)
    np.testing.assert_allclose(high, mean)
    spread = np.array([[0.0, np.nan], [10.0, 4.0]])
    mean, low, high = stats.band(spread)
    np.testing.assert_allclose(mean, [5.0, 4.0])
    assert low[0] == pytest.approx(0.0) and high[0] == pytest.approx(10.0)
    with pytest.raises(ValueError):
        stats.band(np.array([1.0, 2.0]))
