"""The training job: one seed of one entrant, ``training.loop.train`` on its run spec.

The plan builds the run specification once, in the parent (``tourney.plan.Planner.jobs``); the
worker reads it back from the job's JSON (nothing is re-validated or re-defaulted there) and the
trainer writes the job folder, ``summary.json`` last. Its result in the index is the numbers
promotion ranks on (``tourney.outcomes.job_metrics``). A done training job whose folder is gone
or holds a table that cannot be read back runs again, re-opening its part: the same seed gives
the same numbers, so the promotion made on them stands, and the report gets its files back.
An unfinished folder is started again from empty, unless it holds a resume file of the job's
configuration (``training.resume``: written on a schedule and on SIGTERM): then the run
continues from it, bit for bit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from formula_tourney.results.folder import CorruptResultError, JobFolder
from formula_tourney.results.layout import JOB_TABLES
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds.base import JobKind, Progress, fresh_dir, number
from formula_tourney.tourney.outcomes import job_metrics
from formula_tourney.tourney.plan import PlannedPart, Planner, possible_variants
from formula_tourney.tourney.store import Store
from formula_tourney.training.run_spec import RunSpec

STATUSES = ("done", "failed", "pending", "running")


class TrainKind(JobKind):
    """A training run of one entrant's seed."""

    name = "train"
    attrs = ("study", "entrant", "variant", "family", "seed", "reference", "lac", "train_tracks")
    result_fields = ("best_lap_s", "finished", "damage", "train_seconds", "test_distance_m")
    lost_files = "reopen_part"
    changed_settings = "already ran in {root} with other settings"

    def make(
        self, planner: Planner, planned: PlannedPart, store: Store, variants: list[str]
    ) -> list[Job]:
        return planner.jobs(planned.position, variants)

    def entrants(self, job: Job) -> list[str]:
        return [job.meta["entrant"]]

    def resume_jobs(
        self, planner: Planner, planned: PlannedPart, store: Store, retry_failed: bool
    ) -> list[Job]:
        """The part's jobs; for a promoted part, those of the variants the index holds."""
        if planned.variants is not None:
            return planned.jobs
        held = {r["variant"] for r in store.rows(self.name, planned.part.name)}
        possible = possible_variants(planner.spec, planned.part)
        return planner.jobs(planned.position, [v for v in possible if v in held])

    def finished(self, job: Job) -> bool:
        return JobFolder(job.out_dir).is_finished()

    def lost(self, job: Job) -> str | None:
        """Also every table of the folder (episodes, tests, laps) must read back."""
        reason = super().lost(job)
        if reason is not None:
            return reason
        folder = JobFolder(job.out_dir)
        for table in JOB_TABLES:
            try:
                folder.table(table)
            except CorruptResultError as err:
                return str(err)
        return None

    def result(self, job: Job) -> dict[str, Any]:
        metrics = job_metrics(job.out_dir, job.config_hash)
        return {
            "best_lap_s": number(metrics["best_lap_s"]),
            "finished": bool(metrics["finished"]),
            "damage": number(metrics["damage"]),
            "train_seconds": number(metrics["seconds"]),
            "test_distance_m": number(metrics["distance_m"]),
        }

    def show(self, planned: PlannedPart, rows: list[dict[str, Any]], root: Path) -> dict[str, Any]:
        """How many of the part's training jobs are in each status."""
        return {"jobs": {s: sum(r["status"] == s for r in rows) for s in STATUSES}}

    def run(self, job: Job, progress: Progress | None) -> dict[str, Any]:
        # training.loop and training.resume import torch and the env kernels: only worker
        # processes pay for them.
        from formula_tourney.training.loop import train
        from formula_tourney.training.resume import read_resume

        folder = JobFolder(job.out_dir)
        if self.lost(job) is None:
            return folder.summary()
        spec = RunSpec.from_json(job.spec, f"job {job.job_id}")
        resumed = read_resume(folder, spec)  # a preempted or killed attempt's state, if any
        if resumed is None:
            fresh_dir(folder.path)
        folder.write_tourney_meta({"job_id": job.job_id, **job.meta})
        return dict(train(spec, folder.path, progress, resume=resumed or False))

    def progress_total(self, job: Job) -> int:
        """The run's training episodes."""
        return int(job.spec.get("schedule", {}).get("episodes") or 1)
