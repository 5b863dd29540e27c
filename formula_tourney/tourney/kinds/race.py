"""The race series: a race part's one job, all its races in one worker (``tourney.race_part``).

Made once the part's source has promoted (who races with which checkpoint is the parent's,
``tourney.race_part.race_job``), run by ``tourney.race_worker``; its results are the race files
under ``<part>/_races/`` (the index records its status only, the standings are the report's). A
series whose files are incomplete (a race file deleted) or of other settings races again, and
its part re-opens; a resume that would race other entrants or settings than a finished series
is refused (unless ``--retry-failed`` re-promotes, which expects a new series).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from formula_tourney.results.folder import CorruptResultError, RaceFolder
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds.base import CannotRun, JobKind, Progress
from formula_tourney.tourney.kinds.train import TrainKind
from formula_tourney.tourney.plan import PlannedPart, Planner
from formula_tourney.tourney.race_part import race_job, series_complete
from formula_tourney.tourney.store import Store


class RaceKind(JobKind):
    """A race part's whole series."""

    name = "race"
    attrs = ("track", "races", "entrants")
    result_fields = ()
    lost_files = "reopen_part"
    changed_settings = "already raced in {root} with other entrants or race settings"

    def make(self, planner: Planner, planned: PlannedPart, store: Store,
             variants: list[str]) -> list[Job]:
        if planned.part.kind != "race":
            return []
        job = race_job(planner, planned.position, _trained(store, planned), variants)
        cars = len(job.meta["entrants"])
        if cars < 2:
            raise CannotRun(f"{cars} car(s) to race (promoted entrants with a checkpoint, and "
                            "bots); a race needs two")
        return [job]

    def entrants(self, job: Job) -> list[str]:
        return list(job.meta["entrants"])

    def resume_jobs(self, planner: Planner, planned: PlannedPart, store: Store,
                    retry_failed: bool) -> list[Job]:
        """The series of the promotion the index holds, once it has raced (none under
        ``retry_failed``, and none that has not finished: it may race anew)."""
        part = planned.part
        if retry_failed or part.kind != "race":
            return []
        source = store.part(str(part.promoted_from)) or {}
        variants = (source.get("promoted") or {}).get(part.name)
        if variants is None:
            return []
        job = race_job(planner, planned.position, _trained(store, planned), list(variants))
        return [job] if (store.job(job.job_id) or {}).get("status") == "done" else []

    def finished(self, job: Job) -> bool:
        return series_complete(job)

    def result(self, job: Job) -> dict[str, Any]:
        if not series_complete(job):
            raise CorruptResultError(f"{job.out_dir}: the race series ended without all its "
                                     "race files and series.json")
        return {}

    def show(self, planned: PlannedPart, rows: list[dict[str, Any]], root: Path
             ) -> dict[str, Any]:
        """A race part's series: the index's status and the race files on disk."""
        if planned.part.kind != "race":
            return {"race": None}
        row = rows[0] if rows else {"status": "waiting", "races": None, "entrants": [],
                                    "path": None, "reason": None}
        raced = len(RaceFolder(root / row["path"]).race_numbers()) if row["path"] else 0
        return {"race": {"status": row["status"], "reason": row["reason"],
                         "races": row["races"], "raced": raced,
                         "entrants": row["entrants"] or [], "path": row["path"]}}

    def run(self, job: Job, progress: Progress | None) -> dict[str, Any]:
        # the races load checkpoints (torch) and the race kernels: worker processes only
        from formula_tourney.tourney.race_worker import run_race_job

        return run_race_job(job, progress)

    def progress_total(self, job: Job) -> int:
        """The series' races."""
        return int(job.spec.get("races") or 1)


def _trained(store: Store, planned: PlannedPart) -> list[dict[str, Any]]:
    """The index rows of the training jobs of the race part's source part."""
    return store.rows(TrainKind.name, str(planned.part.promoted_from))
