"""The anytime-valid confidence sequence (claims.sequential): its error under repeated looks, the
naive fixed-sample interval's inflation under the same looks, and its power under a real effect."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from formula_tourney.claims.sequential import (
    confidence_sequence,
    paired_differences,
    paired_wins,
    pairs_to_decide,
    rejected,
)

BOUND = 10.0
RUNS = 1000
MIN_SEEDS, WAVE, MAX_SEEDS = 3, 2, 31
LOOKS = np.arange(MIN_SEEDS, MAX_SEEDS + 1, WAVE)
"""A sequential design: min_seeds, then a wave of 2 seeds at a time, read after every wave."""


def _differences(effect: float, seed: int) -> np.ndarray:
    """RUNS sequential runs of MAX_SEEDS paired differences A - B (lap-like, sd 2 each side),
    capped at the bound as a miss is."""
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, 2.0, (RUNS, MAX_SEEDS))
    b = rng.normal(-effect, 2.0, (RUNS, MAX_SEEDS))
    return np.clip(a - b, -BOUND, BOUND)


def _sequential_decides(d: np.ndarray) -> np.ndarray:
    """Whether each run ends supported or contradicted when its CS is read after every wave."""
    x = (d + BOUND) / (2 * BOUND)
    gone = rejected(x, 0.5)[..., 0]
    return gone[:, LOOKS - 1].any(axis=1)


def _naive_decides(d: np.ndarray) -> np.ndarray:
    """The same looks with a fixed-sample 95 % t interval (what a report read after every wave
    would do without a sequential design)."""
    out = np.zeros(d.shape[0], dtype=bool)
    for n in LOOKS:
        mean = d[:, :n].mean(axis=1)
        half = stats.t.ppf(0.975, n - 1) * d[:, :n].std(axis=1, ddof=1) / math.sqrt(n)
        out |= (mean - half > 0) | (mean + half < 0)
    return out


def _bootstrap_decides(d: np.ndarray, resamples: int = 400) -> np.ndarray:
    """The same looks with a percentile bootstrap CI of the mean (the report's fixed-sample
    interval)."""
    rng = np.random.default_rng(3)
    out = np.zeros(d.shape[0], dtype=bool)
    for n in LOOKS:
        idx = rng.integers(0, n, size=(resamples, n))
        means = d[:, :n][:, idx].mean(axis=2)
        low, high = np.quantile(means, [0.025, 0.975], axis=1)
        out |= (low > 0) | (high < 0)
    return out


def test_error_under_the_null_stays_below_alpha_and_the_naive_interval_inflates() -> None:
    d = _differences(0.0, seed=11)
    sequential = _sequential_decides(d).mean()
    naive_t = _naive_decides(d).mean()
    naive_boot = _bootstrap_decides(d[:300]).mean()
    assert sequential <= 0.05
    assert naive_t > 0.15 and naive_t > 3 * max(sequential, 0.05)
    assert naive_boot > 0.15


def test_a_real_effect_is_decided_in_most_runs() -> None:
    d = _differences(3.0, seed=12)  # 1.5 sd of a side: what a clear finding looks like
    assert _sequential_decides(d).mean() > 0.7


def test_confidence_sequence_reads_the_verdict_and_covers_the_mean() -> None:
    rng = np.random.default_rng(5)
    clear = confidence_sequence(rng.normal(4.0, 1.0, 25), BOUND)
    assert clear.verdict == "above" and 0.0 < clear.low < 4.0 < clear.high
    worse = confidence_sequence(rng.normal(-4.0, 1.0, 25), BOUND)
    assert worse.verdict == "below" and worse.high < 0.0
    unclear = confidence_sequence(rng.normal(0.2, 2.0, 6), BOUND)
    assert unclear.verdict == "open" and unclear.low < 0.0 < unclear.high
    assert confidence_sequence([], BOUND).verdict == "empty"
    with pytest.raises(ValueError, match="bound"):
        confidence_sequence([1.0], math.inf)


def test_the_cs_shrinks_and_its_order_matters_only_through_the_running_intersection() -> None:
    rng = np.random.default_rng(9)
    values = rng.normal(1.0, 2.0, 40)
    widths = [confidence_sequence(values[:n], BOUND).half_width for n in (5, 10, 20, 40)]
    assert widths == sorted(widths, reverse=True) and widths[-1] < widths[0] / 2


def test_paired_differences_pair_by_seed_order_and_subtract_a_bot() -> None:
    assert paired_differences([3.0, 4.0, 5.0], [1.0, 1.0]).tolist() == [2.0, 3.0]
    assert paired_differences([3.0, 4.0], [2.5], b_fixed=True).tolist() == [0.5, 1.5]
    assert paired_differences([2.0], [1.0, 3.0], a_fixed=True).tolist() == [1.0, -1.0]


def _bot_null(seed: int) -> tuple[np.ndarray, float, float]:
    """RUNS sequential runs of differences run - bot where the bot sits 1 s from the best
    possible lap and a run counts up to 19 s slower: differences in [-19, 1] with mean 0 (a
    skewed spread: most runs a little faster than the bot, a few far slower)."""
    rng = np.random.default_rng(seed)
    low, high = -19.0, 1.0
    share = rng.beta(9.5, 0.5, (RUNS, MAX_SEEDS))  # mean 0.95: the null's place in the span
    return low + (high - low) * share, low, high


def test_a_bot_comparison_keeps_its_error_on_the_narrow_span() -> None:
    d, low, high = _bot_null(seed=13)
    assert abs(d.mean()) < 0.05
    x = (d - low) / (high - low)
    gone = rejected(x, -low / (high - low))[..., 0]
    assert gone[:, LOOKS - 1].any(axis=1).mean() <= 0.05


def test_a_bot_comparison_decides_sooner_on_its_span_than_on_the_symmetric_range() -> None:
    # runs ~15 s slower than a bot that is 1 s off the best lap (a 20 s bound): the span
    # [-19, 1] decides from 3 pairs, the symmetric [-20, 20] needs 9
    slower = [-15.0, -14.0, -16.0, -15.5, -14.5, -15.0, -16.0, -15.0, -15.0]
    spans = [confidence_sequence(slower[:n], 20.0, span=(-19.0, 1.0)) for n in range(1, 10)]
    symmetric = [confidence_sequence(slower[:n], 20.0) for n in range(1, 10)]
    first = [next(n for n, s in enumerate(seqs, 1) if s.verdict == "below")
             for seqs in (spans, symmetric)]
    assert first == [3, 9]
    assert spans[-1].high < 0.0 and spans[-1].low >= -19.0
    with pytest.raises(ValueError, match="span"):
        confidence_sequence([1.0], 20.0, span=(-30.0, 1.0))


def test_pairs_to_decide_projects_the_observed_values_repeated() -> None:
    # decided: its n; without values or at the threshold: no projection
    assert pairs_to_decide(confidence_sequence([1.0] * 8, 1.0)) == 8
    assert pairs_to_decide(confidence_sequence([], BOUND)) is None
    assert pairs_to_decide(confidence_sequence([2.0, -2.0] * 3, BOUND)) is None
    # open: the first n at which the observed values, repeated in order, exclude 0
    seen = [3.0, 1.0, 4.0, -1.0, 5.0]
    need = pairs_to_decide(confidence_sequence(seen, BOUND))
    assert need is not None and need > 5
    repeated = (seen * (need // 5 + 1))[:need]
    assert confidence_sequence(repeated, BOUND).verdict == "above"
    assert confidence_sequence(repeated[:-1], BOUND).verdict == "open"
    # a real CS: the projection from 5 values lies within a factor 2 of where it decides
    rng = np.random.default_rng(21)
    values = rng.normal(3.0, 2.0, 200)
    first = pairs_to_decide(confidence_sequence(values[:5], BOUND))
    decided_at = next(n for n in range(5, 201)
                      if confidence_sequence(values[:n], BOUND).verdict == "above")
    assert first is not None and first / 2 <= decided_at <= 2 * first


def test_paired_wins_count_a_miss_as_losing_to_any_lap_and_two_misses_as_a_tie() -> None:
    inf = math.inf
    assert paired_wins([-70.0, -inf, -inf, -72.0], [-71.0, -80.0, -inf, -72.0]).tolist() == [
        1.0, -1.0, 0.0, 0.0]
    assert paired_wins([-70.0, -inf, -73.0], [-71.5], b_fixed=True).tolist() == [1.0, -1.0, -1.0]
    assert paired_wins([-71.5], [-70.0, -inf], a_fixed=True).tolist() == [-1.0, 1.0]
    assert paired_wins([1.0, 2.0, 3.0], [0.0]).tolist() == [1.0]  # as many as the shorter side


def _wins_null(seed: int) -> np.ndarray:
    """RUNS sequential runs of MAX_SEEDS pairs from two equal groups whose runs miss a third of
    the time (two misses tie): who wins each pair, under the null of no difference."""
    rng = np.random.default_rng(seed)
    laps = rng.normal(72.0, 2.0, (2, RUNS, MAX_SEEDS))
    laps[rng.random(laps.shape) < 1 / 3] = math.inf
    return paired_wins(-laps[0].ravel(), -laps[1].ravel()).reshape(RUNS, MAX_SEEDS)


def test_deciding_on_wins_keeps_its_error_under_the_null_and_the_naive_reading_inflates() -> None:
    w = _wins_null(seed=17)
    gone = rejected((w + 1.0) / 2.0, 0.5)[..., 0]
    assert gone[:, LOOKS - 1].any(axis=1).mean() <= 0.05
    assert _naive_decides(w).mean() > 0.15


def test_wins_decide_a_consistent_small_effect_the_bounded_mean_cannot() -> None:
    # LAC 1.5-4.5 s faster in every pair on a track whose limit (and so the mean's bound) is
    # 66 s: seven pairs decide on wins; the mean's CS is still open at twenty
    rng = np.random.default_rng(23)
    gains = rng.uniform(1.5, 4.5, 20)
    wins = [confidence_sequence(paired_wins(gains[:n], np.zeros(n)), 1.0) for n in (6, 7)]
    assert [w.verdict for w in wins] == ["open", "above"]
    assert (wins[1].low + 1.0) / 2.0 > 0.5  # P(A better) above one half
    assert confidence_sequence(gains, 66.0).verdict == "open"
