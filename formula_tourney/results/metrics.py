"""The lap-time metrics every table, figure and promotion rule reads: one definition each.

- A *model* is one tested checkpoint: a run's policy at one test round (``episode``) on one
  track, driven from several starts.
- A model's *clean lap* is its best timed lap when it took no damage over all its starts (the
  paper's "models with 0 damage"); nan otherwise.
- A run's *best lap* (the seed's entry in bLT/aLT) is its fastest clean lap over its models.
- **bLT** is the best of the runs' best laps; **aLT** the mean of the runs' best laps, over the
  runs that have one.
- The *gap* of a lap is how much slower than the track's reference limit it is, in percent.
- The *general model* of a run (the paper's Table 3): among its models that have a clean lap on
  the train track and finish a lap from at least ``min_unseen_finish_rate`` of the starts on
  every unseen test track, the one with the fastest train-track lap. A run that is never tested
  on its train track (one trained on many generated tracks, tested only on tracks it never
  saw) has no train-track lap to rank by: its general model is the one with a clean lap on the
  most unseen test tracks, the least sum of those laps breaking a tie (:func:`general_rank`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

MODEL_KEYS = ["job_id", "episode", "track"]
RUN_INFO = ["part", "entrant", "variant", "family", "seed", "reference", "lac"]


def model_clean_lap_s(best_laps_s: Sequence[float], damages: Sequence[float]) -> float:
    """The clean lap of one model from its drives (one per start): the best timed lap when the
    drives took no damage at all, else nan. ``model_table`` applies this rule to whole tables;
    the trainer applies it as it tests (best checkpoint, trace, progress)."""
    if float(np.sum(np.asarray(damages, dtype=float))) > 0.0:
        return math.nan
    laps = np.asarray(best_laps_s, dtype=float)
    laps = laps[np.isfinite(laps)]
    return float(laps.min()) if laps.size else math.nan


def model_table(tests: pd.DataFrame) -> pd.DataFrame:
    """One row per model (job, test round, track): best lap over starts, damage, finish rate and
    ``clean_lap_s``. ``tests`` needs a ``job_id`` column (one job's table gets it added)."""
    info = [c for c in RUN_INFO if c in tests.columns]
    columns = [*MODEL_KEYS, "best_lap_s", "damage", "finished", "finish_rate", "starts",
               "distance_m", *info, "checkpoint", "clean_lap_s"]  # fmt: skip
    if tests.empty:
        return pd.DataFrame(columns=columns)
    frame = tests.copy()
    frame["damage"] = pd.to_numeric(frame["damage"], errors="coerce").fillna(0.0)
    frame["best_lap_s"] = pd.to_numeric(frame["best_lap_s"], errors="coerce")
    frame["finished"] = frame["finished"].astype(bool)
    if "distance_m" not in frame.columns:
        frame["distance_m"] = np.nan
    if "checkpoint" not in frame.columns:
        frame["checkpoint"] = ""
    frame["checkpoint"] = frame["checkpoint"].fillna("").astype(str)
    grouped = frame.groupby(MODEL_KEYS, sort=False, dropna=False)
    models = grouped.agg(
        best_lap_s=("best_lap_s", "min"), damage=("damage", "sum"),
        finished=("finished", "any"), finish_rate=("finished", "mean"),
        starts=("finished", "size"), distance_m=("distance_m", "max"),
        checkpoint=("checkpoint", "max"),
    )  # fmt: skip
    if info:
        models = models.join(grouped[info].first())
    models = models.reset_index()
    # model_clean_lap_s, vectorised: the best lap where the summed damage is zero
    models["clean_lap_s"] = models["best_lap_s"].where(models["damage"] <= 0.0)
    return models[columns]


def run_table(models: pd.DataFrame) -> pd.DataFrame:
    """One row per run and track: its best clean lap, summed test damage, models tested, the
    round of the best lap and the longest distance a test covered."""
    columns = ["job_id", "track", "run_best_s", "damage", "models", "best_episode", "distance_m"]
    if models.empty:
        return pd.DataFrame(columns=columns)
    rows = []
    for (job_id, track), grp in models.groupby(["job_id", "track"], sort=False):
        clean = grp["clean_lap_s"]
        has = bool(clean.notna().any())
        rows.append({
            "job_id": job_id, "track": track,
            "run_best_s": float(clean.min()) if has else math.nan,
            "damage": float(grp["damage"].sum()), "models": len(grp),
            "best_episode": float(grp.loc[clean.idxmin(), "episode"]) if has else math.nan,
            "distance_m": float(pd.to_numeric(grp["distance_m"], errors="coerce").max()),
        })  # fmt: skip
    return pd.DataFrame(rows, columns=columns)


def blt_alt(run_best_s: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """(bLT, aLT) of the runs' best laps; nan where no run has a clean lap."""
    laps = np.asarray(run_best_s, dtype=float)
    laps = laps[np.isfinite(laps)]
    if laps.size == 0:
        return math.nan, math.nan
    return float(laps.min()), float(laps.mean())


def limit_ratio(lap_s: float, limit_s: float) -> float:
    """Lap time over the reference limit ``limit_s`` (1.00 = at the limit); nan when either is
    missing."""
    if not (math.isfinite(lap_s) and math.isfinite(limit_s)) or limit_s <= 0:
        return math.nan
    return lap_s / limit_s


def gap_pct(lap_s: float, limit_s: float) -> float:
    """How much slower than the reference limit ``limit_s`` a lap is, in percent; nan when
    either is missing."""
    return 100.0 * (limit_ratio(lap_s, limit_s) - 1.0)


def at_grip(tests: pd.DataFrame, grip_scale: float) -> pd.DataFrame:
    """The test rows (``tests.parquet``, every grip) that ran at ``grip_scale``."""
    return tests.loc[pd.to_numeric(tests["grip_scale"], errors="coerce") == grip_scale]


def stored_limit_s(tests: pd.DataFrame, track: str, grip_scale: float) -> float:
    """The reference limit of ``track`` at ``grip_scale`` as the jobs stored it with their tests
    (``reference_limit_s``, computed once per job, track and grip by the trainer); nan when no
    job stored one."""
    rows = at_grip(tests, grip_scale)
    vals = pd.to_numeric(rows.loc[rows["track"].astype(str) == track, "reference_limit_s"],
                         errors="coerce").dropna()
    return float(vals.iloc[0]) if not vals.empty else math.nan


def run_metrics(tests: pd.DataFrame, train_track: str) -> dict[str, Any]:
    """What the index and the promotion need from one run's tests on its train track."""
    frame = tests.assign(job_id="run") if "job_id" not in tests.columns else tests
    runs = run_table(model_table(frame[frame["track"] == train_track]))
    if runs.empty:
        return {"best_lap_s": math.nan, "finished": False, "distance_m": math.nan}
    row = runs.iloc[0]
    best = float(row["run_best_s"])
    return {"best_lap_s": best, "finished": bool(math.isfinite(best)),
            "distance_m": float(row["distance_m"])}


def unseen_clean_laps(laps: Mapping[str, float | None], train_track: str) -> list[float]:
    """A model's clean laps (s) on the tracks other than ``train_track``; a track without one
    (nan, or None as the index stores it) is left out."""
    return [float(v) for t, v in laps.items()
            if t != train_track and v is not None and math.isfinite(v)]  # fmt: skip


def general_rank(train_lap_s: float | None, laps: Mapping[str, float | None],
                 train_track: str) -> tuple[float, float]:
    """Sort key of a general model candidate, lowest first: its train-track lap where it has
    one (every candidate of such a run meets the unseen-track rule, so the lap decides); else
    minus the unseen tracks it laps cleanly, then the sum of those laps (s)."""
    if train_lap_s is not None and math.isfinite(train_lap_s):
        return 0.0, float(train_lap_s)
    clean = unseen_clean_laps(laps, train_track)
    return -float(len(clean)), float(sum(clean))


def general_model(
    models: pd.DataFrame,
    train_track: str,
    test_tracks: Sequence[str],
    min_unseen_finish_rate: float,
) -> dict[str, Any] | None:
    """The general model among ``models`` (one run's or several runs'), or None.

    Returns job_id, episode, checkpoint, the train-track lap (nan when the run was never tested
    on its train track), the clean lap per test track and how many unseen tracks it lapped
    cleanly (``unseen_lapped``, of ``unseen``).
    """
    if models.empty:
        return None
    unseen = [t for t in test_tracks if t != train_track]
    train_tested = bool((models["track"].astype(str) == train_track).any())
    best: dict[str, Any] | None = None
    for (job_id, episode), rows in models.groupby(["job_id", "episode"], sort=True):
        by_track = rows.set_index("track")
        laps = {t: (float(by_track.loc[t, "clean_lap_s"]) if t in by_track.index
                    else math.nan) for t in test_tracks}  # fmt: skip
        lapped = len(unseen_clean_laps(laps, train_track))
        if train_tested:
            lap_s = (float(by_track.loc[train_track, "clean_lap_s"])
                     if train_track in by_track.index else math.nan)
            if not math.isfinite(lap_s) or any(
                    t not in by_track.index
                    or float(by_track.loc[t, "finish_rate"]) < min_unseen_finish_rate
                    for t in unseen):  # fmt: skip
                continue
        else:
            lap_s = math.nan
            if not lapped:
                continue
        rank = general_rank(lap_s, laps, train_track)
        if best is None or rank < general_rank(best["train_lap_s"], best["laps"], train_track):
            marks = [str(c) for c in rows["checkpoint"] if isinstance(c, str) and c]
            best = {"job_id": str(job_id), "episode": int(episode), "train_track": train_track,
                    "train_lap_s": lap_s, "laps": laps, "checkpoint": marks[0] if marks else "",
                    "unseen_lapped": lapped, "unseen": len(unseen)}
    return best
