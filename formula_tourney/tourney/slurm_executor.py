"""Jobs as Slurm jobs through submitit (``--executor slurm``), or submitit's local processes
(``--executor slurm-local``); both report the scheduler's events.

The parent buffers the jobs the scheduler submits and sends them, each time it polls, as one
job array (``sbatch --array=...%max_parallel``); each array task unpickles
:class:`SlurmJobCall` and runs ``tourney.runner.run_job`` on the node. The parent then polls
``squeue`` (one call for every job it holds; ``sacct`` needs the accounting daemon, which many
small clusters lack) and reads the result pickle submitit writes when a task ends:

- RUNNING the first time: ``started``; a finished task: ``done`` or ``failed`` from its result;
- a task that ended without a result because of the machine (cancelled with ``scancel``,
  preempted, its node failed): ``lost``, and the scheduler submits the job again;
- without a result because of the job (its Slurm time limit after the requeues, out of memory,
  a crash): ``failed``, with the state and where its log is.

Requeue on preemption or time-out is submitit's: Slurm signals the task (USR2) before its time
limit, :meth:`SlurmJobCall.checkpoint` hands back the same call, and submitit requeues it under
the same job id; the job then starts again from its own folder (a training run continues from
its resume file), so the parent just keeps polling the same id. ``job_timeout_s`` is the
tournament's own limit: a job past it is cancelled (``scancel``) and failed, "timed out after
N s". Every job of one results folder carries one job name, so a run that resumes after its
parent was killed first cancels the jobs that parent left queued or running.

submitit is the optional extra ``formula-tourney[slurm]``, imported here only when used.
"""

from __future__ import annotations

import contextlib
import getpass
import hashlib
import importlib
import os
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.job_events import (
    THREAD_ENV,
    Event,
    EventKind,
    run_to_outcome,
    timed_out_reason,
)
from formula_tourney.tourney.jobs import Job

SlurmCluster = Literal["slurm", "local"]

WAITING_STATES = frozenset({
    "PENDING", "CONFIGURING", "REQUEUED", "REQUEUE_HOLD", "REQUEUE_FED", "RESV_DEL_HOLD",
    "SUSPENDED", "STOPPED", "RESIZING", "SPECIAL_EXIT",
})  # fmt: skip
"""Queued, or requeued (preempted, or checkpointed at its time limit): still the same job."""
ACTIVE_STATES = frozenset({"RUNNING", "COMPLETING", "SIGNALING", "STAGE_OUT"})
"""Running, or its processes are still being stopped: the job folder may still be written."""
LOST_STATES = frozenset({"CANCELLED", "PREEMPTED", "NODE_FAIL", "BOOT_FAIL", "DEADLINE",
                         "REVOKED"})  # fmt: skip
"""Ended without a result because of the machine, not the job: the job runs again."""
RESULT_WAIT_S = 30.0
"""How long a task Slurm calls COMPLETED may take to show its result file (a shared file
system's attribute cache) before it counts as failed."""
RUNNING_LINE = "formula-tourney: running"
"""Start of the line a task prints to its log when its job starts (after submitit's signal
handlers are in place)."""
LEFTOVER_WAIT_S = 120.0
"""Longest wait for the cancelled jobs of a killed earlier parent to stop (Slurm's KillWait is
30 s by default)."""
QUERY_EVERY_S = 2.0
"""Least seconds between two ``squeue`` calls: slurmctld serves every user of the cluster."""


class SlurmSettings(BaseModel):
    """What each Slurm job asks for, from the ``run --slurm-*`` options (validated once here)."""

    model_config = ConfigDict(extra="forbid")

    partition: str | None = Field(
        None,
        min_length=1,
        description="Partition the jobs go to (sbatch --partition); default: the cluster's "
        "default partition.",
    )
    time_min: int = Field(
        60,
        ge=1,
        description="Time limit of one job in minutes (sbatch --time). A job that reaches it is "
        "checkpointed and requeued by submitit (up to 3 times) and continues from its own files.",
    )
    mem_gb: float = Field(4.0, gt=0, description="Memory of one job in GB (sbatch --mem).")
    cpus_per_job: int = Field(1, ge=1, description="CPUs of one job (sbatch --cpus-per-task).")
    max_parallel: int = Field(
        8,
        ge=1,
        description="Jobs queued or running at once: the job array's concurrency cap "
        "(sbatch --array=...%N, submitit's slurm_array_parallelism).",
    )


