"""The numbers behind a claim's verdict: effect with its bootstrap CI, probability of
improvement with its CI, and the seeds a clear answer would need.

Every comparison works on *scores*, one per run, where higher is better (a lap time enters as
its negative, so "A is faster" and "A finishes more" read the same way). A run that never lapped
cleanly has score ``-inf``: it counts as the worst run in the probability of improvement (ties
among such runs count one half) and is left out of the mean effect, which is the difference of
the means over runs with a finite score (for laps: mean lap of B minus mean lap of A, in
seconds, the aLT difference the tables show). A baseline bot is one fixed value, not a sample:
its side contributes no spread.

Intervals are 95 % percentile bootstraps over runs (``scipy.stats.bootstrap``, both groups
resampled independently; a fixed side is not resampled), seeded like every other interval of
the report (``report.stats.DEFAULT_SEED``), so the same results always print the same verdict.

Verdict: *supported* when the effect's CI lies above 0, *contradicted* when it lies below,
*inconclusive* otherwise; where the effect cannot be computed (a side without a finite score)
the CI of the probability of improvement decides against 0.5 instead. *no data*: a side has no
runs at all.

That verdict is valid for a sample size fixed in advance. A sequential run (``[adaptive]``)
looks after every wave of seeds and stops when a claim is decided, so each comparison also gets
an anytime-valid *sequential* verdict (``claims.sequential``): the hedged capital confidence
sequence of the paired differences A - B (the i-th run of A by seed against the i-th of B; a
bot subtracted from every run), with a miss counted as the worst bounded value (``Scale``:
a run without a clean lap as the longest lap a test can time, a missed milestone as the CPU
budget). It is supported / contradicted when the sequence lies above / below 0. A claim with
``decide_on = "wins"`` reads the sequence of who wins each pair instead (+1 / 0 / -1: the sign
test, against a probability of improvement of one half), which needs no bound.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats as sps

from formula_tourney.claims import sequential
from formula_tourney.claims.schema import DecideOn
from formula_tourney.report import stats

SUPPORTED = "supported"
CONTRADICTED = "contradicted"
INCONCLUSIVE = "inconclusive"
NO_DATA = "no data"
VERDICTS = (SUPPORTED, CONTRADICTED, INCONCLUSIVE, NO_DATA)

Z_TWO_SIDED_95 = float(sps.norm.ppf(0.975))
Z_POWER_80 = float(sps.norm.ppf(0.80))
"""The sample-size rule: a two-sided 5 % test that finds the observed effect 80 % of the time."""
WORST_LAP_S = 1e12
"""Stand-in lap time of a run without a clean lap inside ``stats.compare`` (which drops
non-finite values): slower than any lap, equal to every other such run."""


@dataclass(frozen=True)
class ClaimStats:
    """One comparison of A with B: what the claims table prints and ``--json`` carries."""

    effect: float
    effect_low: float
    effect_high: float
    prob: float
    prob_low: float
    prob_high: float
    n_a: int
    n_b: int
    finite_a: int
    finite_b: int
    seeds_needed: int | None
    verdict: str
    sequence: sequential.Sequence | None = None
    """The anytime-valid confidence sequence of the paired differences (None: no scale)."""
    sequential: str = NO_DATA
    """The verdict of :attr:`sequence`: what a sequential run decides on."""

    def as_dict(self) -> dict[str, Any]:
        seq = self.sequence
        return {"effect": self.effect, "effect_low": self.effect_low,
                "effect_high": self.effect_high, "prob_improvement": self.prob,
                "prob_low": self.prob_low, "prob_high": self.prob_high, "n_a": self.n_a,
                "n_b": self.n_b, "finite_a": self.finite_a, "finite_b": self.finite_b,
                "seeds_needed": self.seeds_needed, "verdict": self.verdict,
                "sequential": self.sequential, "pairs": seq.n if seq else 0,
                "cs_low": seq.low if seq else math.nan, "cs_high": seq.high if seq else math.nan,
                "bound": seq.bound if seq else math.nan}


@dataclass(frozen=True)
class Scale:
    """What bounds a comparison's scores, for its confidence sequence: every score counts in
    ``[miss, best]`` (higher is better; a score beyond it counts as its end), and a run without
    a result (-inf) counts as ``miss``. So a paired difference lies in
    ``[-(best - miss), best - miss]``."""

    miss: float
    best: float

    @property
    def bound(self) -> float:
        return float(self.best - self.miss)


SEQUENTIAL = {"above": SUPPORTED, "below": CONTRADICTED, "open": INCONCLUSIVE, "empty": NO_DATA}


def sequence_of(a: Sequence[float], b: Sequence[float], a_fixed: bool, b_fixed: bool,
                scale: Scale, decide_on: DecideOn = "mean") -> sequential.Sequence | None:
    """The confidence sequence of A - B (scores in seed order; -inf counts as the miss, nan
    is no value); None without runs on a side or, for the mean, without a finite bound.
    Against a fixed side the differences lie in a span one bound wide
    (``sequential.confidence_sequence``). ``decide_on = "wins"``: the sequence of who wins
    each pair (``sequential.paired_wins``, values in [-1, 1]), which needs no scale."""
    a, b = _arr(a), _arr(b)
    if a.size == 0 or b.size == 0:
        return None
    if decide_on == "wins":
        return sequential.confidence_sequence(sequential.paired_wins(a, b, a_fixed, b_fixed), 1.0)
    if not (math.isfinite(scale.bound) and scale.bound > 0):
        return None
    fa = np.clip(np.where(np.isneginf(a), scale.miss, a), scale.miss, scale.best)
    fb = np.clip(np.where(np.isneginf(b), scale.miss, b), scale.miss, scale.best)
    diffs = sequential.paired_differences(fa, fb, a_fixed, b_fixed)
    span = None  # a fixed side (a bot's one value) narrows the differences to one bound's width
    if b_fixed:
        span = (scale.miss - float(fb[0]), scale.best - float(fb[0]))
    elif a_fixed:
        span = (float(fa[0]) - scale.best, float(fa[0]) - scale.miss)
    return sequential.confidence_sequence(diffs, scale.bound, span=span)


def _arr(values: Sequence[float] | np.ndarray) -> np.ndarray:
    arr = np.asarray(values, dtype=float).ravel()
    return arr[~np.isnan(arr)]  # nan = no value; -inf (no clean lap) stays a run


def effect_interval(a: np.ndarray, b: np.ndarray, a_fixed: bool = False,
                    b_fixed: bool = False, seed: int = stats.DEFAULT_SEED,
                    n_resamples: int = stats.DEFAULT_RESAMPLES) -> stats.Interval:
    """mean(A) - mean(B) over finite scores, with a percentile bootstrap CI.

    A fixed side (a bot) is a constant: the CI is that of the other side's mean, shifted. Fewer
    than two finite scores on a sampled side give no interval (nan).
    """
    fa, fb = a[np.isfinite(a)], b[np.isfinite(b)]
    nan = float("nan")
    if fa.size == 0 or fb.size == 0:
        return stats.Interval(nan, nan, nan)
    value = float(fa.mean() - fb.mean())
    if b_fixed:
        ci = stats.mean_ci(fa, seed=seed, n_resamples=n_resamples)
        return stats.Interval(value, ci.low - float(fb[0]), ci.high - float(fb[0]))
    if a_fixed:
        ci = stats.mean_ci(fb, seed=seed, n_resamples=n_resamples)
        return stats.Interval(value, float(fa[0]) - ci.high, float(fa[0]) - ci.low)
    if fa.size < 2 or fb.size < 2:
        return stats.Interval(value, nan, nan)
    if np.ptp(fa) == 0.0 and np.ptp(fb) == 0.0:
        return stats.Interval(value, value, value)
    res = sps.bootstrap(
        (fa, fb), lambda x, y, axis: np.mean(x, axis=axis) - np.mean(y, axis=axis),
        paired=False, vectorized=True, confidence_level=0.95, n_resamples=n_resamples,
        method="percentile", rng=np.random.default_rng(seed),
    )
    return stats.Interval(value, float(res.confidence_interval.low),
                          float(res.confidence_interval.high))


def prob_improvement(a: np.ndarray, b: np.ndarray, a_fixed: bool = False,
                     b_fixed: bool = False, seed: int = stats.DEFAULT_SEED,
                     n_resamples: int = stats.DEFAULT_RESAMPLES) -> stats.Interval:
    """P(a run of A scores higher than a run of B), ties one half, with its bootstrap CI.

    Two samples: ``report.stats.compare`` (the report's probability of improvement, rliable's
    definition). Against a fixed value: the share of the other side's runs beaten, with the CI
    of that share (``report.stats.mean_ci`` over the 0 / 0.5 / 1 outcomes).
    """
    nan = float("nan")
    if a.size == 0 or b.size == 0:
        return stats.Interval(nan, nan, nan)
    if a_fixed or b_fixed:
        const = float(a[0] if a_fixed else b[0])
        other = b if a_fixed else a
        wins = np.where(other > const, 1.0, np.where(other == const, 0.5, 0.0))
        if a_fixed:
            wins = 1.0 - wins
        ci = stats.mean_ci(wins, seed=seed, n_resamples=n_resamples)
        return stats.Interval(float(wins.mean()), ci.low, ci.high)
    # compare() wants lap-like values (lower wins) and drops non-finite ones
    la = np.where(np.isfinite(a), -a, WORST_LAP_S)
    lb = np.where(np.isfinite(b), -b, WORST_LAP_S)
    cmp_ = stats.compare(la, lb, seed=seed, n_resamples=n_resamples)
    return stats.Interval(cmp_.prob, cmp_.low, cmp_.high)


def seeds_needed(a: np.ndarray, b: np.ndarray, effect: float, a_fixed: bool = False,
                 b_fixed: bool = False) -> int | None:
    """Runs per group for a two-sided 5 % test to detect ``effect`` with 80 % power at the
    observed spread: ``2 (z_.975 + z_.8)^2 s^2 / d^2`` with the pooled variance of two samples
    (``(z_.975 + z_.8)^2 s^2 / d^2`` against a fixed value); at least 2. None where the effect is
    zero or unknown, or a sampled side has fewer than two finite scores."""
    fa, fb = a[np.isfinite(a)], b[np.isfinite(b)]
    if not math.isfinite(effect) or effect == 0.0:
        return None
    z2 = (Z_TWO_SIDED_95 + Z_POWER_80) ** 2
    if a_fixed or b_fixed:
        other = fb if a_fixed else fa
        if other.size < 2:
            return None
        var, factor = float(np.var(other, ddof=1)), 1.0
    else:
        if fa.size < 2 or fb.size < 2:
            return None
        var = ((fa.size - 1) * np.var(fa, ddof=1) + (fb.size - 1) * np.var(fb, ddof=1)) / (
            fa.size + fb.size - 2)
        factor = 2.0
    return max(2, math.ceil(factor * z2 * float(var) / effect**2))


def decide(effect: stats.Interval, prob: stats.Interval) -> str:
    """The verdict from the effect's CI (or, without an effect, the probability's CI)."""
    if math.isfinite(effect.low) and math.isfinite(effect.high):
        if effect.low > 0.0:
            return SUPPORTED
        if effect.high < 0.0:
            return CONTRADICTED
        return INCONCLUSIVE
    if not math.isfinite(effect.value) and math.isfinite(prob.low) and math.isfinite(prob.high):
        if prob.low > 0.5:
            return SUPPORTED
        if prob.high < 0.5:
            return CONTRADICTED
    return INCONCLUSIVE


def compare_scores(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray,
                   a_fixed: bool = False, b_fixed: bool = False,
                   seed: int = stats.DEFAULT_SEED,
                   n_resamples: int = stats.DEFAULT_RESAMPLES,
                   sequence: sequential.Sequence | None = None) -> ClaimStats:
    """Every number of one comparison of A's scores with B's (higher is better; -inf = a run
    without a result, nan = no value and ignored); ``sequence``: the comparison's confidence
    sequence (:func:`sequence_of` on the scores in seed order), whose verdict is the
    sequential one."""
    xa, xb = _arr(a), _arr(b)
    if a_fixed and xa.size > 1 or b_fixed and xb.size > 1:
        raise ValueError("a fixed side holds one value")
    eff = effect_interval(xa, xb, a_fixed, b_fixed, seed, n_resamples)
    prob = prob_improvement(xa, xb, a_fixed, b_fixed, seed, n_resamples)
    verdict = NO_DATA if xa.size == 0 or xb.size == 0 else decide(eff, prob)
    seq = sequence if xa.size and xb.size else None
    return ClaimStats(
        effect=eff.value, effect_low=eff.low, effect_high=eff.high, prob=prob.value,
        prob_low=prob.low, prob_high=prob.high, n_a=int(xa.size), n_b=int(xb.size),
        finite_a=int(np.isfinite(xa).sum()), finite_b=int(np.isfinite(xb).sum()),
        seeds_needed=seeds_needed(xa, xb, eff.value, a_fixed, b_fixed), verdict=verdict,
        sequence=seq, sequential=SEQUENTIAL[seq.verdict] if seq is not None else
        (NO_DATA if verdict == NO_DATA else INCONCLUSIVE),
    )  # fmt: skip


def overall(verdicts: Sequence[str]) -> str:
    """One verdict for a claim made of several comparisons (each family, every track): it holds
    only if every comparison supports it, fails if any contradicts it."""
    if not verdicts or all(v == NO_DATA for v in verdicts):
        return NO_DATA
    if any(v == CONTRADICTED for v in verdicts):
        return CONTRADICTED
    if all(v == SUPPORTED for v in verdicts):
        return SUPPORTED
    return INCONCLUSIVE
