"""Anytime-valid confidence sequences for the mean of bounded differences: verdicts that stay valid
however often they are read.

A sequential tournament reads its claims after every wave of seeds and stops asking for seeds
once a claim is decided. A fixed-sample interval (a t or bootstrap CI) read that way excludes a
true null far more often than its nominal 5 %: every look is another chance to stop on a lucky
streak. A *confidence sequence* (CS) is a sequence of intervals that covers the mean at every
sample size at once with probability 1 - alpha, so stopping at any look is allowed.

This module implements the hedged capital (betting) confidence sequence of Waudby-Smith and
Ramdas, "Estimating means of bounded random variables by betting", JRSS-B 86(1), 2024 (arXiv
2010.09686), section 4 and Theorem 3, with their predictable plug-in bets (eq. 26-27) and the
running intersection. For values ``x_i`` in [0, 1] and a candidate mean ``m``, two gamblers bet
that the mean is above and below ``m``::

    K+_t(m) = prod_i (1 + l+_i(m) (x_i - m)),   K-_t(m) = prod_i (1 - l-_i(m) (x_i - m))
    l_i = sqrt(2 log(2 / alpha) / (s2_{i-1} i log(1 + i))),  s2: a running variance
    l+_i(m) = min(l_i, c / m),   l-_i(m) = min(l_i, c / (1 - m)),   c = 3/4
    K_t(m)  = (K+_t(m) + K-_t(m)) / 2

``K_t(m)`` is a nonnegative martingale when the mean is ``m``, so by Ville's inequality it ever
reaches ``1 / alpha`` with probability at most alpha: the CS at time t is every ``m`` whose
capital has never reached ``1 / alpha`` up to t (the running intersection). Chosen over a
normal-mixture (sub-Gaussian) boundary because it needs no variance assumption, only the
bound, and its bets adapt to the observed spread: for the few, skewed, sometimes capped lap
times of a tournament it is exact at every sample size, where a normal mixture is only
asymptotically valid.

Differences ``d`` in ``[-bound, bound]`` (or a narrower known span ``[low, high]``: a comparison
with a bot, whose lap is one fixed value) are mapped to ``x = (d - low) / (high - low)``; the
bound comes from the data model (``report.claims.evidence``: a lap time lies between the
track's reference limit and the longest lap a test can time, a miss counts as that longest
lap; a share of tracks lies in [0, 100]; a CPU time to a milestone in [0, budget]).

A claim may instead be decided on its *wins* (``decide_on = "wins"``, :func:`paired_wins`):
each pair counts +1 where A's run beats B's, -1 where it loses and 0 on a tie (two runs
without a result tie). Their mean is P(A beats B) - P(B beats A), so the CS excludes 0 exactly
when it excludes a probability of improvement of one half: the sign test, made anytime-valid by
the same betting sequence. It needs no bound from the data model, counts a miss as worse
than any lap (the "miss counts as infinite" of a median) and reads a consistent effect from 7
pairs whatever its size in seconds, where the mean's CS must first outgrow a bound of one
reference limit (a lap that never comes counts as twice the limit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

ALPHA = 0.05
"""Error level of every confidence sequence: the CS covers the mean at all times w.p. 95 %."""
BET_CAP = 0.75
"""``c`` of the truncated bets (Waudby-Smith and Ramdas suggest 1/2 or 3/4): at most three
quarters of the capital is staked on one value, so a clear effect is decided from 7 pairs on
(with 1/2: from 10; a factor of at most 1 + c per pair must reach 2 / alpha)."""
GRID_POINTS = 2001
"""Candidate means on [0, 1]: the CS's ends are read to 1/2000 of the range."""
PROJECTION_LIMIT = 1000
"""Pairs the projection of an open CS looks ahead (:func:`projected_pairs`): a comparison that
would need more is out of reach of any tournament this tool runs."""


def bets(x: np.ndarray, alpha: float = ALPHA) -> np.ndarray:
    """The predictable plug-in bet size ``l_i`` for each value (axis -1), before truncation:
    it uses only the values before ``i`` (the running mean and variance start at 1/2, 1/4)."""
    n = x.shape[-1]
    t = np.arange(1, n + 1, dtype=float)
    mean = (0.5 + np.cumsum(x, axis=-1)) / (t + 1.0)
    var = (0.25 + np.cumsum((x - mean) ** 2, axis=-1)) / (t + 1.0)
    prev_var = np.concatenate([np.full(x.shape[:-1] + (1,), 0.25), var[..., :-1]], axis=-1)
    return np.sqrt(2.0 * math.log(2.0 / alpha) / (prev_var * t * np.log1p(t)))