def slurm_settings(**values: Any) -> SlurmSettings:
    """:class:`SlurmSettings` from the CLI's values (None: the default); a bad one is a
    UserInputError naming its option."""
    try:
        return SlurmSettings(**{k: v for k, v in values.items() if v is not None})
    except ValidationError as err:
        first = err.errors()[0]
        option = "--slurm-" + str(first["loc"][0]).replace("_", "-")
        raise UserInputError(f"{option}: {first['msg']}") from None


def job_name(results_root: Path) -> str:
    """The Slurm job name of every job of one results folder (its name plus a digest of its
    path): it tells this folder's jobs from any other run's."""
    digest = hashlib.sha256(str(results_root.resolve()).encode()).hexdigest()[:8]
    return f"ft-{results_root.name}-{digest}"


def _submitit() -> Any:
    try:
        return importlib.import_module("submitit")
    except ImportError:
        raise UserInputError(
            "--executor slurm needs the optional extra: pip install 'formula-tourney[slurm]'"
        ) from None


class SlurmJobCall:
    """What a Slurm task runs: one job, its outcome returned as plain data.

    ``checkpoint`` is submitit's ``helpers.Checkpointable`` contract (written out here so that
    submitit is imported only where it runs): at preemption or at the time limit submitit calls
    it and requeues the returned call, the same job, which continues from its own folder.
    """

    def __call__(self, job: Job) -> dict[str, Any]:
        # the task's log says which job it runs (submitit's own lines name only the task)
        print(f"{RUNNING_LINE} {job.job_id} in {job.out_dir}", flush=True)
        return run_to_outcome(job)

    def checkpoint(self, job: Job) -> Any:
        helpers = importlib.import_module("submitit.helpers")
        return helpers.DelayedSubmission(self, job)


@dataclass
class _Held:
    """A job the executor submitted and has not yet reported ended."""

    slot: int
    job: Job
    handle: Any
    """The submitit job."""
    submitted: float
    running_since: float | None = None
    ended_since: float | None = None
    """When a COMPLETED state was first seen without a result file yet."""


