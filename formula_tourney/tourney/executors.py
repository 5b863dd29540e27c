"""Where jobs run: a pool of spawned worker processes, or Ray tasks; both report the same events.

The scheduler (``tourney.scheduler``) submits one job per free slot and polls for :class:`Event`s
(started, progress, done, failed). Both executors run ``tourney.runner.run_job``.

Local pool: long-lived workers (spawned, one torch thread each: two threads in one process
scaled poorly here) each own one duplex ``multiprocessing`` pipe, rather than sharing
one ``multiprocessing.Queue``: a worker killed by -9 in the middle of a ``put`` would keep the
shared queue's write lock forever and stall every other worker. The parent waits on the pipes and
on the process sentinels together, so a dead worker is seen at once; the job it held is reported
failed with the exit code or signal, and a fresh worker takes its slot. Workers exit when the
parent dies (``PR_SET_PDEATHSIG`` plus a parent-pid check), so a resumed run never races an
orphan writing the same folder.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any, Literal, Protocol

from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import JobFolder
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.runner import run_job

EventKind = Literal["started", "progress", "done", "failed"]
THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


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


class Executor(Protocol):
    """What the scheduler needs from an executor."""

    workers: int

    def start(self) -> None: ...
    def free_slots(self) -> int: ...
    def submit(self, job: Job) -> int: ...
    def poll(self, timeout_s: float) -> list[Event]: ...
    def shutdown(self) -> None: ...


def default_workers() -> int:
    """One worker per core this process may use (one torch thread each)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


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


def _write_error(job: Job, exc: BaseException) -> None:
    """Keep the full traceback next to the job's partial output (never trusted: no summary)."""
    with contextlib.suppress(OSError):
        JobFolder(job.out_dir).write_error("".join(traceback.format_exception(exc)))


