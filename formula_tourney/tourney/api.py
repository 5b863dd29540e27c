"""Run a tournament end to end: validate, plan, schedule jobs on an executor, promote, resume.

:func:`run_tournament` is what ``formula-tourney run`` and ``make demo`` call. The parent process
here is the only writer of ``index.sqlite``; it submits jobs as slots free up, records every event,
closes a part when its last job ends, promotes into the parts that wait on it, and goes on until
no work is left. Running it again on the same folder resumes (tourney.store.Store.reconcile).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.executors import Event, Executor, make_executor
from formula_tourney.tourney.lock import RunLock
from formula_tourney.tourney.plan import (
    Job,
    PlannedPart,
    build_plan,
    describe_plan,
    make_jobs,
    validate_plan,
)
from formula_tourney.tourney.promote import promote, rank_entrants
from formula_tourney.tourney.runner import BASELINE_RESULT_FILE, general_candidates, job_metrics
from formula_tourney.tourney.spec import Tournament, error_at, load_spec
from formula_tourney.tourney.store import Store

DEFAULT_RESULTS = Path("results")


def default_workers() -> int:
    """One worker per core this process may use (one torch thread each)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass
class _PartState:
    planned: PlannedPart
    variants: list[str] | None
    status: str = "pending"
    jobs: dict[str, Job] = field(default_factory=dict)
    baselines: dict[str, Job] = field(default_factory=dict)


class ProgressView:
    """Rich progress: one bar per worker slot plus an overall bar (on stderr)."""

    def __init__(self, workers: int, enabled: bool) -> None:
        self.enabled = enabled
        self._progress: Any = None
        self._overall: Any = None
        self._slots: list[Any] = []
        if not enabled:
            return
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
        )

        from formula_tourney.commands.output import stderr_console

        self._progress = Progress(
            TextColumn("{task.description}", style="bold"), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.fields[note]}"), TimeElapsedColumn(),
            console=stderr_console, transient=False,
        )
        self._overall = self._progress.add_task("all jobs", total=0, note="")
        self._slots = [
            self._progress.add_task(f"worker {i}", total=1, note="idle") for i in range(workers)
        ]

    def __enter__(self) -> ProgressView:
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()

    def set_total(self, total: int, done: int) -> None:
        if self._progress is not None:
            self._progress.update(self._overall, total=total, completed=done)

    def job_started(self, slot: int, job: Job) -> None:
        if self._progress is not None:
            total = int(job.config.get("episodes") or 1) if job.kind == "train" else 2
            self._progress.update(self._slots[slot], description=f"w{slot} {job.job_id}",
                                  total=total, completed=0, note="")

    def job_progress(self, slot: int, info: dict[str, Any]) -> None:
        if self._progress is None:
            return
        lap = info.get("best_lap_s")
        note = f"best {lap:.2f} s" if isinstance(lap, float) and lap == lap else ""
        self._progress.update(self._slots[slot], completed=info.get("episode", 0),
                              total=info.get("episodes") or None, note=note)

    def job_ended(self, slot: int, note: str) -> None:
        if self._progress is not None:
            self._progress.update(self._slots[slot], description=f"worker {slot}", note=note)


def run_tournament(
    path: str | Path,
    workers: int | None = None,
    executor: str = "local",
    address: str | None = None,
    retries: int = 0,
    results_dir: str | Path | None = None,
    dry_run: bool = False,
    show_progress: bool = True,
    on_event: Callable[[Event], None] | None = None,
) -> dict[str, Any]:
    """Run (or resume) the tournament in ``path``; return the results as plain data.

    Validation and the plan come first, so bad input raises UserInputError before anything is
    written. ``dry_run`` returns the plan only. ``on_event`` sees every executor event (tests and
    benchmarks use it).
    """
    path = Path(path)
    if retries < 0:
        raise UserInputError(f"--retries must be >= 0, got {retries}")
    if workers is not None and workers < 1:
        raise UserInputError(f"--workers must be >= 1, got {workers}")
    spec, text = load_spec(path)
    root = Path(results_dir if results_dir is not None else DEFAULT_RESULTS) / spec.name
    planned = build_plan(spec, root.resolve())
    validate_plan(spec, path, text, root.resolve())
    plan = describe_plan(spec, planned)
    if dry_run:
        return {"dry_run": True, "results": str(root), "plan": plan}
    store = Store(root)
    if store.exists():
        _check_unchanged(store, spec, planned, path, text)
    workers = workers or default_workers()
    with RunLock(root):
        runner = _Scheduler(spec, planned, store, root.resolve(), retries, on_event)
        started = time.perf_counter()
        pool = make_executor(executor, workers, address)
        try:
            with ProgressView(pool.workers, show_progress) as view:
                runner.view = view
                pool.start()
                runner.run(pool)
        finally:
            pool.shutdown()
        result = collect_results(store, spec)
        result["wall_s"] = time.perf_counter() - started
        result["workers"] = pool.workers
        result["executor"] = executor
        result["this_run"] = runner.counts
        store.close()
    return result