class SlurmExecutor:
    """Jobs as Slurm job arrays (``cluster="slurm"``) or submitit's local processes
    (``cluster="local"``: the same code path, no Slurm), at most ``max_parallel`` at once."""

    def __init__(
        self,
        settings: SlurmSettings,
        folder: Path,
        name: str,
        cluster: SlurmCluster = "slurm",
        job_timeout_s: float | None = None,
    ) -> None:
        self.settings = settings
        self.workers = settings.max_parallel
        self.folder = folder
        self.name = name
        self.cluster = cluster
        self.job_timeout_s = job_timeout_s
        self._submitit = _submitit()
        if cluster == "slurm":
            _check_cluster(settings)
        self._executor: Any = None
        self._slots: list[Job | None] = [None] * self.workers
        self._buffer: list[tuple[int, Job]] = []
        self._held: dict[str, _Held] = {}
        self._queried_at = 0.0

    def start(self) -> None:
        for key in THREAD_ENV:  # sbatch and the local processes pass the environment on
            os.environ.setdefault(key, "1")
        self.folder.mkdir(parents=True, exist_ok=True)
        if self.cluster == "slurm":
            self._cancel_leftovers()
        executor = self._submitit.AutoExecutor(folder=self.folder, cluster=self.cluster)
        settings = self.settings
        params: dict[str, Any] = {
            "name": self.name,
            "timeout_min": settings.time_min,
            "mem_gb": settings.mem_gb,
            "cpus_per_task": settings.cpus_per_job,
            "slurm_array_parallelism": settings.max_parallel,
        }
        if settings.partition:
            params["slurm_partition"] = settings.partition
        executor.update_parameters(**params)
        self._executor = executor

    def _cancel_leftovers(self) -> None:
        """Cancel the jobs of this results folder that a killed earlier parent left queued or
        running (the run's lock says no live parent follows them), and wait until Slurm has
        stopped their processes, so no two attempts of one job write its folder at once."""
        mine = [f"--name={self.name}", f"--user={getpass.getuser()}"]
        subprocess.run(["scancel", *mine], capture_output=True, check=False)
        deadline = time.monotonic() + LEFTOVER_WAIT_S
        while time.monotonic() < deadline:
            out = subprocess.run(["squeue", "-h", "-o", "%i", *mine], capture_output=True,
                                 text=True, check=False)  # fmt: skip
            if out.returncode != 0 or not out.stdout.strip():
                return
            time.sleep(1.0)

    def free_slots(self) -> int:
        return sum(1 for job in self._slots if job is None)

    def submit(self, job: Job) -> int:
        slot = self._slots.index(None)
        self._slots[slot] = job
        self._buffer.append((slot, job))
        return slot

    def poll(self, timeout_s: float) -> list[Event]:
        events: list[Event] = []
        self._flush(events)
        time.sleep(timeout_s)
        if not self._held or time.monotonic() - self._queried_at < self._query_every_s():
            return events
        self._queried_at = time.monotonic()
        states = self._query()
        if states is None:
            return events  # slurmctld did not answer: ask again at the next poll
        for held in list(self._held.values()):
            self._follow(held, states.get(held.handle.job_id), events)
        self._stop_overdue(events)
        return events

    def _query_every_s(self) -> float:
        return QUERY_EVERY_S if self.cluster == "slurm" else 0.0

    def _flush(self, events: list[Event]) -> None:
        """Send the buffered jobs as one job array."""
        if not self._buffer:
            return
        batch, self._buffer = self._buffer, []
        try:
            with self._executor.batch():
                handles = [self._executor.submit(SlurmJobCall(), job) for _slot, job in batch]
        except Exception as exc:  # sbatch refused: those jobs fail, the rest goes on
            first = str(exc).strip().splitlines()
            for slot, job in batch:
                self._slots[slot] = None
                events.append(
                    Event(
                        "failed",
                        job.job_id,
                        slot,
                        reason=f"sbatch failed: {first[-1] if first else exc}",
                    )
                )
            return
        now = time.monotonic()
        for (slot, job), handle in zip(batch, handles, strict=True):
            self._held[job.job_id] = _Held(slot, job, handle, now)

    def _query(self) -> dict[str, str] | None:
        """State of every held job: ``squeue`` for Slurm (jobs it no longer knows are left
        out; None when slurmctld did not answer, so that no running job is taken for lost),
        the process for submitit's local jobs."""
        if self.cluster == "local":
            return {h.handle.job_id: h.handle.get_info()["jobState"] for h in self._held.values()}
        ids = ",".join(h.handle.job_id for h in self._held.values())
        out = subprocess.run(
            ["squeue", "-h", "-r", "--states=all", "-o", "%i|%T", "-j", ids],
            capture_output=True,
            text=True,
            check=False,
        )
        if out.returncode != 0 and "Invalid job id" not in out.stderr:
            return None
        states = {}
        for line in out.stdout.splitlines():
            job_id, _, state = line.strip().partition("|")
            states[job_id] = state.split()[0] if state else ""
        return states

    def _follow(self, held: _Held, state: str | None, events: list[Event]) -> None:
        job, slot = held.job, held.slot
        result = held.handle.paths.result_pickle
        if state in ACTIVE_STATES:
            if held.running_since is None:
                held.running_since = time.monotonic()
                events.append(Event("started", job.job_id, slot))
            return
        if state in WAITING_STATES:
            held.running_since = None  # requeued: its time limit starts again when it runs
            return
        if state is None and time.monotonic() - held.submitted < RESULT_WAIT_S:
            return  # not yet in squeue's view
        if result.exists():
            events.append(self._ended(held))
            return
        if state == "COMPLETED":
            if held.ended_since is None:
                held.ended_since = time.monotonic()
            if time.monotonic() - held.ended_since < RESULT_WAIT_S:
                return
        self._release(held)
        log = held.handle.paths.stderr
        if state in LOST_STATES or state is None:
            what = f"ended {state}" if state else "left the queue"
            events.append(
                Event(
                    "lost",
                    job.job_id,
                    slot,
                    reason=f"Slurm job {held.handle.job_id} {what} without a result",
                    wall_s=self._wall_s(held),
                )
            )
            return
        why = {
            "TIMEOUT": f"reached its Slurm time limit (--slurm-time-min "
            f"{self.settings.time_min}) after its requeues",
            "OUT_OF_MEMORY": f"ran out of memory (--slurm-mem-gb {self.settings.mem_gb:g})",
        }
        events.append(
            Event(
                "failed",
                job.job_id,
                slot,
                reason=f"Slurm job {held.handle.job_id} "
                f"{why.get(state, f'ended {state} without a result')}; see {log}",
                wall_s=self._wall_s(held),
            )
        )

    def _ended(self, held: _Held) -> Event:
        """The event of a task whose result file is there."""
        self._release(held)
        utils = importlib.import_module("submitit.core.utils")
        kind: EventKind
        try:
            outcome, payload = utils.pickle_load(held.handle.paths.result_pickle)
        except Exception as exc:  # a torn file: the task died while writing it
            return Event(
                "failed",
                held.job.job_id,
                held.slot,
                reason=f"unreadable result of Slurm job {held.handle.job_id}: {exc}",
            )
        if outcome != "success":  # submitit's own error, e.g. "timed-out too many times"
            last = str(payload).strip().splitlines()
            return Event(
                "failed",
                held.job.job_id,
                held.slot,
                reason=f"Slurm job {held.handle.job_id}: {last[-1] if last else outcome}",
                wall_s=self._wall_s(held),
            )
        kind = "done" if payload["ok"] else "failed"
        return Event(
            kind,
            held.job.job_id,
            held.slot,
            payload["pid"],
            info=payload.get("summary") or {},
            reason=payload.get("reason", ""),
            wall_s=payload["wall_s"],
        )

    def _wall_s(self, held: _Held) -> float:
        return time.monotonic() - (held.running_since or held.submitted)

    def _release(self, held: _Held) -> None:
        self._held.pop(held.job.job_id, None)
        self._slots[held.slot] = None

    def _stop_overdue(self, events: list[Event]) -> None:
        """Cancel the jobs that ran past ``job_timeout_s``: failed, and not retried."""
        if self.job_timeout_s is None:
            return
        now = time.monotonic()
        for held in list(self._held.values()):
            if held.running_since is None or now - held.running_since < self.job_timeout_s:
                continue
            self._cancel(held)
            self._release(held)
            events.append(
                Event(
                    "failed",
                    held.job.job_id,
                    held.slot,
                    reason=timed_out_reason(self.job_timeout_s),
                    wall_s=now - held.running_since,
                    retry=False,
                )
            )

    def _cancel(self, held: _Held) -> None:
        with contextlib.suppress(Exception):
            held.handle.cancel(check=False)
        if self.cluster == "local":
            process = getattr(held.handle, "_process", None)
            if process is not None:
                _end_process_tree(process.pid)

    def shutdown(self) -> None:
        """Cancel what is still queued or running: an interrupted job has no summary in its
        folder, and the next run starts it again."""
        for held in list(self._held.values()):
            self._cancel(held)
        self._held.clear()
        self._buffer.clear()
        self._slots = [None] * self.workers