def die_with_parent(parent_pid: int) -> None:
    """Make this worker exit when the parent dies (Linux prctl; ppid poll elsewhere)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, daemon=True, name="parent-watch").start()


def _worker_main(slot: int, conn: Connection, parent_pid: int) -> None:
    """A worker: receive jobs on the pipe, run each, send events back; ``None`` means stop."""
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    pid = os.getpid()
    while True:
        try:
            job = conn.recv()
        except EOFError:
            return
        if job is None:
            return
        conn.send(("started", job.job_id, pid, {}))
        started = time.perf_counter()

        def progress(info: dict[str, Any], job_id: str = job.job_id) -> None:
            conn.send(("progress", job_id, pid, dict(info)))

        try:
            summary = run_job(job, progress)
        except Exception as exc:  # one failing job must not take the worker down
            _write_error(job, exc)
            conn.send(("failed", job.job_id, pid,
                       {"reason": failure_reason(exc),
                        "wall_s": time.perf_counter() - started}))
            # SIGTERM reached a training job (training.resume): it saved its state at a step
            # boundary and stopped; the worker was asked to end, so it ends now
            if type(exc).__name__ == "Preempted":
                return
        else:
            conn.send(("done", job.job_id, pid,
                       {"summary": summary, "wall_s": time.perf_counter() - started}))


def _exit_reason(code: int | None) -> str:
    if code is None:
        return "worker process vanished"
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"worker process killed by {name}"
    return f"worker process exited with code {code}"


class LocalExecutor:
    """A pool of ``workers`` spawned processes, one job at a time each."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, int(workers))
        self._ctx = mp.get_context("spawn")
        self._procs: list[Any] = [None] * self.workers
        self._conns: list[Connection | None] = [None] * self.workers
        self._holding: list[Job | None] = [None] * self.workers
        self._started_at: list[float] = [0.0] * self.workers
        self._spawned_at: list[float] = [0.0] * self.workers
        self._early_deaths = 0

    def start(self) -> None:
        for key in THREAD_ENV:  # inherited by spawned workers before numpy/torch import
            os.environ.setdefault(key, "1")
        for slot in range(self.workers):
            self._spawn(slot)

    def _spawn(self, slot: int) -> None:
        parent_conn, child_conn = self._ctx.Pipe(duplex=True)
        proc = self._ctx.Process(
            target=_worker_main, args=(slot, child_conn, os.getpid()),
            name=f"formula-tourney-worker-{slot}", daemon=True,
        )
        proc.start()
        child_conn.close()
        self._procs[slot] = proc
        self._conns[slot] = parent_conn
        self._spawned_at[slot] = time.monotonic()

    def worker_pids(self) -> list[int | None]:
        return [p.pid if p is not None else None for p in self._procs]

    def free_slots(self) -> int:
        return sum(1 for job in self._holding if job is None)

    def submit(self, job: Job) -> int:
        slot = self._holding.index(None)
        self._holding[slot] = job
        self._started_at[slot] = time.perf_counter()
        conn = self._conns[slot]
        assert conn is not None
        # A worker that died while idle: poll() sees its sentinel and fails the job.
        with contextlib.suppress(OSError):
            conn.send(job)
        return slot

    def poll(self, timeout_s: float) -> list[Event]:
        conns = {c: i for i, c in enumerate(self._conns) if c is not None}
        sentinels = {p.sentinel: i for i, p in enumerate(self._procs) if p is not None}
        ready = wait(list(conns) + list(sentinels), timeout=timeout_s)
        events: list[Event] = []
        dead: list[int] = []
        for obj in ready:
            if obj in conns:
                self._drain(conns[obj], events)
            else:
                dead.append(sentinels[obj])
        for slot in dead:
            self._drain(slot, events)  # a final 'done' may precede the exit
            proc = self._procs[slot]
            proc.join(timeout=5)
            job = self._holding[slot]
            if job is not None:
                events.append(Event("failed", job.job_id, slot, proc.pid,
                                    reason=_exit_reason(proc.exitcode),
                                    wall_s=time.perf_counter() - self._started_at[slot]))
                self._holding[slot] = None
            conn = self._conns[slot]
            if conn is not None:
                conn.close()
            # A worker that dies idle right after its start (a broken install) would otherwise
            # be respawned forever; deaths while holding a job are that job's failure.
            early = job is None and time.monotonic() - self._spawned_at[slot] < 5.0
            self._early_deaths = self._early_deaths + 1 if early else 0
            if self._early_deaths > 3 * self.workers:
                reason = _exit_reason(proc.exitcode)
                raise RuntimeError(f"worker processes keep dying at start ({reason})")
            self._spawn(slot)
        return events

    def _drain(self, slot: int, events: list[Event]) -> None:
        conn = self._conns[slot]
        if conn is None:
            return
        while True:
            try:
                if not conn.poll():
                    return
                kind, job_id, pid, payload = conn.recv()
            except (EOFError, OSError):
                return
            if kind == "started":
                events.append(Event("started", job_id, slot, pid))
            elif kind == "progress":
                events.append(Event("progress", job_id, slot, pid, info=payload))
            elif kind == "done":
                self._holding[slot] = None
                events.append(Event("done", job_id, slot, pid, info=payload["summary"],
                                    wall_s=payload["wall_s"]))
            elif kind == "failed":
                self._holding[slot] = None
                events.append(Event("failed", job_id, slot, pid, reason=payload["reason"],
                                    wall_s=payload["wall_s"]))

    def shutdown(self) -> None:
        for slot, proc in enumerate(self._procs):
            conn = self._conns[slot]
            if proc is None:
                continue
            if self._holding[slot] is None and conn is not None:
                with contextlib.suppress(OSError):
                    conn.send(None)
            else:
                proc.terminate()  # interrupted job: its folder has no summary, resume restarts it
        deadline = time.monotonic() + 10
        for proc in self._procs:
            if proc is not None:
                proc.join(timeout=max(0.1, deadline - time.monotonic()))
                if proc.is_alive():
                    proc.kill()
                    proc.join(timeout=5)
        for conn in self._conns:
            if conn is not None:
                conn.close()
        self._procs = [None] * self.workers
        self._conns = [None] * self.workers


# ------------------------------------------------------------------------------------ Ray


def _ray_task(job: Job, queue: Any) -> dict[str, Any]:
    """Body of a Ray task: the same run_job; progress goes through a Ray queue actor."""
    pid = os.getpid()
    queue.put(("started", job.job_id, pid, {}))
    started = time.perf_counter()

    def progress(info: dict[str, Any]) -> None:
        with contextlib.suppress(Exception):
            queue.put_nowait(("progress", job.job_id, pid, dict(info)))

    try:
        summary = run_job(job, progress)
    except Exception as exc:
        _write_error(job, exc)
        return {"ok": False, "reason": failure_reason(exc),
                "wall_s": time.perf_counter() - started, "pid": pid}
    return {"ok": True, "summary": summary, "wall_s": time.perf_counter() - started, "pid": pid}


