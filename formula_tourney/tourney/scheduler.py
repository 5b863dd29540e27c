"""The parent's loop: submit jobs as slots free up, record every event, close parts, promote.

The scheduler is the only writer of ``index.sqlite`` while a tournament runs. It resumes from
the index (reconciled with the job folders first), closes a part when its last job ends,
promotes into the parts that wait on it, and goes on until no work is left. ``retry_failed``
re-opens the parts that hold failed jobs (a closed part is otherwise frozen, since its
promotion was decided on those results) and the parts downstream of them, whose promotion is
then computed again. The scheduler knows no job kind by name: each kind's object
(``tourney.kinds``) makes a part's jobs of that kind, says whether a job's folder already holds
its finished result, reads that result into the index, and says what a resumed run does with a
done job whose files are gone (``JobKind.lost_files``). A training run, a baseline drive and a
race series (a race part's one job, made once its source part promotes) go through the same
loop. Progress reaches whoever shows it through :class:`RunProgress`. A job that lost its
machine (a ``lost`` event) is queued again at once and counted as retried, apart from
``--retries`` (which is for the job's own failures); a time-out is failed and not retried.
A sequential run (``tourney.adaptive.AdaptiveRun``) adds waves: when every queued job has
ended, it reads the claims and gives the entrants of the undecided ones more seeds, and
holds a part open until it is settled.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from formula_tourney.results.folder import CorruptResultError
from formula_tourney.results.metrics import general_rank
from formula_tourney.tourney.adaptive import AdaptiveRun
from formula_tourney.tourney.executors import Executor
from formula_tourney.tourney.job_events import Event
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds import KINDS, TRAIN, CannotRun, JobKind, kind_of
from formula_tourney.tourney.outcomes import general_pick
from formula_tourney.tourney.plan import PlannedPart, Planner
from formula_tourney.tourney.promote import promote, rank_entrants
from formula_tourney.tourney.store import Store

LOST_RERUNS = 3
"""Times one job is run again in a run after losing the machine under it (a Ray node died, a
Slurm job was cancelled) before it counts as failed: a job that takes its node down each time
must not loop forever."""
QUEUE_ORDER = {name: i for i, name in enumerate(KINDS)}
"""Within a part, jobs queue in the registry's order of their kinds (training runs first)."""


class RunProgress(Protocol):
    """What the scheduler tells a progress display (the CLI's bars; nothing below the CLI
    draws). Slots are the executor's worker slots."""

    def start(self, workers: int) -> None: ...
    def set_total(self, total: int, done: int) -> None: ...
    def job_started(self, slot: int, job_id: str, episodes: int) -> None: ...
    def job_progress(self, slot: int, info: dict[str, Any]) -> None: ...
    def job_ended(self, slot: int, note: str) -> None: ...
    def stop(self) -> None: ...


@dataclass
class _PartState:
    planned: PlannedPart
    variants: list[str] | None
    status: str = "pending"
    jobs: dict[str, Job] = field(default_factory=dict)
    """The part's jobs of every kind, once its entrants are known."""


