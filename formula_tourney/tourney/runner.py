"""One job, in whatever process runs it: a training run or a baseline drive into its own folder.

Called by both executors (a spawned worker process or a Ray task) with a plain :class:`Job`.
A training job is ``training.loop.train`` (which writes the job folder, ``summary.json`` last);
a baseline job is the follower bot on a reference line. Parent-side helpers read a finished
folder back into the numbers the index and the promotion need (:func:`job_metrics`,
:func:`general_candidates`).
"""

from __future__ import annotations

import fnmatch
import json
import math
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from formula_tourney.safeio import atomic_write_json, atomic_write_parquet
from formula_tourney.tourney.plan import Job
from formula_tourney.tourney.store import SUMMARY_FILE, is_finished

Progress = Callable[[dict[str, Any]], None]

FAULTS_ENV = "FORMULA_TOURNEY_FAULTS"
"""Test hook: JSON {job-id glob: "raise" | "exit" | "diverge" | "sleep:<s>"} injects a failure
at the start of matching jobs (``exit`` kills the worker process with os._exit(3)), so failure
isolation and crash recovery can be tested on the real orchestration."""

TOURNEY_META_FILE = "tourney.json"
BASELINE_RESULT_FILE = "result.json"


class InjectedFault(RuntimeError):
    """Raised by the FORMULA_TOURNEY_FAULTS test hook."""


