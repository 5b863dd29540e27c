"""Optuna pre-selection of one variant's hyperparameters: the parent that runs a study.

The paper tunes on the oval before the tournament proper (Study 1, part 1); this is that step as
an Optuna study (TPE, pruning on the periodic test laps). The file is ``tune.spec``'s,
the Optuna plumbing ``tune.study``'s, a trial ``tune.worker``'s.

Processes: the study is created once, in the parent (two processes creating one SQLite study at
once crashed one); worker processes load it and run trials. Storage defaults to a
``JournalFileBackend`` under the results folder (~10x faster than SQLite for two processes, and
needs no server); ``--storage URL`` takes an RDB for many machines, where Optuna's heartbeats plus
``RetryFailedTrialCallback`` retry trials whose process died. The journal has no heartbeats, so
the parent does the same by itself: a trial left RUNNING by a dead worker (seen by its process
sentinel, or at ``--resume`` after the whole run was killed) is failed and enqueued again with
the same parameters, at most ``max_retry`` times.

With ``[objective] kind = "cpu_s_to_beat_follower"`` the lap to beat (the follower bot's on the
objective's line of the key track, for the run's car) is driven once here, before any trial, and
handed to every worker; the study records it in its ``objective`` user attribute.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
from collections.abc import Callable
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import TrialState

from formula_tourney.agents.variants import ALL_VARIANTS
from formula_tourney.errors import UserInputError
from formula_tourney.tourney.executors import THREAD_ENV, default_workers
from formula_tourney.tourney.lock import RunLock
from formula_tourney.tourney.spec import load_spec
from formula_tourney.tourney.tune.best_params import write_best_params
from formula_tourney.tourney.tune.spec import TuneSpec, check_tune, load_tune_spec
from formula_tourney.tourney.tune.study import (
    counted,
    decode_params,
    fail_and_retry,
    make_pruner,
    make_sampler,
    sampler_seed,
    storage_for,
    worker_tag,
)
from formula_tourney.tourney.tune.worker import tune_worker
from formula_tourney.training.run_spec import RunSpec

Report = Callable[[str], None]
"""Receives one line of progress (the CLI prints it on stderr)."""


def run_tune(
    path: str | Path,
    variant: str,
    trials: int,
    workers: int | None = None,
    storage: str | None = None,
    resume: bool = False,
    write_best: str | Path | None = None,
    results_dir: str | Path = "results",
    report: Report | None = None,
) -> dict[str, Any]:
    """Create (or resume) the study in the parent, run trials in worker processes, summarise.

    The tune file, the variant, the trial specs at the corners of the search space and the
    ``--write-best`` target are all checked before anything is written.
    """
    path = Path(path)
    spec, text = load_tune_spec(path)
    if variant not in ALL_VARIANTS:
        raise UserInputError(f"--variant {variant!r}: unknown; allowed values: "
                             f"{', '.join(ALL_VARIANTS)}")
    if trials < 1:
        raise UserInputError(f"--trials must be >= 1, got {trials}")
    if workers is not None and workers < 1:
        raise UserInputError(f"--workers must be >= 1, got {workers}")
    base = check_tune(spec, text, path, variant)
    if write_best is not None:
        load_spec(Path(write_best))  # a broken target file fails now, not after hours of tuning
    threshold_s = objective_threshold(spec, base)  # once, before any trial
    root = Path(results_dir) / spec.name
    journal = root / "optuna" / f"{variant}.journal"
    study_name = f"{spec.name}-{variant}"
    if resume and storage is None and not journal.is_file():
        raise UserInputError(f"--resume: no study {study_name!r} ({journal} does not exist)")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # A storage URL is opened before the lock: a bad one leaves nothing in the results folder.
    url_store = None if storage is None else storage_for(storage, journal, spec.max_retry)
    with RunLock(root, what="tune"):
        store = url_store or storage_for(None, journal, spec.max_retry)
        names = [s.study_name for s in optuna.get_all_study_summaries(store)]
        if study_name in names and not resume:
            raise UserInputError(f"study {study_name!r} already exists in "
                                 f"{storage or journal}; add --resume to continue it")
        if study_name not in names and resume:
            raise UserInputError(f"--resume: no study {study_name!r} in {storage or journal}")
        study = optuna.create_study(study_name=study_name, storage=store, direction="minimize",
                                    sampler=make_sampler(spec, spec.sampler.seed),
                                    pruner=make_pruner(spec), load_if_exists=resume)
        objective = _objective_record(spec, study, threshold_s)
        study.set_user_attr("search", json.loads(json.dumps(
            {k: v.model_dump() for k, v in spec.search.items()})))
        study.set_user_attr("objective", objective)
        retried = 0
        if storage is None:
            # Nothing else can hold this journal (we hold the folder lock): RUNNING is stale.
            for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
                retried += fail_and_retry(study, trial, spec.max_retry,
                                          "process died (found at resume)")
        pool = _Workers(spec, variant, storage, journal, study_name, trials,
                        root / "tune" / variant, path.resolve().parent,
                        start_trials=len(study.get_trials(deepcopy=False)),
                        threshold_s=threshold_s)
        retried += pool.run(study, workers or default_workers(), report)
        result = _summarise(study, variant, storage or str(journal), retried, spec)
    if write_best is not None and result["best"] is not None:
        write_best_params(Path(write_best), variant, result["best"]["params"],
                          preset=spec.train.preset)
        result["written_to"] = str(write_best)
    return result


def objective_threshold(spec: TuneSpec, run: RunSpec) -> float | None:
    """The lap a CPU-second objective's milestone must get under: ``math.inf`` for the first
    clean lap; for cpu_s_to_beat_follower the follower bot's best clean lap of 2 on the
    objective's line of the key track, driven here for the run's car. None for best_lap."""
    kind = spec.objective.kind
    if kind == "best_lap":
        return None
    if kind == "cpu_s_to_first_clean_lap":
        return math.inf
    # the bots import numba kernels and the line solvers: only when this objective needs them
    from formula_tourney.bots.follower import drive
    from formula_tourney.bots.line_offsets import reference_offsets
    from formula_tourney.sim.catalog import load_track

    track = load_track(run.key_track)
    car = run.env.car_params()
    lap = float(drive(track, reference_offsets(track, spec.objective.line, car), laps=2,
                      car=car)["best_lap_s"])  # fmt: skip
    if not math.isfinite(lap):
        raise UserInputError(f"objective {kind}: the follower drove no clean lap on the "
                             f"{spec.objective.line} line of {run.key_track}: nothing to beat")
    return lap


def _objective_record(spec: TuneSpec, study: Any, threshold_s: float | None) -> dict[str, Any]:
    """The study's ``objective`` user attribute; a resumed study must keep its objective (the
    values of two objectives cannot be compared; a study from before objectives were recorded
    ran best_lap)."""
    record = spec.objective.model_dump()
    if spec.objective.cpu:
        record["miss_score"] = spec.objective.miss_score()
    record["threshold_s"] = threshold_s if math.isfinite(threshold_s or 0.0) else None
    stored = study.user_attrs.get("objective")
    if stored is None and study.get_trials(deepcopy=False):
        stored = type(spec.objective)().model_dump()
    if stored is not None:
        was = {k: stored.get(k) for k in spec.objective.model_dump()}
        if was != spec.objective.model_dump():
            raise UserInputError(f"--resume: study {study.study_name!r} was run with objective "
                                 f"{was}; the file now gives {spec.objective.model_dump()}")
    return record


class _Workers:
    """Keeps worker processes running trials until the study has enough counted ones; a worker
    that dies has its RUNNING trial failed and re-enqueued, and is replaced."""

    def __init__(self, spec: TuneSpec, variant: str, storage: str | None, journal: Path,
                 study_name: str, trials: int, trial_root: Path, base_dir: Path,
                 start_trials: int, threshold_s: float | None = None) -> None:
        self.spec = spec
        self.trials = trials
        self.start_trials = start_trials
        self.serial = 0
        self.args = (spec.model_dump_json(), variant, storage, str(journal), study_name, trials,
                     str(trial_root), str(base_dir), threshold_s)
        self.study_name = study_name
        self._ctx = mp.get_context("spawn")

    def _spawn(self) -> Any:
        # Each worker samples from its own stream: one seed for all drew identical trials.
        seed = sampler_seed(self.spec, self.start_trials, self.serial)
        self.serial += 1
        proc = self._ctx.Process(target=tune_worker, args=(*self.args, seed), daemon=True)
        proc.start()
        return proc

    def run(self, study: Any, workers: int, report: Report | None) -> int:
        for key in THREAD_ENV:
            os.environ.setdefault(key, "1")
        procs = [self._spawn() for _ in range(min(workers, self.trials))]
        retried = 0
        deaths = 0
        try:
            while procs:
                wait([p.sentinel for p in procs], timeout=2.0)
                for proc in [p for p in procs if not p.is_alive()]:
                    procs.remove(proc)
                    proc.join()
                    if proc.exitcode == 0:
                        continue
                    deaths += 1
                    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
                        if trial.user_attrs.get("worker") == worker_tag(proc.pid):
                            retried += fail_and_retry(study, trial, self.spec.max_retry,
                                                      f"worker exit code {proc.exitcode}")
                    if counted(study) < self.trials and deaths <= self.trials * (
                        self.spec.max_retry + 1
                    ):
                        procs.append(self._spawn())
                if report is not None:
                    report(f"tune {self.study_name}: {counted(study)}/{self.trials} trials")
        finally:
            for proc in procs:
                proc.terminate()
                proc.join(timeout=5)
        return retried


def _summarise(study: Any, variant: str, where: str, retried: int,
               spec: TuneSpec) -> dict[str, Any]:
    trials = study.get_trials(deepcopy=False)
    rows = [{"number": t.number, "state": t.state.name, "value": t.value,
             "params": decode_params(t.params, spec.search),
             "best_lap_s": t.user_attrs.get("best_lap_s"), "cpu_s": t.user_attrs.get("cpu_s"),
             "retry_of": t.system_attrs.get("failed_trial")} for t in trials]
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    best = None
    if complete:
        top = min(complete, key=lambda t: t.value)
        best = {"number": top.number, "value": top.value,
                "params": decode_params(top.params, spec.search),
                "best_lap_s": top.user_attrs.get("best_lap_s"),
                "cpu_s": top.user_attrs.get("cpu_s")}
    counts = {s.name: sum(t.state == s for t in trials) for s in TrialState}
    return {"study": study.study_name, "variant": variant, "storage": where,
            "objective": study.user_attrs.get("objective"), "trials": rows, "counts": counts,
            "best": best, "retried": retried}
