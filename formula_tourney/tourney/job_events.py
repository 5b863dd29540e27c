"""What an executor reports about a job: the :class:`Event`, and a finished job's outcome.

Shared by every executor (the pool and Ray in ``tourney.executors``, Slurm in
``tourney.slurm_executor``) and read by the scheduler, so the executors need not know each
other. ``failed`` is the job's own failure (an exception, a crash of the process running it,
its time limit); ``lost`` means the machine under it went away (a Ray node died, a Slurm job
was cancelled or its node failed): the scheduler runs a lost job again without counting it
against ``--retries``.
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import JobFolder
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds.base import Progress
from formula_tourney.tourney.runner import run_job

EventKind = Literal["started", "progress", "done", "failed", "lost"]
THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
"""One thread each for the maths libraries of a job's process: jobs run one per core."""


@dataclass
class Event:
    """Something a job did, as seen by the scheduler."""

    kind: EventKind
    job_id: str
    slot: int
    pid: int | None = None
    info: dict[str, Any] = field(default_factory=dict)
    reason: str = ""
    wall_s: float = 0.0
    retry: bool = True
    """False for a failure that would repeat on a retry (its time limit): ``--retries`` skips it."""


def failure_reason(exc: BaseException) -> str:
    """One line for the index: the error and where it was raised (the full trace goes to a file)."""
    name = type(exc).__name__
    diverged = name == "DivergedError"
    head = f"diverged (NaN loss): {exc}" if diverged else f"{name}: {exc}"
    frames = traceback.extract_tb(exc.__traceback__)
    if frames:
        last = frames[-1]
        head += f" [at {Path(last.filename).name}:{last.lineno}]"
    return head


def timed_out_reason(timeout_s: float) -> str:
    """The index's reason for a job stopped at its time limit."""
    return f"timed out after {timeout_s:g} s"


def check_job_timeout(job_timeout_s: float | None) -> float | None:
    """``--job-timeout-s``: a positive number of seconds, or None for no limit."""
    if job_timeout_s is not None and not job_timeout_s > 0:
        raise UserInputError(f"--job-timeout-s must be > 0, got {job_timeout_s:g}")
    return job_timeout_s


def write_error(job: Job, exc: BaseException) -> None:
    """Keep the full traceback next to the job's partial output (never trusted: no summary)."""
    with contextlib.suppress(OSError):
        JobFolder(job.out_dir).write_error("".join(traceback.format_exception(exc)))


def run_to_outcome(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Run one job where a remote executor put it (a Ray task, a Slurm job) and return its
    outcome as plain data: ``ok`` with the summary, or the failure's one-line reason (the trace
    goes to the job folder); ``wall_s``, ``pid`` and ``host`` for the index and the logs."""
    started = time.perf_counter()
    where = {"pid": os.getpid(), "host": socket.gethostname()}
    try:
        summary = run_job(job, progress)
    except Exception as exc:
        write_error(job, exc)
        return {
            "ok": False,
            "reason": failure_reason(exc),
            "wall_s": time.perf_counter() - started,
            **where,
        }
    return {"ok": True, "summary": summary, "wall_s": time.perf_counter() - started, **where}