class RayExecutor:
    """Jobs as Ray tasks (``num_cpus=1`` each); a local Ray instance or ``address``.

    Ray's own retries are off (``max_retries=0``): the scheduler owns retries so that every
    attempt is counted in the index. With ``address`` the results folder must be on a file
    system the Ray nodes share, since each task writes its own job folder.
    """

    def __init__(self, workers: int, address: str | None = None) -> None:
        self.workers = max(1, int(workers))
        self.address = address
        self._pending: dict[Any, tuple[int, Job, float]] = {}
        self._slots: list[Job | None] = [None] * self.workers
        self._queue: Any = None
        self._remote: Any = None
        self._ray: Any = None

    def start(self) -> None:
        try:  # optional extra, and ray.init alone costs 12-15 s: imported only when used
            import ray
            from ray.util.queue import Queue
        except ImportError:
            raise UserInputError(
                "--executor ray needs the optional extra: pip install 'formula-tourney[ray]'"
            ) from None
        for key in THREAD_ENV:
            os.environ.setdefault(key, "1")
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "ignore_reinit_error": True,
                                  "runtime_env": {"env_vars": {k: "1" for k in THREAD_ENV}}}
        if self.address:
            ray.init(address=self.address, **kwargs)
        else:
            ray.init(num_cpus=self.workers + 1, **kwargs)  # +1: the progress queue actor
        self._ray = ray
        self._queue = Queue(actor_options={"num_cpus": 0})
        self._remote = ray.remote(num_cpus=1, max_retries=0)(_ray_task)

    def free_slots(self) -> int:
        return sum(1 for job in self._slots if job is None)

    def submit(self, job: Job) -> int:
        slot = self._slots.index(None)
        self._slots[slot] = job
        ref = self._remote.remote(job, self._queue)
        self._pending[ref] = (slot, job, time.perf_counter())
        return slot

    def poll(self, timeout_s: float) -> list[Event]:
        ray = self._ray
        events: list[Event] = []
        slot_of = {job.job_id: slot for slot, job in enumerate(self._slots) if job is not None}
        for kind, job_id, pid, payload in self._queue.get_nowait_batch(self._queue.qsize()):
            if job_id in slot_of:
                events.append(Event(kind, job_id, slot_of[job_id], pid, info=payload))
        if not self._pending:
            time.sleep(timeout_s)
            return events
        done, _ = ray.wait(list(self._pending), num_returns=1, timeout=timeout_s)
        for ref in done:
            slot, job, started = self._pending.pop(ref)
            self._slots[slot] = None
            try:
                out = ray.get(ref)
            except Exception as exc:  # the worker process crashed or was killed
                events.append(Event("failed", job.job_id, slot,
                                    reason=f"Ray task failed: {type(exc).__name__}: "
                                    f"{str(exc).splitlines()[0] if str(exc) else ''}",
                                    wall_s=time.perf_counter() - started))
                continue
            if out["ok"]:
                events.append(Event("done", job.job_id, slot, out["pid"],
                                    info=out["summary"], wall_s=out["wall_s"]))
            else:
                events.append(Event("failed", job.job_id, slot, out["pid"],
                                    reason=out["reason"], wall_s=out["wall_s"]))
        return events

    def shutdown(self) -> None:
        if self._ray is None:
            return
        for ref in list(self._pending):
            with contextlib.suppress(Exception):
                self._ray.cancel(ref, force=True)
        self._pending.clear()
        with contextlib.suppress(Exception):
            self._ray.shutdown()
        self._ray = None


def make_executor(kind: str, workers: int, address: str | None = None) -> Executor:
    """``local`` or ``ray``; anything else is a usage error."""
    if kind == "local":
        if address:
            raise UserInputError("--address is only for --executor ray")
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(workers, address)
    raise UserInputError(f"unknown executor {kind!r}; allowed values: local, ray")
