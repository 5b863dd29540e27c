"""What a finished job folder means to the tournament: the numbers its index and promotion need.

Read in the parent through the job-folder module (``results.folder``) and computed by the one
definition of each metric (``results.metrics``), so promotion and the report agree on what a
"clean lap" and a "general model" are. A corrupt file raises ``CorruptResultError`` naming it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from formula_tourney.results.folder import BaselineFolder, CorruptResultError, JobFolder
from formula_tourney.results.metrics import general_model, model_table, run_metrics
from formula_tourney.training.run_spec import RunSpec


def run_spec(job_dir: str | Path) -> RunSpec:
    """The run specification a job folder was trained with (its config.json)."""
    folder = JobFolder(job_dir)
    return RunSpec.from_json(folder.config(), str(folder.config_path))


def job_metrics(job_dir: str | Path, config_hash: str | None = None) -> dict[str, Any]:
    """Best clean test lap on the key track, finished flag, distance, damage and train time.

    The lap and the distance come from ``tests.parquet`` through ``results.metrics.run_metrics``
    (the lap that counts for aLT/bLT); damage and seconds from ``summary.json``. With
    ``config_hash`` the folder must hold that run: a finished folder of other settings (left by
    an earlier version of the file, found again by a rebuilt index) is never adopted.
    """
    folder = JobFolder(job_dir)
    spec = run_spec(job_dir)
    if config_hash and spec.digest() != config_hash:
        raise CorruptResultError(
            f"{folder.config_path}: this finished job was trained with other settings than the "
            "tournament file gives it now"
        )
    summary = folder.summary()
    metrics = run_metrics(folder.tests(), spec.key_track)
    return {
        "best_lap_s": metrics["best_lap_s"],
        "finished": metrics["finished"],
        "distance_m": metrics["distance_m"],
        "damage": _float(summary.get("damage")),
        "seconds": _float(summary.get("seconds")),
    }


def general_pick(
    job_dir: str | Path, job_id: str, train_track: str, test_tracks: list[str],
    min_unseen_finish_rate: float,
) -> dict[str, Any] | None:
    """The paper's general model of one run (``results.metrics.general_model``), or None.

    Lap times of tracks without a clean lap are None (the index stores JSON, which has no NaN).
    """
    tests = JobFolder(job_dir).tests()
    if tests.empty:
        return None
    pick = general_model(model_table(tests.assign(job_id=job_id)), train_track, test_tracks,
                         min_unseen_finish_rate)
    if pick is None:
        return None
    pick["laps"] = {t: (None if v is None or not math.isfinite(v) else float(v))
                    for t, v in pick["laps"].items()}
    return pick


def baseline_result(out_dir: str | Path) -> dict[str, Any]:
    """A finished baseline drive's result.json."""
    return BaselineFolder(out_dir).result()


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
