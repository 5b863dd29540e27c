"""One job, in whatever process runs it: its kind's ``run`` (``tourney.kinds``).

Called by both executors (a spawned worker process or a Ray task) with a plain :class:`Job`.
The kind object does the work: a training run (``kinds.train``), a baseline drive
(``kinds.baseline``), a race series (``kinds.race``). This module adds what every kind shares:
the fault-injection hook the orchestration tests use.
"""

from __future__ import annotations

import fnmatch
import json
import os
import time
from typing import Any

from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds import kind_of
from formula_tourney.tourney.kinds.base import Progress

FAULTS_ENV = "FORMULA_TOURNEY_FAULTS"
"""Test hook: JSON {job-id glob: "raise" | "exit" | "diverge" | "sleep:<s>"} injects a failure
at the start of matching jobs (``exit`` kills the worker process with os._exit(3)), so failure
isolation and crash recovery can be tested on the real orchestration."""


class InjectedFault(RuntimeError):
    """Raised by the FORMULA_TOURNEY_FAULTS test hook."""


def run_job(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Run one job to completion and return its summary; raises on failure."""
    _inject_fault(job)
    return kind_of(job.kind).run(job, progress)


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