def log_capital(x: np.ndarray, m: np.ndarray | float, alpha: float = ALPHA) -> np.ndarray:
    """log K_t(m) of the hedged capital process for values ``x`` in [0, 1] (shape (..., n))
    and candidate means ``m`` (shape (g,) or a scalar): shape (..., n, g), one row per time."""
    x = np.asarray(x, dtype=float)
    grid = np.atleast_1d(np.asarray(m, dtype=float))
    lam = bets(x, alpha)[..., None]
    up = np.minimum(lam, BET_CAP / np.maximum(grid, 1e-12))
    down = np.minimum(lam, BET_CAP / np.maximum(1.0 - grid, 1e-12))
    dev = x[..., None] - grid
    log_up = np.cumsum(np.log1p(up * dev), axis=-2)
    log_down = np.cumsum(np.log1p(-down * dev), axis=-2)
    return np.logaddexp(log_up, log_down) - math.log(2.0)


def rejected(x: np.ndarray, m: np.ndarray | float, alpha: float = ALPHA) -> np.ndarray:
    """Whether each candidate mean ``m`` has left the CS by each time (the running
    intersection): shape (..., n, g), True from the first time its capital reached 1/alpha."""
    hit = log_capital(x, m, alpha) >= math.log(1.0 / alpha)
    return np.logical_or.accumulate(hit, axis=-2)


@dataclass(frozen=True)
class Sequence:
    """A confidence sequence read at its last value: the mean, the CS's ends (in the
    differences' unit) and the verdict against the threshold."""

    n: int
    mean: float
    low: float
    high: float
    bound: float
    threshold: float
    verdict: str
    """``above`` (the CS lies above the threshold), ``below``, ``open`` (it contains it) or
    ``empty`` (no values)."""
    projected: int | None = None
    """Pairs in all at which the CS would first exclude the threshold if the values seen so
    far came again in the same order (:func:`projected_pairs`); its ``n`` once decided, None
    without values or beyond ``PROJECTION_LIMIT``."""

    @property
    def half_width(self) -> float:
        return 0.5 * (self.high - self.low) if self.n else math.inf

    def as_dict(self) -> dict[str, Any]:
        return {
            "n": self.n,
            "mean": self.mean,
            "cs_low": self.low,
            "cs_high": self.high,
            "bound": self.bound,
            "threshold": self.threshold,
            "verdict": self.verdict,
            "projected_pairs": self.projected,
        }


def confidence_sequence(
    diffs: np.ndarray | list[float],
    bound: float,
    threshold: float = 0.0,
    alpha: float = ALPHA,
    span: tuple[float, float] | None = None,
) -> Sequence:
    """The CS of the mean of ``diffs`` (in their order: the order the values came, e.g. by
    seed), each in ``[-bound, bound]`` or, where known, the narrower ``span`` ``(low, high)``
    inside it (values beyond it are clipped to it), read at the last value with the running
    intersection, and whether it excludes ``threshold``.

    ``span`` is what a comparison against a fixed value (a bot's lap) knows: every difference
    is a run's score less that one value, so it lies in ``[miss - value, best - value]``, one
    bound wide instead of two. Near an end of that span the bets against the threshold may be
    large (a truncated bet ``c / m`` grows as the threshold nears an end), so a run far on the
    other side of a bot that sits near the best possible lap decides in a few pairs where the
    symmetric range needs at least seven (runs 15 s slower than a bot 1 s off the best lap,
    bound 20 s: 3 pairs against 9, tests/test_claims_sequential.py)."""
    d = np.asarray(diffs, dtype=float).ravel()
    if not (math.isfinite(bound) and bound > 0.0):
        raise ValueError(f"a confidence sequence needs a finite bound > 0, got {bound}")
    lo, hi = (-bound, bound) if span is None else (float(span[0]), float(span[1]))
    if not (math.isfinite(lo) and math.isfinite(hi) and -bound <= lo < hi <= bound):
        raise ValueError(f"a span must lie in [-{bound}, {bound}] with low < high, got {span}")
    if d.size == 0:
        nan = math.nan
        return Sequence(0, nan, lo, hi, bound, threshold, "empty")
    d = np.clip(d, lo, hi)
    scale = hi - lo
    x = (d - lo) / scale
    m0 = min(max((threshold - lo) / scale, 0.0), 1.0)
    grid = np.unique(np.concatenate([np.linspace(0.0, 1.0, GRID_POINTS), [m0]]))
    gone = rejected(x, grid, alpha)[-1]
    kept = grid[~gone]
    if kept.size == 0:  # every candidate left: the CS is empty, read as a point at the mean
        low = high = float(d.mean())
    else:
        low, high = float(kept.min()) * scale + lo, float(kept.max()) * scale + lo
    at = int(np.searchsorted(grid, m0))
    verdict = "open"
    if gone[at]:
        verdict = "above" if float(d.mean()) > threshold else "below"
        low, high = (
            (max(low, threshold), high) if verdict == "above" else (low, min(high, threshold))
        )
    projected = int(d.size) if verdict != "open" else projected_pairs(x, m0, alpha)
    return Sequence(int(d.size), float(d.mean()), low, high, bound, threshold, verdict, projected)