LOCAL_CANCEL_GRACE_S = 5.0
"""How long a cancelled local job's tasks have after SIGTERM (a training job writes its resume
file) before what is left of the job, its controller included, gets SIGKILL."""


def _descendants(pid: int) -> list[int]:
    """The processes below ``pid``, read from /proc (none where there is no /proc)."""
    children: dict[int, list[int]] = {}
    proc = Path("/proc")
    if not proc.is_dir():
        return []
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rpartition(")")[2].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _end_process_tree(pid: int) -> None:
    """End a local job's controller and everything below it. submitit cancels a local job
    with SIGINT to its controller, which a process started with SIGINT ignored (a background
    shell, CI) never sees: the controller then outlives the cancel and requeues the job at its
    own time limit. So the tasks get SIGTERM, and after a grace period the rest gets SIGKILL."""
    tasks = _descendants(pid)
    for child in tasks:
        with contextlib.suppress(OSError):
            os.kill(child, signal.SIGTERM)
    deadline = time.monotonic() + LOCAL_CANCEL_GRACE_S
    while time.monotonic() < deadline and any(_alive(c) for c in tasks):
        time.sleep(0.1)
    for victim in [*_descendants(pid), pid]:
        with contextlib.suppress(OSError):
            os.kill(victim, signal.SIGKILL)


def _alive(pid: int) -> bool:
    """Whether ``pid`` still runs (a zombie counts as ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except OSError:
        return False
    return state != "Z"


def _check_cluster(settings: SlurmSettings) -> None:
    """Before anything runs: the Slurm client is there, and the partition exists."""
    for tool in ("sbatch", "squeue", "scancel", "sinfo"):
        if shutil.which(tool) is None:
            raise UserInputError(
                f"--executor slurm: {tool} is not on PATH (run on a machine "
                "with the Slurm client, or use --executor slurm-local)"
            )
    out = subprocess.run(["sinfo", "-h", "-o", "%P"], capture_output=True, text=True, check=False)
    if out.returncode != 0:
        first = (out.stderr.strip().splitlines() or ["no output"])[0]
        raise UserInputError(f"--executor slurm: sinfo failed ({first})")
    partitions = [p.rstrip("*") for p in out.stdout.split()]
    if settings.partition and settings.partition not in partitions:
        raise UserInputError(
            f"--slurm-partition {settings.partition!r} does not exist; "
            f"allowed values: {', '.join(partitions)}"
        )
