"""Where jobs run: a pool of spawned worker processes, Ray tasks or Slurm jobs; all report the
same events.

The scheduler (``tourney.scheduler``) submits one job per free slot and polls for :class:`Event`s
(started, progress, done, failed, lost). Every executor runs ``tourney.runner.run_job``; the
Slurm one (``tourney.slurm_executor``, through submitit) lives in its own module.

A failed job is the job's own failure; a lost one lost the machine under it and runs again
(``tourney.job_events``). A job running longer than ``job_timeout_s`` is stopped (the pool
stops its worker, Ray cancels the task with force, Slurm's is cancelled) and reported failed,
"timed out after N s", and not retried: it would run out of time again.

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
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any, Protocol

from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import SUBMITIT_DIR
from formula_tourney.tourney.job_events import (
    THREAD_ENV,
    Event,
    EventKind,
    check_job_timeout,
    failure_reason,
    run_to_outcome,
    timed_out_reason,
    write_error,
)
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.runner import run_job
from formula_tourney.tourney.slurm_executor import (
    SlurmCluster,
    SlurmExecutor,
    SlurmSettings,
    job_name,
)

SLURM_KINDS: dict[str, SlurmCluster] = {"slurm": "slurm", "slurm-local": "local"}
"""``--executor`` values that go through submitit, and the submitit cluster of each."""


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
            write_error(job, exc)
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
    """A pool of ``workers`` spawned processes, one job at a time each; a job running longer
    than ``job_timeout_s`` (from its start in the worker) has its worker stopped."""

    def __init__(self, workers: int, job_timeout_s: float | None = None) -> None:
        self.workers = max(1, int(workers))
        self.job_timeout_s = job_timeout_s
        self._ctx = mp.get_context("spawn")
        self._procs: list[Any] = [None] * self.workers
        self._conns: list[Connection | None] = [None] * self.workers
        self._holding: list[Job | None] = [None] * self.workers
        self._started_at: list[float] = [0.0] * self.workers
        self._running_since: list[float | None] = [None] * self.workers
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
        self._running_since[slot] = None
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
        self._stop_overdue(events)
        return events

    def _stop_overdue(self, events: list[Event]) -> None:
        """Stop the workers whose job ran past ``job_timeout_s``; the job is failed, not retried
        (it would run out of time again), and a fresh worker takes the slot."""
        if self.job_timeout_s is None:
            return
        now = time.monotonic()
        for slot, since in enumerate(self._running_since):
            job = self._holding[slot]
            if job is None or since is None or now - since < self.job_timeout_s:
                continue
            proc = self._procs[slot]
            proc.terminate()
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=5)
            tail: list[Event] = []
            self._drain(slot, tail)
            # a 'done' sent just before the stop stands; a 'failed' the stop itself caused
            # (a worker that turns SIGTERM into an exception) is the time-out
            events.extend(e for e in tail if e.kind != "failed")
            if not any(e.kind == "done" for e in tail):
                events.append(Event("failed", job.job_id, slot, proc.pid,
                                    reason=timed_out_reason(self.job_timeout_s),
                                    wall_s=time.monotonic() - since, retry=False))
            self._holding[slot] = None
            self._running_since[slot] = None
            conn = self._conns[slot]
            if conn is not None:
                conn.close()
            self._spawn(slot)

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
                self._running_since[slot] = time.monotonic()
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

    def progress(info: dict[str, Any]) -> None:
        with contextlib.suppress(Exception):
            queue.put_nowait(("progress", job.job_id, pid, dict(info)))

    return run_to_outcome(job, progress)


class RayExecutor:
    """Jobs as Ray tasks (``num_cpus=1`` each); a local Ray instance or ``address``.

    Ray's own retries are off (``max_retries=0``): the scheduler owns retries so that every
    attempt is counted in the index. A task whose node died (``NodeDiedError``: a raylet
    killed, a machine gone) is reported ``lost`` and runs again elsewhere; a task whose worker
    process crashed is ``failed``, as in the pool. The progress queue lives on the driver's own
    node, so losing another node loses no progress channel. With ``address`` the results folder
    must be on a file system the Ray nodes share, since each task writes its own job folder.
    """

    def __init__(self, workers: int | None, address: str | None = None,
                 job_timeout_s: float | None = None) -> None:
        self.workers = max(1, int(workers)) if workers else 0
        """Jobs queued at once; None given: the cluster's CPUs (known once joined), or this
        machine's cores for a local instance."""
        self.address = address
        self.job_timeout_s = job_timeout_s
        self._pending: dict[Any, tuple[int, Job, float]] = {}
        self._running_since: dict[Any, float] = {}
        self._slots: list[Job | None] = [None] * self.workers
        self._queue: Any = None
        self._remote: Any = None
        self._ray: Any = None
        self._lost_errors: tuple[type[BaseException], ...] = ()

    def start(self) -> None:
        try:  # optional extra, and ray.init alone costs 12-15 s: imported only when used
            import ray
            from ray.util.queue import Queue
            from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
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
            if not self.workers:
                self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        else:
            self.workers = self.workers or default_workers()
            ray.init(address="local", num_cpus=self.workers + 1, **kwargs)  # +1: the queue actor
        self._slots = [None] * self.workers
        self._ray = ray
        _cluster_errors_to_stderr(ray)
        here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(), soft=False)
        self._queue = Queue(actor_options={"num_cpus": 0, "scheduling_strategy": here})
        self._remote = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
        self._lost_errors = (ray.exceptions.NodeDiedError, ray.exceptions.ObjectLostError)

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
        ref_of = {job.job_id: ref for ref, (_slot, job, _t) in self._pending.items()}
        for kind, job_id, pid, payload in self._queue.get_nowait_batch(self._queue.qsize()):
            if job_id in ref_of:
                slot = self._pending[ref_of[job_id]][0]
                if kind == "started":
                    self._running_since[ref_of[job_id]] = time.monotonic()
                events.append(Event(kind, job_id, slot, pid, info=payload))
        if not self._pending:
            time.sleep(timeout_s)
            return events
        refs = list(self._pending)
        ray.wait(refs, num_returns=1, timeout=timeout_s)
        done, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
        for ref in done:
            events.append(self._finished(ref))
        self._stop_overdue(events)
        return events

    def _release(self, ref: Any) -> tuple[int, Job, float]:
        slot, job, started = self._pending.pop(ref)
        self._running_since.pop(ref, None)
        self._slots[slot] = None
        return slot, job, started

    def _finished(self, ref: Any) -> Event:
        slot, job, started = self._release(ref)
        try:
            out = self._ray.get(ref)
        except Exception as exc:  # the worker process crashed, or its node is gone
            first = str(exc).splitlines()[0] if str(exc) else ""
            kind: EventKind = "lost" if isinstance(exc, self._lost_errors) else "failed"
            return Event(kind, job.job_id, slot,
                         reason=f"Ray task failed: {type(exc).__name__}: {first}",
                         wall_s=time.perf_counter() - started)
        if out["ok"]:
            return Event("done", job.job_id, slot, out["pid"], info=out["summary"],
                         wall_s=out["wall_s"])
        return Event("failed", job.job_id, slot, out["pid"], reason=out["reason"],
                     wall_s=out["wall_s"])

    def _stop_overdue(self, events: list[Event]) -> None:
        """Cancel (with force: the worker process is killed) the tasks past ``job_timeout_s``."""
        if self.job_timeout_s is None:
            return
        now = time.monotonic()
        for ref, since in list(self._running_since.items()):
            if now - since < self.job_timeout_s:
                continue
            with contextlib.suppress(Exception):
                self._ray.cancel(ref, force=True)
            slot, job, _submitted = self._release(ref)
            events.append(Event("failed", job.job_id, slot,
                                reason=timed_out_reason(self.job_timeout_s),
                                wall_s=now - since, retry=False))

    def shutdown(self) -> None:
        if self._ray is None:
            return
        for ref in list(self._pending):
            with contextlib.suppress(Exception):
                self._ray.cancel(ref, force=True)
        self._pending.clear()
        self._running_since.clear()
        with contextlib.suppress(Exception):
            self._ray.shutdown()
        self._ray = None


