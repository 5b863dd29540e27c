"""Run a tournament end to end: validate, plan, lock the folder, schedule, collect the results.

:func:`run_tournament` is what ``formula-tourney run`` and ``make demo`` call. Everything that can
be checked is checked before anything is written: the file, and the run specification of every
job that can exist (``tourney.plan.Planner.validate``). Then the results folder is locked, its
index opened (a corrupt one is an error naming it, or is moved aside with ``rebuild_index``),
and ``tourney.scheduler.Scheduler`` runs, resuming whatever an earlier run left.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import ESTIMATE_FILE
from formula_tourney.safeio import atomic_write_json
from formula_tourney.tourney.adaptive import AdaptiveRun, Judge
from formula_tourney.tourney.estimate import MIN_CALIBRATE_S
from formula_tourney.tourney.executors import SLURM_KINDS, default_workers, make_executor
from formula_tourney.tourney.job_events import Event
from formula_tourney.tourney.kinds import KINDS
from formula_tourney.tourney.lock import RunLock
from formula_tourney.tourney.plan import PlannedPart, Planner
from formula_tourney.tourney.scheduler import RunProgress, Scheduler
from formula_tourney.tourney.slurm_executor import SlurmSettings
from formula_tourney.tourney.spec import Adaptive, error_at, load_spec
from formula_tourney.tourney.store import Store
from formula_tourney.tourney.summary import collect_results

DEFAULT_RESULTS = Path("results")


def plan_tournament(
    path: str | Path, results_dir: str | Path | None = None,
    budget_cpu_h: float | None = None,
    wave_seeds: int | None = None,
) -> tuple[Planner, list[PlannedPart], Path]:
    """Load and validate a tournament file and plan it; writes nothing.

    Every job's run specification that can exist is built here (promoted parts with every
    variant they could receive), so any bad value raises UserInputError with ``file:line``.
    ``budget_cpu_h`` makes the run sequential (``tourney.adaptive``): the file's
    ``[adaptive]`` table with this budget, or the default design. Returns the planner, the
    planned parts and the tournament's results folder.
    """
    path = Path(path)
    spec, text = load_spec(path)
    if budget_cpu_h is not None:
        if not (budget_cpu_h > 0 and budget_cpu_h < float("inf")):
            raise UserInputError(f"--budget-cpu-h must be a number > 0, got {budget_cpu_h}")
        design = spec.adaptive or Adaptive()
        spec = spec.model_copy(update={"adaptive": design.model_copy(
            update={"budget_cpu_h": float(budget_cpu_h)})})
    if wave_seeds is not None:
        if spec.adaptive is None:
            raise UserInputError("--wave-seeds needs a sequential run: an [adaptive] table in "
                                 f"{path} or --budget-cpu-h")
        if not 1 <= wave_seeds <= 1000:
            raise UserInputError(f"--wave-seeds must be 1-1000, got {wave_seeds}")
        spec = spec.model_copy(update={"adaptive": spec.adaptive.model_copy(
            update={"wave_seeds": int(wave_seeds)})})
    root = Path(results_dir if results_dir is not None else DEFAULT_RESULTS) / spec.name
    planner = Planner(spec, path, text, root.resolve())
    planner.validate()
    return planner, planner.plan(), root


def run_tournament(
    path: str | Path,
    workers: int | None = None,
    executor: str = "local",
    address: str | None = None,
    retries: int = 0,
    results_dir: str | Path | None = None,
    dry_run: bool = False,
    retry_failed: bool = False,
    rebuild_index: bool = False,
    progress: RunProgress | None = None,
    on_event: Callable[[Event], None] | None = None,
    estimate: bool = False,
    calibrate_s: float = 1.0,
    cluster_cpus: int | None = None,
    report: Callable[[str], None] | None = None,
    budget_cpu_h: float | None = None,
    wave_seeds: int | None = None,
    judge: Judge | None = None,
    job_timeout_s: float | None = None,
    slurm: SlurmSettings | None = None,
) -> dict[str, Any]:
    """Run (or resume) the tournament in ``path``; return the results as plain data.

    ``dry_run`` returns the plan only. ``retry_failed`` re-runs failed jobs even in parts that
    closed (re-opening them and computing the promotion downstream again); ``rebuild_index``
    moves the index aside and rebuilds it from the job folders. ``progress`` receives the
    scheduler's progress; ``on_event`` sees every executor event (tests and benchmarks).
    KeyboardInterrupt stops the workers, leaves finished jobs recorded and propagates.
    ``estimate`` measures this machine's rates (``calibrate_s`` per distinct job) and adds the
    cost estimate (``tourney.estimate``; ``cluster_cpus``: also for a Ray cluster that size):
    to the dry run's result, or, for a run, to ``estimate.json`` in the results folder when the
    tournament has none yet (a resume keeps the first). ``report`` hears its progress lines.
    A sequential run (``[adaptive]`` or ``budget_cpu_h``; ``wave_seeds`` replaces its
    design's runs per wave, e.g. a cluster's CPUs) reads its claims with ``judge``
    after every wave (``report.claims.judge.judge``; the tournament layer reads no report).
    ``job_timeout_s`` stops and fails a job that runs longer; ``slurm`` holds the settings of
    ``executor="slurm"`` / ``"slurm-local"`` (``tourney.slurm_executor``).
    """
    if retries < 0:
        raise UserInputError(f"--retries must be >= 0, got {retries}")
    if workers is not None and workers < 1:
        raise UserInputError(f"--workers must be >= 1, got {workers}")
    if estimate and calibrate_s < MIN_CALIBRATE_S:
        raise UserInputError(f"--calibrate-s {calibrate_s:g} is too short to time the jobs' "
                             f"steps and updates; use at least {MIN_CALIBRATE_S:g} s")
    if cluster_cpus is not None and cluster_cpus < 1:
        raise UserInputError(f"--cluster-cpus must be >= 1, got {cluster_cpus}")
    if workers is not None and executor in SLURM_KINDS:
        raise UserInputError("--workers is not for --executor slurm; use --slurm-max-parallel")
    planner, planned, root = plan_tournament(path, results_dir, budget_cpu_h, wave_seeds)
    if planner.spec.adaptive is not None and judge is None and not dry_run:
        raise ValueError("a sequential run ([adaptive]) needs a judge to read its claims")
    if executor in SLURM_KINDS:  # the estimate's wall time: the jobs Slurm runs at once
        slots = (slurm or SlurmSettings()).max_parallel
    else:
        slots = workers or default_workers()
    cost = None
    if estimate and (dry_run or not (root / ESTIMATE_FILE).is_file()):
        # torch and the env kernels: only when asked (and the import is what a worker pays,
        # which the estimate measures)
        from formula_tourney.tourney.estimate.plan import estimate_plan

        cost = estimate_plan(planner, planned, slots, cluster_cpus, calibrate_s, report).to_json()
    if dry_run:
        out = {"dry_run": True, "results": str(root), "plan": planner.describe(planned)}
        if planner.spec.adaptive is not None:
            out["adaptive"] = planner.spec.adaptive.model_dump()
        return out if cost is None else {**out, "estimate": cost}
    pool = make_executor(executor, workers, address, job_timeout_s, slurm, root)
    with RunLock(root):
        if cost is not None:
            atomic_write_json(root / ESTIMATE_FILE, cost)
        store = Store(root)
        moved = store.move_aside() if rebuild_index else None
        waves = AdaptiveRun(planner, root, judge) if judge and planner.spec.adaptive else None
        if waves is not None:
            planned = planner.plan()  # with the seeds earlier waves added
        if store.exists():
            store.check()
            _check_unchanged(store, planner, planned, retry_failed)
        scheduler = Scheduler(planner, planned, store, retries, retry_failed, on_event,
                              progress, waves)
        started = time.perf_counter()
        try:
            pool.start()  # first: a Ray cluster's size is known once joined
            if progress is not None:
                progress.start(pool.workers)
            scheduler.run(pool)
        except KeyboardInterrupt:
            scheduler.abandon()
            raise
        finally:
            pool.shutdown()
            if progress is not None:
                progress.stop()
        result = collect_results(store, planner.spec.name, planned)
        store.close()
    if waves is not None:
        result["adaptive"] = waves.state
    result.update(wall_s=time.perf_counter() - started, workers=pool.workers, executor=executor,
                  this_run=scheduler.counts, lost=scheduler.lost,
                  index_moved_to=str(moved) if moved else None)
    return result


def _check_unchanged(store: Store, planner: Planner, planned: list[PlannedPart],
                     retry_failed: bool = False) -> None:
    """Refuse to resume when a job that already ran would now get other settings: each kind
    names the jobs it guards (``JobKind.resume_jobs``: a training run of a variant the index
    holds, a race series of the promotion it holds; ``retry_failed`` may re-promote, so a new
    series is then expected)."""
    for item in planned:
        for kind in KINDS.values():
            if kind.changed_settings is None:
                continue
            for job in kind.resume_jobs(planner, item, store, retry_failed):
                row = store.job(job.job_id)
                if row and row["config_hash"] and row["config_hash"] != job.config_hash and (
                    row["status"] in ("done", "running", "failed")
                ):
                    raise error_at(planner.path, planner.text, ("parts", item.position),
                                   f"{job.job_id} "
                                   f"{kind.changed_settings.format(root=store.root)}; use a new "
                                   "tournament name or --results DIR to start afresh")
