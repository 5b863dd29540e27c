"""The baseline drive: a bot on a reference line of one test track (``bots.baselines``).

A part's baselines (``tourney.plan.Planner.baselines``) anchor its lap times: the follower bot
on the part's car, with the track's reference limit. The drive writes ``result.json`` with its
config hash (``results.folder.BaselineFolder``), which is also its result in the index; a folder
of other settings is driven again while its part is open.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.results.folder import BaselineFolder
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.catalog import load_track
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds.base import JobKind, Progress, fresh_dir, number
from formula_tourney.tourney.outcomes import baseline_result
from formula_tourney.tourney.plan import PlannedPart, Planner
from formula_tourney.tourney.store import Store

SHOWN = ("bot", "reference", "track", "best_lap_s", "reference_limit_s", "finished", "status")


class BaselineKind(JobKind):
    """One bot's drive on one track of a part."""

    name = "baseline"
    attrs = ("bot", "track", "reference")
    result_fields = ("best_lap_s", "damage", "finished", "reference_limit_s")
    lost_files = "rerun_if_open"

    def make(self, planner: Planner, planned: PlannedPart, store: Store,
             variants: list[str]) -> list[Job]:
        """The part's drives; none in a race part, whose bots race instead."""
        return [] if planned.part.kind == "race" else list(planned.baselines)

    def finished(self, job: Job) -> bool:
        return BaselineFolder(job.out_dir).holds(job.config_hash)

    def result(self, job: Job) -> dict[str, Any]:
        result = baseline_result(job.out_dir)
        return {"best_lap_s": number(result.get("best_lap_s")),
                "damage": number(result.get("damage")),
                "finished": bool(result.get("finished")),
                "reference_limit_s": number(result.get("reference_limit_s"))}

    def show(self, planned: PlannedPart, rows: list[dict[str, Any]], root: Path
             ) -> dict[str, Any]:
        """The part's drives: bot, line, track, lap, reference limit, status."""
        return {"baselines": [{k: r.get(k) for k in SHOWN} for r in rows]}

    def run(self, job: Job, progress: Progress | None) -> dict[str, Any]:
        # The bots import numba kernels and the line solvers: worker processes only.
        from formula_tourney.bots.baselines import bot_report

        folder = BaselineFolder(job.out_dir)
        if folder.holds(job.config_hash):
            return folder.result()
        fresh_dir(folder.path)
        task = job.spec
        started = time.perf_counter()
        if progress:
            progress({"episode": 0, "episodes": 2, "best_lap_s": math.nan, "env_steps": 0})
        report = bot_report(load_track(task["track"]), task["reference"],
                            laps=int(task["laps"]), car=CarParams(**task.get("car", {})))
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

    def progress_total(self, job: Job) -> int:
        """Two steps: started, driven."""
        return 2


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