def _check_unchanged(
    store: Store, spec: Tournament, planned: list[PlannedPart], path: Path, text: str
) -> None:
    """Refuse to resume when a job that already ran would now get a different configuration."""
    for item in planned:
        for job in item.jobs:
            row = store.job(job.job_id)
            if row and row["config_hash"] and row["config_hash"] != job.config_hash and (
                row["status"] in ("done", "running", "failed")
            ):
                raise error_at(path, text, ("parts", item.position),
                               f"{job.job_id} already ran in {store.root} with other settings; "
                               "use a new tournament name or --results DIR to start afresh")


class _Scheduler:
    """The parent's loop: submit, record, close parts, promote."""

    def __init__(self, spec: Tournament, planned: list[PlannedPart], store: Store, root: Path,
                 retries: int, on_event: Callable[[Event], None] | None) -> None:
        self.spec = spec
        self.store = store
        self.root = root
        self.retries = retries
        self.on_event = on_event
        self.view: ProgressView | None = None
        self.parts = {p.part.name: _PartState(p, p.variants) for p in planned}
        self.order = [p.part.name for p in planned]
        self.queue: list[Job] = []
        self.running: dict[str, tuple[Job, int]] = {}
        self.attempts: dict[str, int] = {}
        self.counts = {"done": 0, "failed": 0, "retried": 0, "skipped": 0, "recovered": 0}

    # -------------------------------------------------------------- setup
    def _open(self) -> None:
        store = self.store
        store.set_meta("tournament", self.spec.name)
        store.set_meta("spec", self.spec.model_dump_json())
        fixed = store.reconcile()
        self.counts["recovered"] = fixed["recovered_done"]
        for name in self.order:
            state = self.parts[name]
            part = state.planned.part
            store.add_part(name, part.study, state.planned.position, part.promoted_from)
            row = store.part(name) or {}
            state.status = row.get("status", "pending")
            if state.status == "running":
                state.status = "pending"
            if state.status == "done" and self._dependents_unpromoted(name):
                state.status = "pending"  # died between closing the part and promoting: redo
            if state.variants is None:
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
        """Create the jobs of a part whose variants are known; queue what is not finished."""
        part = state.planned.part
        jobs = make_jobs(self.spec, part, state.planned.position, state.variants or [],
                         self.root)
        state.jobs = {j.job_id: j for j in jobs}
        state.baselines = {j.job_id: j for j in state.planned.baselines}
        self.store.add_jobs([{**j.meta, "job_id": j.job_id, "position": j.position,
                              "config_hash": j.config_hash} for j in jobs])
        self.store.add_baselines(j.meta for j in state.baselines.values())
        entrants = sorted({j.meta["entrant"] for j in jobs}, key=[
            j.meta["entrant"] for j in jobs].index)
        self.store.set_part(part.name, entrants=entrants)
        statuses = {j.job_id: (self.store.job(j.job_id) or {}).get("status") for j in jobs}
        self.counts["skipped"] += sum(s == "done" for s in statuses.values())
        if state.status == "done":
            return  # frozen: its promotion was made on these results
        for job in jobs:
            if statuses[job.job_id] == "done":
                continue
            if statuses[job.job_id] == "failed":
                self.store.mark_pending(job.job_id)
            self.queue.append(job)
        base_rows = {(r["bot"], r["track"], r["reference"]): r
                     for r in self.store.baseline_rows(part.name)}
        for job in state.baselines.values():
            key = (job.meta["bot"], job.meta["track"], job.meta["reference"])
            if base_rows.get(key, {}).get("status") != "done":
                self.queue.append(job)
        self.queue.sort(key=lambda j: (j.position, j.kind != "train"))

    # -------------------------------------------------------------- main loop
    def run(self, pool: Executor) -> None:
        self._open()
        self._close_finished_parts()
        while self.queue or self.running:
            while self.queue and pool.free_slots() > 0:
                job = self.queue.pop(0)
                slot = pool.submit(job)
                self.running[job.job_id] = (job, slot)
                self.attempts[job.job_id] = self.attempts.get(job.job_id, 0) + 1
                self._record_start(job, None)
                if self.view:
                    self.view.job_started(slot, job)
            self._update_total()
            for event in pool.poll(0.5):
                self._handle(event)
            self._close_finished_parts()
        self._close_finished_parts()
        self._update_total()

    def _update_total(self) -> None:
        if self.view is None:
            return
        total = done = 0
        for state in self.parts.values():
            total += len(state.jobs) + len(state.baselines)
        for row in self.store.job_rows():
            done += row["status"] in ("done", "failed") and row["job_id"] not in self.running
        done += sum(r["status"] in ("done", "failed") for r in self.store.baseline_rows())
        self.view.set_total(total, done)

    def _record_start(self, job: Job, pid: int | None) -> None:
        if job.kind == "train":
            self.store.mark_running(job.job_id, pid)
        else:
            self.store.set_baseline(_bkey(job), status="running")

    def _handle(self, event: Event) -> None:
        if self.on_event is not None:
            self.on_event(event)
        entry = self.running.get(event.job_id)
        if entry is None:
            return
        job, slot = entry
        if event.kind == "started":
            if job.kind == "train" and event.pid is not None:
                with self.store.transaction() as db:
                    db.execute("UPDATE jobs SET worker_pid=? WHERE job_id=?",
                               (event.pid, job.job_id))
        elif event.kind == "progress":
            if self.view:
                self.view.job_progress(slot, event.info)
        elif event.kind == "done":
            del self.running[job.job_id]
            self._record_done(job, event)
            self.counts["done"] += 1
            if self.view:
                self.view.job_ended(slot, f"done {job.job_id}")
        elif event.kind == "failed":
            del self.running[job.job_id]
            if self.attempts[job.job_id] <= self.retries:
                self.counts["retried"] += 1
                if job.kind == "train":
                    self.store.mark_failed(job.job_id, event.reason, event.wall_s)
                    self.store.mark_pending(job.job_id)
                self.queue.insert(0, job)
            else:
                self.counts["failed"] += 1
                if job.kind == "train":
                    self.store.mark_failed(job.job_id, event.reason, event.wall_s)
                else:
                    self.store.set_baseline(_bkey(job), status="failed", reason=event.reason)
            if self.view:
                self.view.job_ended(slot, f"FAILED {job.job_id}")

    def _record_done(self, job: Job, event: Event) -> None:
        out_dir = Path(job.out_dir)
        if job.kind == "train":
            metrics = job_metrics(out_dir, job.meta["train_tracks"][0])
            self.store.mark_done(job.job_id, metrics, event.wall_s)
            return
        result = json.loads((out_dir / BASELINE_RESULT_FILE).read_text(encoding="utf-8"))
        self.store.set_baseline(
            _bkey(job), status="done", reason=None, best_lap_s=result["best_lap_s"],
            damage=result["damage"], finished=int(bool(result["finished"])),
            reference_limit_s=result["reference_limit_s"],
        )

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
                self._finish_part(state)
                changed = True

    def _finish_part(self, state: _PartState) -> None:
        part = state.planned.part
        rows = self.store.job_rows(part.name)
        failed = [r for r in rows if r["status"] == "failed"]
        ranking = rank_entrants(rows)
        if part.selection.kind == "general":
            self._select_general(state, rows)
        reason = f"{len(failed)} of {len(rows)} jobs failed" if failed else None
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
        found = []
        for row in rows:
            if row["status"] != "done":
                continue
            pick = general_candidates(self.root / row["path"], part.train_tracks[0],
                                      part.all_test_tracks(),
                                      part.selection.min_unseen_finish_rate)
            if pick is not None:
                found.append({"job_id": row["job_id"], "entrant": row["entrant"],
                              "seed": row["seed"], **pick, "chosen": False})
        best: dict[str, dict[str, Any]] = {}
        for item in found:
            if item["entrant"] not in best or item["train_lap_s"] < best[item["entrant"]][
                "train_lap_s"
            ]:
                best[item["entrant"]] = item
        for item in best.values():
            item["chosen"] = True
        self.store.set_general_models(part.name, found)


