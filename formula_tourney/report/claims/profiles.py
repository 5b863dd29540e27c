"""Performance profiles (Agarwal et al. 2021, rliable's view): the share of runs whose best lap
is within ``tau`` times the track's reference limit, for every ``tau``.

A run's ratio is its best clean lap on its first train track (``Context.runs``, the metric of
every table) divided by that track's reference limit (``Context.limits``, from the baseline
drives); a run without a clean lap has ratio ``inf`` and never counts. One curve is one entrant
(``report.claims.entrants``: runs alike in variant, line, train track and setup), so runs of
two presets or two tracks are never one curve. A run repeating another's
training (``report.claims.training_key``: same seed and settings, other tests) is the same
model and counts once, as in the claims. The band is a percentile bootstrap over runs, seeded
like the report's other intervals.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from formula_tourney.report import stats
from formula_tourney.report.claims.entrants import entrant_labels
from formula_tourney.report.claims.evaluate import training_key
from formula_tourney.report.paper_tables import Context


def run_ratios(ctx: Context) -> pd.DataFrame:
    """One row per run with a reference limit on its first train track: job_id, group (its
    entrant's label), setup (what it adds to the paper's, "" for none), track, best lap and
    ratio (inf without a clean lap)."""
    groups = entrant_labels(ctx)
    rows = []
    seen: set[str] = set()
    for _, job in ctx.jobs.iterrows():
        key = training_key(ctx, str(job["job_id"]))
        if key and key in seen:
            continue
        if key:
            seen.add(key)
        tracks = job["train_tracks"]
        track = str(tracks[0]) if len(tracks) else ""
        limit = ctx.limits.get(track, math.nan)
        run = ctx.runs.loc[(ctx.runs["job_id"] == job["job_id"])
                           & (ctx.runs["track"].astype(str) == track)]
        if run.empty or not math.isfinite(limit) or limit <= 0:
            continue
        lap = float(run["run_best_s"].min())
        job_id = str(job["job_id"])
        rows.append({"job_id": job_id, "group": groups[job_id],
                     "setup": ", ".join(ctx.data.beyond_paper.get(job_id) or []), "track": track,
                     "lap_s": lap, "ratio": lap / limit if math.isfinite(lap) else math.inf})
    return pd.DataFrame(rows, columns=["job_id", "group", "setup", "track", "lap_s", "ratio"])


def profile(ratios: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Fraction of runs with ratio <= tau, for each tau (runs without a lap never count)."""
    arr = np.asarray(ratios, dtype=float)
    if arr.size == 0:
        return np.full(np.shape(taus), np.nan)
    return (arr[None, :] <= np.asarray(taus, dtype=float)[:, None]).mean(axis=1)


def profile_band(ratios: np.ndarray, taus: np.ndarray, n_resamples: int = 2000,
                 seed: int = stats.DEFAULT_SEED) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(profile, low, high): the profile with a 95 % percentile bootstrap band over runs (no
    band for a single run)."""
    arr = np.asarray(ratios, dtype=float)
    mid = profile(arr, taus)
    if arr.size < 2:
        return mid, np.full_like(mid, np.nan), np.full_like(mid, np.nan)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, arr.size, size=(n_resamples, arr.size))
    boot = (arr[idx][:, None, :] <= np.asarray(taus, dtype=float)[None, :, None]).mean(axis=2)
    low, high = np.quantile(boot, [0.025, 0.975], axis=0)
    return mid, low, high


def tau_grid(ratios: np.ndarray, points: int = 200) -> np.ndarray:
    """From the limit (1) to just past the slowest finite ratio."""
    finite = np.asarray(ratios, dtype=float)
    finite = finite[np.isfinite(finite)]
    top = max(1.05, float(finite.max()) * 1.01) if finite.size else 1.5
    return np.linspace(min(1.0, float(finite.min()) if finite.size else 1.0), top, points)
