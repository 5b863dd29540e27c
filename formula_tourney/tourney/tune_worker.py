"""A tune worker process: load the study (never create it) and run trials until it holds enough.

A trial is one training job (``tourney.runner.run_job``) whose run specification is the tune
file's ``[train]`` with the trial's hyperparameters (``tourney.tune_spec.trial_spec``). The
objective is the best clean test lap on the key track; each periodic test reports it to the
pruner, and a pruned trial stops its run at once (``train``'s progress returns False).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import optuna
from optuna.study import MaxTrialsCallback
from optuna.trial import TrialState

from formula_tourney.tourney.executors import die_with_parent
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.outcomes import job_metrics
from formula_tourney.tourney.runner import run_job
from formula_tourney.tourney.tune_spec import TuneSpec, trial_spec
from formula_tourney.tourney.tune_study import (
    counted,
    make_pruner,
    make_sampler,
    storage_for,
    suggest,
    worker_tag,
)


def objective(trial: Any, spec: TuneSpec, variant: str, trial_root: Path, base_dir: Path) -> float:
    """Train one trial; its value is the best clean test lap (or the no-finish penalty)."""
    trial.set_user_attr("worker", worker_tag(os.getpid()))
    params = suggest(trial, spec.search)
    out_dir = trial_root / f"trial-{trial.number}"
    job_id = f"tune/{variant}/trial-{trial.number}"
    run = trial_spec(spec, variant, params, base_dir, job_id)
    job = Job(job_id=job_id, kind="train", part="tune", out_dir=str(out_dir), spec=run.to_json(),
              config_hash=run.digest(), meta={"variant": variant, "trial": trial.number,
                                              "part": "tune"})  # fmt: skip
    penalty = spec.no_finish_penalty_s
    every = run.schedule.test_every_episodes
    episodes = run.schedule.episodes
    pruned: list[str] = []

    def progress(info: dict[str, Any]) -> bool | None:
        # best_lap_s is the best clean *test* lap on the key track so far: it changes only at
        # the periodic tests, which are the steps reported to the pruner.
        episode = int(info.get("episode", 0))
        if episode % every and episode != episodes:
            return None
        lap = info.get("best_lap_s")
        lap = penalty if lap is None or math.isnan(float(lap)) else float(lap)
        trial.report(lap, step=episode)
        if trial.should_prune():
            pruned.append(f"pruned at episode {episode}: best test lap {lap:.2f} s")
            return False  # the run stops here and still writes its summary
        return None

    run_job(job, progress)
    if pruned:
        raise optuna.TrialPruned(pruned[0])
    lap = job_metrics(out_dir, job.config_hash)["best_lap_s"]
    trial.set_user_attr("best_lap_s", None if math.isnan(lap) else lap)
    return penalty if math.isnan(lap) else lap


def tune_worker(spec_json: str, variant: str, storage_url: str | None, journal: str,
                study_name: str, trials: int, trial_root: str, base_dir: str,
                sampler_seed: int | None) -> None:
    """Process entry point: run trials until the study has ``trials`` counted ones."""
    die_with_parent(os.getppid())
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    spec = TuneSpec.model_validate_json(spec_json)
    storage = storage_for(storage_url, Path(journal), spec.max_retry)
    study = optuna.load_study(study_name=study_name, storage=storage,
                              sampler=make_sampler(spec, sampler_seed), pruner=make_pruner(spec))
    if counted(study) >= trials:
        return
    study.optimize(
        lambda t: objective(t, spec, variant, Path(trial_root), Path(base_dir)),
        callbacks=[MaxTrialsCallback(trials, states=(TrialState.COMPLETE, TrialState.PRUNED))],
        catch=(Exception,),
        gc_after_trial=True,
    )