def run_job(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Run one job to completion and return its summary; raises on failure."""
    _inject_fault(job)
    if job.kind == "train":
        return _run_train(job, progress)
    if job.kind == "baseline":
        return _run_baseline(job, progress)
    raise ValueError(f"unknown job kind {job.kind!r}")


def _inject_fault(job: Job) -> None:
    raw = os.environ.get(FAULTS_ENV)
    if not raw:
        return
    for pattern, fault in json.loads(raw).items():
        if not fnmatch.fnmatchcase(job.job_id, pattern):
            continue
        if fault == "raise":
            raise InjectedFault(f"injected fault in {job.job_id}")
        if fault == "exit":
            os._exit(3)
        if fault == "diverge":
            from formula_tourney.training.loop import DivergedError

            raise DivergedError(f"injected NaN loss in {job.job_id}")
        if fault.startswith("sleep:"):
            time.sleep(float(fault.split(":", 1)[1]))


def _fresh_dir(out_dir: Path) -> None:
    """An unfinished folder is a crashed attempt: start it again from empty."""
    if out_dir.exists() and not is_finished(out_dir):
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)


def _run_train(job: Job, progress: Progress | None) -> dict[str, Any]:
    from formula_tourney.training.config import TrainConfig
    from formula_tourney.training.loop import train

    out_dir = Path(job.out_dir)
    if is_finished(out_dir):
        return json.loads((out_dir / SUMMARY_FILE).read_text(encoding="utf-8"))
    _fresh_dir(out_dir)
    atomic_write_json(out_dir / TOURNEY_META_FILE, {"job_id": job.job_id, **job.meta})
    cfg = TrainConfig(**job.config)
    from formula_tourney.agents.ddpg import configure_torch

    configure_torch(int(job.config.get("threads") or 1))
    return dict(train(cfg, out_dir, progress))


def _run_baseline(job: Job, progress: Progress | None) -> dict[str, Any]:
    import pandas as pd

    from formula_tourney.bots.follower import drive
    from formula_tourney.lines.registry import reference_offsets
    from formula_tourney.lines.speed_profile import reference_limit_s
    from formula_tourney.sim.catalog import load_track

    out_dir = Path(job.out_dir)
    result_path = out_dir / BASELINE_RESULT_FILE
    if result_path.is_file():
        return json.loads(result_path.read_text(encoding="utf-8"))
    _fresh_dir(out_dir)
    cfg = job.config
    started = time.perf_counter()
    track = load_track(cfg["track"])
    if progress:
        progress({"episode": 0, "episodes": 2, "best_lap_s": math.nan, "env_steps": 0})
    offsets = reference_offsets(track, cfg["reference"])
    run = drive(track, offsets, laps=int(cfg["laps"]))
    limit_s = float(reference_limit_s(track))
    trace = run.get("trace")
    if trace is not None:
        frame = trace if isinstance(trace, pd.DataFrame) else pd.DataFrame(trace)
        atomic_write_parquet(out_dir / "trace.parquet", frame)
    result = {
        "bot": cfg["bot"], "reference": cfg["reference"], "track": cfg["track"],
        "best_lap_s": _float(run.get("best_lap_s")),
        "lap_times_s": [float(x) for x in run.get("lap_times_s", [])],
        "damage": _float(run.get("damage")), "finished": bool(run.get("finished")),
        "reference_limit_s": limit_s, "seconds": time.perf_counter() - started,
    }
    atomic_write_json(result_path, result)
    if progress:
        progress({"episode": 2, "episodes": 2, "best_lap_s": result["best_lap_s"],
                  "env_steps": 0})
    return result


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


# ------------------------------------------------------------------ parent side: reading results


def _clean_laps(tests: Any, track: str) -> Any:
    rows = tests[(tests["track"] == track) & tests["finished"].astype(bool)]
    return rows[rows["best_lap_s"].notna()]


def job_metrics(job_dir: Path, train_track: str) -> dict[str, Any]:
    """Best clean test lap on the first train track, finished flag, damage and training time.

    Read from ``tests.parquet`` (the lap that counts for aLT/bLT); ``summary.json`` fills in
    what the tests do not hold, and is the fallback when a job wrote no tests.
    """
    import pandas as pd

    summary: dict[str, Any] = {}
    if (job_dir / SUMMARY_FILE).is_file():
        summary = json.loads((job_dir / SUMMARY_FILE).read_text(encoding="utf-8"))
    out = {
        "best_lap_s": _float(summary.get("best_lap_s")),
        "finished": bool(summary.get("finished", False)),
        "damage": _float(summary.get("damage")),
        "seconds": _float(summary.get("seconds")),
        "distance_m": math.nan,
    }
    tests_path = job_dir / "tests.parquet"
    if tests_path.is_file():
        tests = pd.read_parquet(tests_path)
        if not tests.empty and {"track", "finished", "best_lap_s"} <= set(tests.columns):
            clean = _clean_laps(tests, train_track)
            out["best_lap_s"] = float(clean["best_lap_s"].min()) if len(clean) else math.nan
            out["finished"] = bool(len(clean))
            on_track = tests[tests["track"] == train_track]
            if "distance_m" in tests.columns and len(on_track):
                out["distance_m"] = float(on_track["distance_m"].max())
    return out


def general_candidates(
    job_dir: Path, train_track: str, test_tracks: list[str], min_unseen_finish_rate: float
) -> dict[str, Any] | None:
    """The paper's general model of one run: among test rounds whose checkpoint finishes every
    unseen track (at least ``min_unseen_finish_rate`` of its starts), the one with the best clean
    lap on the train track. None when no round qualifies.
    """
    import pandas as pd

    tests_path = job_dir / "tests.parquet"
    if not tests_path.is_file():
        return None
    tests = pd.read_parquet(tests_path)
    unseen = [t for t in test_tracks if t != train_track]
    best: dict[str, Any] | None = None
    for episode, rows in tests.groupby("episode", sort=True):
        ok = True
        for track in unseen:
            on_track = rows[rows["track"] == track]
            rate = float(on_track["finished"].astype(bool).mean()) if len(on_track) else 0.0
            ok = ok and rate >= min_unseen_finish_rate
        clean = _clean_laps(rows, train_track)
        if not ok or clean.empty:
            continue
        lap_s = float(clean["best_lap_s"].min())
        if best is None or lap_s < best["train_lap_s"]:
            laps = {}
            for track in test_tracks:
                track_clean = _clean_laps(rows, track)
                laps[track] = float(track_clean["best_lap_s"].min()) if len(track_clean) else None
            checkpoint = ""
            if "checkpoint" in rows.columns:
                marks = [str(c) for c in rows["checkpoint"] if isinstance(c, str) and c]
                checkpoint = marks[0] if marks else ""
            best = {"episode": int(episode), "train_track": train_track, "train_lap_s": lap_s,
                    "laps": laps, "checkpoint": checkpoint}
    return best
