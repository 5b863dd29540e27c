"""One job, in whatever process runs it: a training run, a baseline drive or a race part's series.

Called by both executors (a spawned worker process or a Ray task) with a plain :class:`Job`.
A training job is ``training.loop.train`` on the job's run specification, read back from its
JSON as the parent built it (nothing is re-validated or re-defaulted here); the trainer writes
the job folder, ``summary.json`` last. A baseline job is ``bots.baselines.bot_report``: the
follower bot on a reference line, with the track's reference limit. A race job is
``tourney.race_worker.run_race_job``: it keeps its finished races, unlike the others' folders.
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

import pandas as pd

from formula_tourney.results.folder import BaselineFolder, JobFolder
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.catalog import load_track
from formula_tourney.tourney.jobs import Job
from formula_tourney.training.spec import RunSpec

Progress = Callable[[dict[str, Any]], Any]

FAULTS_ENV = "FORMULA_TOURNEY_FAULTS"
"""Test hook: JSON {job-id glob: "raise" | "exit" | "diverge" | "sleep:<s>"} injects a failure
at the start of matching jobs (``exit`` kills the worker process with os._exit(3)), so failure
isolation and crash recovery can be tested on the real orchestration."""


class InjectedFault(RuntimeError):
    """Raised by the FORMULA_TOURNEY_FAULTS test hook."""


def run_job(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Run one job to completion and return its summary; raises on failure."""
    _inject_fault(job)
    if job.kind == "train":
        return _run_train(job, progress)
    if job.kind == "baseline":
        return _run_baseline(job, progress)
    if job.kind == "race":
        # the races load checkpoints (torch) and the race kernels: worker processes only
        from formula_tourney.tourney.race_worker import run_race_job

        return run_race_job(job, progress)
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
            # training.loop imports torch: only worker processes pay for it.
            from formula_tourney.training.loop import DivergedError

            raise DivergedError(f"injected NaN loss in {job.job_id}")
        if fault.startswith("sleep:"):
            time.sleep(float(fault.split(":", 1)[1]))


def _fresh_dir(out_dir: Path) -> None:
    """An unfinished folder is a crashed attempt: start it again from empty."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)


def _run_train(job: Job, progress: Progress | None) -> dict[str, Any]:
    # training.loop imports torch and the env kernels: only worker processes pay for them.
    from formula_tourney.training.loop import train

    folder = JobFolder(job.out_dir)
    if folder.is_finished():
        return folder.summary()
    spec = RunSpec.from_json(job.spec, f"job {job.job_id}")
    _fresh_dir(folder.path)
    folder.write_tourney_meta({"job_id": job.job_id, **job.meta})
    return dict(train(spec, folder.path, progress))


def _run_baseline(job: Job, progress: Progress | None) -> dict[str, Any]:
    # The bots import numba kernels and the line solvers: worker processes only.

    from formula_tourney.bots.baselines import bot_report

    folder = BaselineFolder(job.out_dir)
    if folder.holds(job.config_hash):
        return folder.result()
    _fresh_dir(folder.path)
    task = job.spec
    started = time.perf_counter()
    if progress:
        progress({"episode": 0, "episodes": 2, "best_lap_s": math.nan, "env_steps": 0})
    report = bot_report(load_track(task["track"]), task["reference"], laps=int(task["laps"]),
                        car=CarParams(**task.get("car", {})))
    trace = report.get("_trace")
    if trace is not None:
        folder.write_trace(trace if isinstance(trace, pd.DataFrame) else pd.DataFrame(trace))
    result = {
        "bot": task["bot"], "reference": task["reference"], "track": task["track"],
        "best_lap_s": _float(report.get("best_lap_s")),
        "lap_times_s": [float(x) for x in report.get("laps", [])],
        "damage": _float(report.get("damage")), "finished": bool(report.get("finished")),
        "reference_limit_s": _float(report.get("reference_limit_s")),
        "seconds": time.perf_counter() - started,
        "car": dict(task.get("car", {})), "config_hash": job.config_hash,
    }  # fmt: skip
    folder.write_result(result)
    if progress:
        progress({"episode": 2, "episodes": 2, "best_lap_s": result["best_lap_s"],
                  "env_steps": 0})
    return result


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