def _bkey(job: Job) -> tuple[str, str, str, str]:
    return (job.part, job.meta["bot"], job.meta["track"], job.meta["reference"])


def collect_results(store: Store, spec: Tournament) -> dict[str, Any]:
    """The tournament's state as plain data: parts with rankings, failures, baselines."""
    parts = []
    baselines = store.baseline_rows()
    for part_spec in spec.parts:
        name = part_spec.name
        row = store.part(name) or {"part": name, "status": "pending"}
        jobs = store.job_rows(name)
        track = part_spec.train_tracks[0]
        limits = [b["reference_limit_s"] for b in baselines
                  if b["track"] == track and b["reference_limit_s"] is not None]
        parts.append({
            "part": name, "study": row.get("study"), "status": row.get("status"),
            "train_track": track, "reference_limit_s": limits[0] if limits else None,
            "reason": row.get("reason"), "entrants": row.get("entrants") or [],
            "promoted": row.get("promoted") or {}, "ranking": row.get("ranking") or [],
            "jobs": {s: sum(j["status"] == s for j in jobs)
                     for s in ("done", "failed", "pending", "running")},
        })
    failures = [{"job_id": r["job_id"], "reason": r["reason"], "attempts": r["attempts"]}
                for r in store.job_rows() if r["status"] == "failed"]
    general = store.general_models()
    return {
        "tournament": spec.name, "results": str(store.root), "parts": parts,
        "failures": failures, "baselines": baselines,
        "general_models": general.to_dict(orient="records") if not general.empty else [],
    }