def _cluster_errors_to_stderr(ray: Any) -> None:
    """Ray's driver prints the cluster's error messages (a raylet that died) on stdout, where
    ``run --json`` prints its one document: send them to stderr instead."""
    worker = getattr(getattr(ray, "_private", None), "worker", None)
    original = getattr(worker, "print_to_stdstream", None)
    if original is None or getattr(original, "to_stderr", False):
        return

    def to_stderr(data: dict[str, Any], ignore_prefix: bool) -> None:
        original({**data, "is_err": True}, ignore_prefix)

    to_stderr.to_stderr = True  # type: ignore[attr-defined]
    worker.print_to_stdstream = to_stderr


def make_executor(kind: str, workers: int | None, address: str | None = None,
                  job_timeout_s: float | None = None, slurm: SlurmSettings | None = None,
                  results_root: Path | None = None) -> Executor:
    """``local``, ``ray``, ``slurm`` or ``slurm-local``; anything else is a usage error.
    ``workers`` None: this machine's cores (the pool, a local Ray instance), a Ray cluster's
    CPUs, or ``--slurm-max-parallel``.
    ``slurm`` holds the ``--slurm-*`` settings (only for the two Slurm kinds); the Slurm kinds
    keep submitit's files under ``results_root``."""
    check_job_timeout(job_timeout_s)
    if address and kind != "ray":
        raise UserInputError("--address is only for --executor ray")
    if slurm is not None and kind not in SLURM_KINDS:
        raise UserInputError("--slurm-* options are only for --executor slurm or slurm-local")
    if kind == "local":
        return LocalExecutor(workers or default_workers(), job_timeout_s)
    if kind == "ray":
        return RayExecutor(workers, address, job_timeout_s)
    if kind in SLURM_KINDS:
        root = Path(results_root if results_root is not None else ".")
        return SlurmExecutor(slurm or SlurmSettings(), root / SUBMITIT_DIR, job_name(root),
                             SLURM_KINDS[kind], job_timeout_s)
    raise UserInputError(f"unknown executor {kind!r}; allowed values: local, ray, "
                         f"{', '.join(SLURM_KINDS)}")
