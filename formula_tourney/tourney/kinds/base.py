"""What a job kind is: the one object that makes, runs, recognises and records its jobs.

Every job of a tournament is a :class:`~formula_tourney.tourney.jobs.Job` of some kind, and
every kind is one :class:`JobKind` in the registry (``tourney.kinds.KINDS``). The scheduler,
the runner and the store know no kind by name: they ask the job's kind object

- in the parent: which jobs a part has (:meth:`JobKind.make`), whether a job's folder already
  holds its finished result (:meth:`JobKind.finished`) and what that result is
  (:meth:`JobKind.result`, stored in the index's ``jobs.result``), which jobs must keep their
  settings on resume (:meth:`JobKind.resume_jobs`), and how a part's jobs of the kind show in a
  run's summary (:meth:`JobKind.show`);
- in the worker: how to run it (:meth:`JobKind.run`).

Who the job is (``JobKind.attrs``, keys of ``Job.meta``) goes to ``jobs.attrs``; what its
result records (``JobKind.result_fields``) to ``jobs.result`` (``results.layout``).
"""

from __future__ import annotations

import math
import shutil
from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar, Literal

from formula_tourney.results.folder import CorruptResultError
from formula_tourney.results.index import JOB_COLUMNS
from formula_tourney.safeio import make_dirs
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.plan import PlannedPart, Planner
from formula_tourney.tourney.store import Store

Progress = Callable[[dict[str, Any]], Any]
"""What a running job reports now and then: episode, episodes, best_lap_s, env_steps."""

LostFiles = Literal["rerun_if_open", "reopen_part"]
"""What a resumed run does with a job the index has as done whose folder no longer holds its
finished result (:meth:`JobKind.lost`: deleted, a file cut short, written with other settings):
``rerun_if_open`` runs it again while its part is open (and keeps the index's result in a
closed part); ``reopen_part`` runs it again and re-opens its part if that part had closed, as
it does when the index never held the job. Either way the run's summary lists it."""


class CannotRun(Exception):
    """A part's jobs of this kind cannot be made; the message becomes the part's failure."""


class JobKind(ABC):
    """One kind of job. Subclasses set the class attributes and implement the methods."""

    name: ClassVar[str]
    """The ``jobs.kind`` value and ``Job.kind``."""
    attrs: ClassVar[tuple[str, ...]]
    """Keys of ``Job.meta`` recorded in ``jobs.attrs``: who the job is."""
    result_fields: ClassVar[tuple[str, ...]]
    """Keys of :meth:`result`, recorded in ``jobs.result`` when the job is done."""
    lost_files: ClassVar[LostFiles]
    changed_settings: ClassVar[str | None] = None
    """How a resume that would give one of :meth:`resume_jobs` other settings is refused
    ("already ran ... with other settings"); None: such a job simply runs again."""

    @property
    def columns(self) -> list[str]:
        """The columns of this kind's rows as readers see them (``results.index``)."""
        return [*JOB_COLUMNS, *self.attrs, *self.result_fields]

    def index_row(self, job: Job) -> dict[str, Any]:
        """The job's ``jobs`` row as the plan knows it (status and result come later)."""
        return {"job_id": job.job_id, "kind": self.name, "part": job.part,
                "position": job.position, "path": job.meta.get("path", job.job_id),
                "config_hash": job.config_hash,
                "attrs": {k: job.meta.get(k) for k in self.attrs}}

    def entrants(self, job: Job) -> list[str]:
        """The entrants the job brings to its part's ``entrants`` (none by default)."""
        return []

    # ------------------------------------------------------------------ parent
    @abstractmethod
    def make(self, planner: Planner, planned: PlannedPart, store: Store,
             variants: list[str]) -> list[Job]:
        """The part's jobs of this kind, its entrants being ``variants`` (none: []). Raises
        :class:`CannotRun` when the part cannot have them."""

    def resume_jobs(self, planner: Planner, planned: PlannedPart, store: Store,
                    retry_failed: bool) -> list[Job]:
        """The jobs whose settings a resumed run must not change (see ``changed_settings``)."""
        return []

    @abstractmethod
    def finished(self, job: Job) -> bool:
        """Whether the job's folder holds its finished result, of this job's settings."""

    @abstractmethod
    def result(self, job: Job) -> dict[str, Any]:
        """The finished job's ``result_fields``, read from its folder; CorruptResultError
        naming the file when it cannot be read."""

    def lost(self, job: Job) -> str | None:
        """Why the job's folder no longer holds its finished result (gone, unfinished, written
        with other settings, a file that cannot be read back), else None. The index is not
        trusted alone: a resume checks the files a report will read."""
        if not Path(job.out_dir).is_dir():
            return f"its folder {job.out_dir} is missing"
        if not self.finished(job):
            return f"its folder {job.out_dir} no longer holds its finished result"
        try:
            self.result(job)
        except CorruptResultError as err:
            return str(err)
        return None

    def show(self, planned: PlannedPart, rows: list[dict[str, Any]], root: Path
             ) -> dict[str, Any]:
        """Keys this kind adds to a part's entry in a run's summary (``tourney.summary``),
        from the part's rows of this kind."""
        return {}

    # ------------------------------------------------------------------ worker
    @abstractmethod
    def run(self, job: Job, progress: Progress | None) -> dict[str, Any]:
        """Run the job to completion in a worker process; returns its summary, raises on
        failure. A job whose folder is already finished returns at once."""

    def progress_total(self, job: Job) -> int:
        """How many steps :meth:`run` reports (a progress bar's total)."""
        return 1


def fresh_dir(out_dir: Path) -> None:
    """An unfinished folder is a crashed attempt: start it again from empty."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    make_dirs(out_dir, "job folder")


def number(value: Any) -> float | None:
    """A float for the index; NaN (and anything not a number) is None, as SQLite and JSON have
    no NaN."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(value) else value