def projected_pairs(x: np.ndarray, m0: float, alpha: float = ALPHA) -> int | None:
    """The pairs in all at which the CS of values ``x`` (in [0, 1]) would first exclude the
    candidate mean ``m0`` if ``x`` came again and again in the same order; None if not within
    ``PROJECTION_LIMIT`` pairs (a mean at the threshold never does).

    Exact for the betting CS, not a 1/sqrt(n) rate: its plug-in bets grow as the running
    variance settles, so a comparison won in every pair is decided at 7 pairs however many it
    has now, where a 1/sqrt(n) model of the width asks for more. Repeating the observed values
    keeps their spread and their share of wins; the projection is what a sequential run
    allocates seeds by (``tourney.adaptive``), and what the report prices an open comparison
    at."""
    x = np.asarray(x, dtype=float).ravel()
    if x.size == 0:
        return None
    ahead = np.resize(x, max(PROJECTION_LIMIT, x.size))
    hit = np.flatnonzero(log_capital(ahead, m0, alpha)[:, 0] >= math.log(1.0 / alpha))
    return int(hit[0]) + 1 if hit.size else None


def pairs(
    a: np.ndarray | list[float],
    b: np.ndarray | list[float],
    a_fixed: bool = False,
    b_fixed: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """A's and B's values pair by pair: the i-th run of A (in seed order) against the i-th of
    B, as many pairs as the shorter side has; a fixed side (a bot: one value) meets every run
    of the other. The pairing is fixed before any value is seen (by seed number), so the
    pairs are i.i.d.; the one pairing rule of :func:`paired_differences` and
    :func:`paired_wins`."""
    xa, xb = np.asarray(a, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
    if a_fixed and b_fixed:
        raise ValueError("a comparison needs runs on at least one side")
    if b_fixed:
        xb = np.full(xa.shape, xb[0]) if xb.size else xb
    elif a_fixed:
        xa = np.full(xb.shape, xa[0]) if xa.size else xa
    n = min(xa.size, xb.size)
    return xa[:n], xb[:n]


def paired_differences(
    a: np.ndarray | list[float],
    b: np.ndarray | list[float],
    a_fixed: bool = False,
    b_fixed: bool = False,
) -> np.ndarray:
    """A - B for each of :func:`pairs`: i.i.d. differences with mean mean(A) - mean(B)."""
    xa, xb = pairs(a, b, a_fixed, b_fixed)
    return xa - xb


def paired_wins(
    a: np.ndarray | list[float],
    b: np.ndarray | list[float],
    a_fixed: bool = False,
    b_fixed: bool = False,
) -> np.ndarray:
    """Who wins each of :func:`pairs` (scores, higher is better; -inf: a run without a
    result): +1 where A's score is higher, -1 where B's is, 0 on a tie, two misses included.
    A difference of two misses is undefined (nan), a comparison is not, which is why this
    compares instead of taking the sign of the differences."""
    xa, xb = pairs(a, b, a_fixed, b_fixed)
    return (xa > xb).astype(float) - (xa < xb).astype(float)


def pairs_to_decide(seq: Sequence) -> int | None:
    """The pairs a comparison needs in all for its CS to decide: its ``n`` if decided, else
    the projection of its observed values (:func:`projected_pairs`); None without values or
    out of reach. A projection, not a promise: the values to come differ from those seen."""
    return seq.n if seq.verdict in ("above", "below") else seq.projected