def render_results(console: Any, result: dict[str, Any]) -> None:
    """Rich tables of a run's result: per part, entrants ranked by aLT with bLT, the gap of bLT
    to the train track's reference limit, and the finish rate."""
    from rich.table import Table

    if result.get("dry_run"):
        render_plan(console, result["plan"], result["results"])
        return
    for part in result["parts"]:
        table = Table(title=f"{part['part']} ({part['study']}): {part['status']}"
                      + (f" - {part['reason']}" if part.get("reason") else ""))
        limit = part.get("reference_limit_s")
        for col in ("entrant", "family", "aLT s", "bLT s", "gap", "finished", "decision"):
            table.add_column(col, justify="right" if col.endswith(("s", "finished", "gap"))
                             else "left")
        for row in part["ranking"]:
            table.add_row(
                row["entrant"], row["family"], _fmt(row["aLT"]), _fmt(row["bLT"]),
                _gap(row["bLT"], limit),
                f"{row['finished_seeds']}/{row['seeds']}", row.get("decision") or "",
            )
        for base in result["baselines"]:
            if base["part"] == part["part"]:
                table.add_row(f"{base['bot']} ({base['reference']}) @{base['track']}", "bot",
                              "", _fmt(base["best_lap_s"]),
                              _gap(base["best_lap_s"], base["reference_limit_s"]),
                              "yes" if base["finished"] else base["status"],
                              f"limit {_fmt(base['reference_limit_s'])}")
        console.print(table)
    for fail in result["failures"]:
        console.print(f"[red]failed[/red] {fail['job_id']}: {fail['reason']}")
    if "wall_s" in result:
        run = result["this_run"]
        console.print(
            f"{result['results']}: {run['done']} jobs done, {run['failed']} failed, "
            f"{run['skipped']} already done, in {result['wall_s']:.1f} s on "
            f"{result['workers']} {result['executor']} workers"
        )


def render_plan(console: Any, plan: dict[str, Any], results: str) -> None:
    """The dry-run view: one short block per part (fits a narrow terminal)."""
    from rich.markup import escape

    console.print(f"[bold]plan of {plan['tournament']}[/bold] -> {results}/"
                  f"  ({plan['known_jobs']} jobs known now; promoted parts add theirs later)")
    if plan.get("description"):
        console.print(f"  {plan['description']}")
    for part in plan["parts"]:
        if "entrants" in part:
            who = f"{len(part['entrants'])} entrants ({', '.join(part['entrants'])})"
            jobs = f"= {part['jobs']} jobs"
        else:
            who = f"promoted from {part['promoted_from']} ({part['rule']})"
            jobs = f"= {part['jobs_per_entrant']} jobs per promoted variant"
        console.print(f"[bold]{part['part']}[/bold] (study {part['study']}): {escape(who)}")
        console.print(f"    x setups {', '.join(part['setups'])} x {part['seeds']} seeds {jobs}")
        console.print(
            f"    train {', '.join(part['train_tracks'])}; test {', '.join(part['test_tracks'])}"
            f" every {part['test_every_episodes'] or 'default'} episodes; "
            f"{part['episodes'] or 'default'} episodes x {part['max_steps'] or 'default'} steps;"
            f" selection {part['selection']}"
        )
        if part["baselines"]:
            console.print(f"    baselines {', '.join(part['baselines'])}")


def _gap(lap_s: Any, limit_s: Any) -> str:
    """Gap of a lap to the track's reference limit (QSS lap on the min-curvature line)."""
    if lap_s is None or limit_s is None or lap_s != lap_s or not limit_s:
        return "-"
    return f"+{100.0 * (float(lap_s) / float(limit_s) - 1.0):.1f}%"


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "-" if value != value else f"{value:.2f}"
