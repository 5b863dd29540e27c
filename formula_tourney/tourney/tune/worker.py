"""A tune worker process: load the study (never create it) and run trials until it holds enough.

A trial is one training job (``tourney.runner.run_job``) whose run specification is the tune
file's ``[train]`` with the trial's hyperparameters (``tourney.tune.spec.trial_spec``). The
objective (``[objective] kind``) is the best clean test lap on the key track, or the CPU-seconds
of training to a milestone (:class:`CpuMilestone`, on the training loop's CPU clock; the trial's
schedule carries the objective's ``budget_cpu_s``, so the loop ends it there as it ends any run
with a CPU budget, ``training.budget``); each periodic test reports to the pruner, and a pruned
trial stops its run at once (``train``'s progress returns False).
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
from formula_tourney.tourney.tune.spec import Objective, TuneSpec, trial_spec
from formula_tourney.tourney.tune.study import (
    counted,
    make_pruner,
    make_sampler,
    storage_for,
    suggest,
    worker_tag,
)

PRUNE_STEPS = 100
"""A CPU-second objective reports to the pruner at step = percent of the budget spent."""


class CpuMilestone:
    """The arithmetic of a CPU-second objective, fed the training loop's progress dicts.

    Each dict's ``cpu_s`` is the run's CPU-seconds since training started, on the loop's clock
    (``training.budget.CpuClock``: this process's CPU time, every thread), which also times
    the tests in ``tests.parquet`` and stops a run at its ``budget_cpu_s``. The milestone is reached
    at the first episode whose ``best_lap_s`` (the model's clean lap on the key track so far,
    which changes only at the periodic tests) is below ``threshold_s``: ``math.inf`` for the
    first clean lap, the follower's lap to beat it. Its value is the CPU-seconds then, if within
    ``budget_cpu_s``; a miss (budget spent first, or the run's episodes) scores
    ``budget_cpu_s x penalty_factor``.

    For the pruner, :meth:`projected` is the value the trial would score if it stopped now: the
    miss score until the milestone, its CPU-seconds from then on. Within a trial that sequence
    never rises, as the median pruner needs (it compares a trial's *best* reported value so far
    with the median of the complete trials' values at the same step); a rising "CPU so far"
    would leave every trial its first, smallest value and never prune. Steps are percent of the
    budget (:meth:`step`), and a complete trial reports its whole :meth:`series`, so at any step
    a running trial that has not reached its milestone is pruned when at least half of the
    complete trials had reached theirs with that much CPU.
    """

    def __init__(self, objective: Objective, threshold_s: float) -> None:
        if not objective.cpu or objective.budget_cpu_s is None:
            raise ValueError(f"{objective.kind} is not a CPU-second objective with a budget")
        self.budget_cpu_s = float(objective.budget_cpu_s)
        self.miss_s = objective.miss_score()
        self.threshold_s = float(threshold_s)
        self.cpu_s = 0.0
        """CPU-seconds of training at the last progress call."""
        self.hit: dict[str, float] | None = None
        """cpu_s, episode, lap_s and env_steps of the episode that reached the milestone."""

    def update(self, info: dict[str, Any]) -> bool:
        """Take an episode's progress; True when the trial should stop (milestone reached, or
        the budget spent)."""
        self.cpu_s = float(info["cpu_s"])
        lap = info.get("best_lap_s")
        if (self.hit is None and lap is not None and math.isfinite(float(lap))
                and float(lap) < self.threshold_s and self.cpu_s <= self.budget_cpu_s):
            self.hit = {"cpu_s": self.cpu_s, "episode": int(info.get("episode", 0)),
                        "lap_s": float(lap), "env_steps": int(info.get("env_steps", 0))}
        return self.hit is not None or self.cpu_s > self.budget_cpu_s

    def projected(self) -> float:
        """The trial's value if it stopped now: its milestone's CPU-seconds, else the miss."""
        return self.miss_s if self.hit is None else self.hit["cpu_s"]

    value = projected  # at the end of the run the projection is the value

    def step(self) -> int:
        """The pruner step of the last progress call: percent of the budget spent (<= 100)."""
        return min(PRUNE_STEPS, int(PRUNE_STEPS * self.cpu_s / self.budget_cpu_s))

    def series(self) -> dict[int, float]:
        """The value known at the end of every step 0..100: the miss score before the
        milestone's step, its CPU-seconds from it on (what a complete trial reports)."""
        if self.hit is None:
            return dict.fromkeys(range(PRUNE_STEPS + 1), self.miss_s)
        at = min(PRUNE_STEPS, int(PRUNE_STEPS * self.hit["cpu_s"] / self.budget_cpu_s))
        return {s: self.hit["cpu_s"] if s >= at else self.miss_s for s in range(PRUNE_STEPS + 1)}


def objective(trial: Any, spec: TuneSpec, variant: str, trial_root: Path, base_dir: Path,
              threshold_s: float | None = None) -> float:
    """Train one trial; its value is the best clean test lap (or the no-finish penalty), or
    for a CPU-second objective the CPU-seconds to its milestone (``threshold_s``: the lap to
    get under, from the parent) or the miss score."""
    trial.set_user_attr("worker", worker_tag(os.getpid()))
    params = suggest(trial, spec.search)
    out_dir = trial_root / f"trial-{trial.number}"
    job_id = f"tune/{variant}/trial-{trial.number}"
    run = trial_spec(spec, variant, params, base_dir, job_id)
    if spec.objective.cpu:  # the loop ends the trial at its budget, as any CPU-budget run
        schedule = run.schedule.model_copy(update={"budget_cpu_s": spec.objective.budget_cpu_s})
        run = run.model_copy(update={"schedule": schedule})
    job = Job(job_id=job_id, kind="train", part="tune", out_dir=str(out_dir), spec=run.to_json(),
              config_hash=run.digest(), meta={"variant": variant, "trial": trial.number,
                                              "part": "tune"})  # fmt: skip
    if spec.objective.cpu:
        assert threshold_s is not None, "the parent computes the threshold of a CPU objective"
        return _cpu_objective(trial, spec, run, job, out_dir, threshold_s)
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


def _cpu_objective(trial: Any, spec: TuneSpec, run: Any, job: Job, out_dir: Path,
                   threshold_s: float) -> float:
    """One trial of a CPU-second objective: stop at the milestone or the budget, report the
    projected value at every test (and at the stop), and the whole series when complete."""
    every = run.schedule.test_every_episodes
    episodes = run.schedule.episodes
    clock = CpuMilestone(spec.objective, threshold_s)
    reported: set[int] = set()
    pruned: list[str] = []

    def progress(info: dict[str, Any]) -> bool | None:
        stop = clock.update(info)
        episode = int(info.get("episode", 0))
        if episode % every and episode != episodes and not stop:
            return None
        step = clock.step()
        if step not in reported:  # two tests in one percent: the first one's value stands
            reported.add(step)
            trial.report(clock.projected(), step=step)
            if not stop and trial.should_prune():
                pruned.append(f"pruned at {clock.cpu_s:.1f} CPU-s (episode {episode}): "
                              "milestone not reached")
                return False
        return False if stop else None

    run_job(job, progress)
    trial.set_user_attr("cpu_s_used", round(clock.cpu_s, 3))
    if pruned:
        raise optuna.TrialPruned(pruned[0])
    for step, value in clock.series().items():
        if step not in reported:
            trial.report(value, step=step)
    lap = job_metrics(out_dir, job.config_hash)["best_lap_s"]
    trial.set_user_attr("best_lap_s", None if math.isnan(lap) else lap)
    trial.set_user_attr("cpu_s", None if clock.hit is None else clock.hit["cpu_s"])
    trial.set_user_attr("milestone_episode", None if clock.hit is None else clock.hit["episode"])
    return clock.value()


def tune_worker(spec_json: str, variant: str, storage_url: str | None, journal: str,
                study_name: str, trials: int, trial_root: str, base_dir: str,
                threshold_s: float | None, sampler_seed: int | None) -> None:
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
        lambda t: objective(t, spec, variant, Path(trial_root), Path(base_dir), threshold_s),
        callbacks=[MaxTrialsCallback(trials, states=(TrialState.COMPLETE, TrialState.PRUNED))],
        catch=(Exception,),
        gc_after_trial=True,
    )