class Scheduler:
    """Runs the planned parts of one tournament on an executor, resuming from the index."""

    def __init__(
        self,
        planner: Planner,
        planned: list[PlannedPart],
        store: Store,
        retries: int = 0,
        retry_failed: bool = False,
        on_event: Callable[[Event], None] | None = None,
        progress: RunProgress | None = None,
        waves: AdaptiveRun | None = None,
    ) -> None:
        self.planner = planner
        self.waves = waves
        self.spec = planner.spec
        self.store = store
        self.retries = retries
        self.retry_failed = retry_failed
        self.on_event = on_event
        self.progress = progress
        self.parts = {p.part.name: _PartState(p, p.variants) for p in planned}
        self.order = [p.part.name for p in planned]
        self.queue: list[Job] = []
        self.running: dict[str, tuple[Job, int]] = {}
        self.attempts: dict[str, int] = {}
        self.lost_runs: dict[str, int] = {}
        self.counts = {"done": 0, "failed": 0, "retried": 0, "skipped": 0, "recovered": 0,
                       "reopened": 0, "lost": 0}  # fmt: skip
        self.lost: list[dict[str, str]] = []
        """Jobs the index held as done whose files were lost (``JobKind.lost``), with the
        reason and what this run did: shown in the run's summary."""

    # -------------------------------------------------------------- setup
    def _downstream(self, names: set[str]) -> set[str]:
        """Parts promoted (directly or not) from any of ``names``."""
        found: set[str] = set()
        changed = True
        while changed:
            changed = False
            for name in self.order:
                source = self.parts[name].planned.part.promoted_from
                if name not in found and (source in names or source in found):
                    found.add(name)
                    changed = True
        return found

    def _reopen_failed(self) -> set[str]:
        """Mark the parts holding failed jobs, and those downstream, pending again; returns
        the downstream parts, which wait for a new promotion."""
        failed_parts = {r["part"] for r in self.store.rows() if r["status"] == "failed"}
        failed_parts &= set(self.order)
        downstream = self._downstream(failed_parts)
        for name in self.order:
            if name not in failed_parts | downstream:
                continue
            row = self.store.part(name) or {}
            promoted = {k: v for k, v in (row.get("promoted") or {}).items()
                        if k not in downstream}  # fmt: skip
            self.store.set_part(name, status="pending", promoted=promoted)
        self.counts["reopened"] = len(failed_parts | downstream)
        return downstream

    def _open(self) -> None:
        store = self.store
        store.set_meta("tournament", self.spec.name)
        store.set_meta("spec", self.spec.model_dump_json())
        store.reconcile()
        for name in self.order:
            state = self.parts[name]
            part = state.planned.part
            store.add_part(name, part.study, state.planned.position, part.promoted_from)
        waiting = self._reopen_failed() if self.retry_failed else set()
        for name in self.order:
            state = self.parts[name]
            row = store.part(name) or {}
            state.status = row.get("status", "pending")
            if state.status == "running":
                state.status = "pending"
            if state.status == "done" and self._dependents_unpromoted(name):
                state.status = "pending"  # died between closing the part and promoting: redo
            if state.variants is None and name not in waiting:
                state.variants = self._stored_promotion(name)
            if state.variants is not None:
                self._materialise(state)

    def _dependents_unpromoted(self, name: str) -> bool:
        promoted = (self.store.part(name) or {}).get("promoted") or {}
        return any(
            self.parts[o].planned.part.promoted_from == name and o not in promoted
            for o in self.order
        )

    def _stored_promotion(self, name: str) -> list[str] | None:
        part = self.parts[name].planned.part
        if part.promoted_from is None:
            return None
        source = self.store.part(part.promoted_from) or {}
        promoted = source.get("promoted") or {}
        return list(promoted[name]) if name in promoted else None

    def _materialise(self, state: _PartState) -> None:
        """Create the jobs of a part whose variants are known, of every kind; record in the
        index what their folders already hold; queue what is not finished."""
        part = state.planned.part
        made: list[tuple[JobKind, list[Job]]] = []
        for kind in KINDS.values():
            try:
                made.append((kind, kind.make(self.planner, state.planned, self.store,
                                             state.variants or [])))
            except CannotRun as err:
                self._fail_part(part.name, str(err))
                return
        store = self.store
        known = {r["job_id"] for r in store.rows(part=part.name)}
        for kind, jobs in made:
            store.drop_jobs_except(part.name, kind.name, [j.job_id for j in jobs])
        jobs = [j for _kind, kind_jobs in made for j in kind_jobs]
        state.jobs = {j.job_id: j for j in jobs}
        store.add_jobs(kind_of(j.kind).index_row(j) for j in jobs)
        store.set_part(part.name, entrants=list(dict.fromkeys(
            e for j in jobs for e in kind_of(j.kind).entrants(j))))
        statuses = {}
        # the kinds that re-open a part first: the lost files of the others then run again too
        for job in sorted(jobs, key=lambda j: kind_of(j.kind).lost_files != "reopen_part"):
            statuses[job.job_id], reopen = self._reconcile_job(job, state, job.job_id in known)
            if reopen and state.status == "done":
                state.status = "pending"
                store.set_part(part.name, status="pending")
        self.counts["skipped"] += sum(s == "done" for s in statuses.values())
        if state.status in ("done", "failed"):
            return  # frozen: its promotion was made on these results
        for job in jobs:
            if statuses[job.job_id] == "done":
                continue
            if statuses[job.job_id] == "failed":
                store.mark_pending(job.job_id)
            self.queue.append(job)
        self.queue.sort(key=lambda j: (j.position, QUEUE_ORDER[j.kind]))

    def _reconcile_job(self, job: Job, state: _PartState, known: bool) -> tuple[str, bool]:
        """The job's status after trusting its folder: a finished folder the index missed (a
        crash, a rebuilt index, a promotion made again) is recorded instead of run; a done job
        whose files are gone goes by its kind's ``lost_files``. Returns the status and whether
        the job re-opens its part."""
        kind = kind_of(job.kind)
        status = (self.store.job(job.job_id) or {}).get("status", "pending")
        if status == "done":
            reason = kind.lost(job)
            if reason is None:
                return status, False
            reopen = kind.lost_files == "reopen_part"
            rerun = reopen or state.status not in ("done", "failed")
            self.lost.append({"job_id": job.job_id, "reason": reason,
                              "action": "run again" if rerun else "kept (its part is closed)"})
            self.counts["lost"] += 1
            if rerun:
                self.store.mark_pending(job.job_id)
                return "pending", reopen
            return status, False
        if kind.finished(job):
            try:
                result = kind.result(job)
            except CorruptResultError as err:
                raise CorruptResultError(f"{err}; remove the job folder {job.out_dir} to run "
                                         "that job again") from None
            self.store.mark_done(job.job_id, result, None)
            self.counts["recovered"] += 1
            return "done", False
        return status, not known and kind.lost_files == "reopen_part"

    # -------------------------------------------------------------- main loop
    def run(self, pool: Executor) -> None:
        """Run until no job is queued or running and, in a sequential run, no wave is added
        (KeyboardInterrupt goes to the caller)."""
        self._open()
        self._close_finished_parts()
        self._drain(pool)
        while self.waves is not None:
            added, reason = self.waves.next_wave(self.store, self._closed_parts())
            skipped = self.counts["skipped"]
            for name in added:  # the same jobs again, and the new seeds' jobs
                self._materialise(self.parts[name])
            self.counts["skipped"] = skipped
            self._close_finished_parts()
            if self.queue or self.running:
                self._drain(pool)
            elif not added:  # nothing to run and no seeds to add: the run stops here
                self.waves.finish(reason)
                self._close_finished_parts()
                break
            # else the new seeds' folders already held their results: read the claims again

    def _closed_parts(self) -> set[str]:
        """Parts that take no more seeds: closed, failed, or not planned yet."""
        return {n for n, s in self.parts.items()
                if s.status in ("done", "failed") or s.variants is None}

    def _drain(self, pool: Executor) -> None:
        """Submit and record jobs until none is queued or running."""
        while self.queue or self.running:
            while self.queue and pool.free_slots() > 0:
                job = self.queue.pop(0)
                slot = pool.submit(job)
                self.running[job.job_id] = (job, slot)
                self.attempts[job.job_id] = self.attempts.get(job.job_id, 0) + 1
                self._record_start(job)
                if self.progress:
                    self.progress.job_started(slot, job.job_id,
                                              kind_of(job.kind).progress_total(job))
            self._update_total()
            for event in pool.poll(0.5):
                self._handle(event)
            self._close_finished_parts()
        self._close_finished_parts()
        self._update_total()

    def abandon(self) -> None:
        """After an interrupt: the jobs that were running go back to pending in the index."""
        for job, _slot in self.running.values():
            self.store.mark_pending(job.job_id)
        self.running.clear()

    def _update_total(self) -> None:
        if self.progress is None:
            return
        total = sum(len(s.jobs) for s in self.parts.values())
        done = sum(r["status"] in ("done", "failed") and r["job_id"] not in self.running
                   for r in self.store.rows() if r["part"] in self.parts)  # fmt: skip
        self.progress.set_total(total, done)

    def _record_start(self, job: Job) -> None:
        self.store.mark_running(job.job_id, None)

    def _handle(self, event: Event) -> None:
        if self.on_event is not None:
            self.on_event(event)
        entry = self.running.get(event.job_id)
        if entry is None:
            return
        job, slot = entry
        if event.kind == "started":
            if event.pid is not None:
                self.store.set_worker_pid(job.job_id, event.pid)
        elif event.kind == "progress":
            if self.progress:
                self.progress.job_progress(slot, event.info)
        elif event.kind == "done":
            del self.running[job.job_id]
            try:
                self._record_done(job, event)
            except CorruptResultError as err:  # finished, but its files cannot be read back
                self._record_failed(job, slot, str(err), event.wall_s, retry=False)
                return
            self.counts["done"] += 1
            if self.progress:
                self.progress.job_ended(slot, f"done {job.job_id}")
        elif event.kind == "failed":
            del self.running[job.job_id]
            self._record_failed(job, slot, event.reason, event.wall_s, retry=event.retry)
        elif event.kind == "lost":
            del self.running[job.job_id]
            self._record_lost(job, slot, event)

    def _record_lost(self, job: Job, slot: int, event: Event) -> None:
        """Queue a job that lost its machine again, up to :data:`LOST_RERUNS` times."""
        runs = self.lost_runs[job.job_id] = self.lost_runs.get(job.job_id, 0) + 1
        if runs > LOST_RERUNS:
            self._record_failed(job, slot, f"{event.reason} (lost {runs} times)", event.wall_s,
                                retry=False)
            return
        self.counts["retried"] += 1
        self.store.mark_pending(job.job_id)
        self.queue.insert(0, job)
        if self.progress:
            self.progress.job_ended(slot, f"LOST {job.job_id} (run again)")

    def _record_failed(self, job: Job, slot: int, reason: str, wall_s: float,
                       retry: bool) -> None:
        self.store.mark_failed(job.job_id, reason, wall_s)
        if retry and self.attempts[job.job_id] <= self.retries:
            self.counts["retried"] += 1
            self.store.mark_pending(job.job_id)
            self.queue.insert(0, job)
        else:
            self.counts["failed"] += 1
        if self.progress:
            self.progress.job_ended(slot, f"FAILED {job.job_id}")

    def _record_done(self, job: Job, event: Event) -> None:
        self.store.mark_done(job.job_id, kind_of(job.kind).result(job), event.wall_s)

    # -------------------------------------------------------------- parts and promotion
    def _close_finished_parts(self) -> None:
        changed = True
        while changed:
            changed = False
            for name in self.order:
                state = self.parts[name]
                if state.status in ("done", "failed") or state.variants is None:
                    continue
                if any(j.part == name for j in self.queue) or any(
                    j.part == name for j, _ in self.running.values()
                ):
                    if state.status != "running":
                        state.status = "running"
                        self.store.set_part(name, status="running")
                    continue
                if self.waves is not None and self.waves.holds(name):
                    continue  # a sequential run may still add seeds here
                self._finish_part(state)
                changed = True

    def _finish_part(self, state: _PartState) -> None:
        part = state.planned.part
        every = self.store.rows(part=part.name)
        failed = [r for r in every if r["status"] == "failed"]
        rows = self.store.rows(TRAIN.name, part.name)  # entrants rank on their training runs
        ranking = rank_entrants(rows)
        if part.selection.kind == "general":
            self._select_general(state, rows)
        reason = f"{len(failed)} of {len(every)} jobs failed" if failed else None
        promoted = dict((self.store.part(part.name) or {}).get("promoted") or {})
        for name in self.order:
            other = self.parts[name]
            if other.planned.part.promoted_from != part.name:
                continue
            variants, ranking = promote(rank_entrants(rows), other.planned.part.promotion)
            promoted[name] = variants
            if other.variants is not None:
                continue  # already promoted (and materialised) earlier in this run
            if variants:
                other.variants = variants
                self._materialise(other)
            else:
                self._fail_part(name, f"no entrant of {part.name} met the promotion rule")
        # Status last: a crash before this line makes the resumed run close the part again.
        state.status = "done"
        self.store.set_part(part.name, ranking=ranking, promoted=promoted, reason=reason,
                            status="done")

    def _fail_part(self, name: str, reason: str) -> None:
        state = self.parts[name]
        state.status = "failed"
        state.variants = []
        self.store.set_part(name, status="failed", reason=reason, entrants=[])
        for other in self.order:
            if self.parts[other].planned.part.promoted_from == name:
                self._fail_part(other, f"source part {name} failed")

    def _select_general(self, state: _PartState, rows: list[dict[str, Any]]) -> None:
        part = state.planned.part
        position = state.planned.position
        key = self.planner.key_track(position)
        tests = list(self.planner.tracks(position)[1])
        found = []
        for row in rows:
            if row["status"] != "done":
                continue
            pick = general_pick(self.store.job_dir(row["job_id"]), row["job_id"], key, tests,
                                part.selection.min_unseen_finish_rate)
            if pick is not None:
                found.append({**pick, "entrant": row["entrant"], "seed": row["seed"],
                              "chosen": False})
        best: dict[str, dict[str, Any]] = {}
        for item in found:
            rank = general_rank(item["train_lap_s"], item["laps"], key)
            held = best.get(item["entrant"])
            if held is None or rank < general_rank(held["train_lap_s"], held["laps"], key):
                best[item["entrant"]] = item
        for item in best.values():
            item["chosen"] = True
        self.store.set_general_models(part.name, found)

