"""Optuna pre-selection of one variant's hyperparameters: TPE, pruning on periodic test laps.

The paper tunes on the oval before the tournament proper (Study 1, part 1); this is that step as
an Optuna study. The search space is declared in TOML (``[search]``), keys are the variant's
hyperparameters (``agents.variants.AgentConfig``). The objective is the best clean test lap on
the first train track (lower is better; no clean lap scores ``no_finish_penalty_s``), never the
return, which ranks laps poorly (DESIGN.md). Each periodic test reports its lap so the pruner
stops hopeless trials early.

Processes: the study is created once, in the parent (two processes creating one SQLite study at
once crashed one, DESIGN.md); worker processes load it and run trials. Storage defaults to a
``JournalFileBackend`` under the results folder (~10x faster than SQLite for two processes, and
needs no server); ``--storage URL`` takes an RDB for many machines, where Optuna's heartbeats plus
``RetryFailedTrialCallback`` retry trials whose process died. The journal has no heartbeats, so
the parent does the same by itself: a trial left RUNNING by a dead worker (seen by its process
sentinel, or at ``--resume`` after the whole run was killed) is failed and enqueued again with
the same parameters, at most ``max_retry`` times.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_text, check_name, read_user_text
from formula_tourney.tourney.lock import RunLock
from formula_tourney.tourney.spec import JobSettings, Setup, describe_errors, error_at

HEARTBEAT_INTERVAL_S = 30
HEARTBEAT_GRACE_S = 120


class SearchParam(BaseModel):
    """One dimension of the search space: a float/int range or a list of choices."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: Literal["float", "int", "categorical"] | None = Field(
        None, description="float, int or categorical (default: categorical with choices, "
        "int when low and high are integers, else float)."
    )
    low: float | None = Field(None, description="Lower bound (inclusive).")
    high: float | None = Field(None, description="Upper bound (inclusive).")
    log: bool = Field(False, description="Sample on a log scale (learning rates).")
    step: float | None = Field(None, gt=0, description="Grid step inside [low, high].")
    choices: list[Any] | None = Field(None, min_length=1, description="Values to choose from.")

    @model_validator(mode="after")
    def _shape(self) -> SearchParam:
        if self.choices is None and (self.low is None or self.high is None):
            raise ValueError("give low and high, or choices")
        if self.low is not None and self.high is not None and self.low > self.high:
            raise ValueError("low must be <= high")
        if self.log and self.low is not None and self.low <= 0:
            raise ValueError("log scale needs low > 0")
        return self

    def kind(self) -> str:
        if self.type is not None:
            return self.type
        if self.choices is not None:
            return "categorical"
        if float(self.low).is_integer() and float(self.high).is_integer() and (
            self.step is None or float(self.step).is_integer()
        ) and not self.log:
            return "int"
        return "float"


class TuneTrain(JobSettings):
    """What each trial trains: tracks, one reference setup, and the job settings."""

    train_tracks: list[str] = Field(min_length=1, description="Tracks trained on; the lap on "
                                    "the first is the objective.")
    test_tracks: list[str] | None = Field(None, description="Tracks tested (default: train).")
    setup: Setup = Field(default_factory=Setup, description="Reference line and LAC.")
    seed: int = Field(0, ge=0, description="Training seed of every trial (one seed per trial).")


class Sampler(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    seed: int | None = Field(0, description="TPE seed (reproducible suggestions).")
    n_startup_trials: int = Field(5, ge=0, description="Random trials before TPE models.")


class Pruner(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["median", "none"] = Field("median", description="median: stop a trial whose "
                                            "test lap is worse than the median at that episode.")
    n_startup_trials: int = Field(3, ge=0, description="Trials never pruned.")
    n_warmup_steps: int = Field(0, ge=0, description="Episodes before pruning starts.")


class TuneSpec(BaseModel):
    """A tune file: ``[train]`` settings, ``[search]`` space, sampler, pruner, retries."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(description="Results go to <results>/<name>/optuna/.")
    train: TuneTrain = Field(description="What each trial trains.")
    search: dict[str, SearchParam] = Field(min_length=1, description="Search space by "
                                           "hyperparameter name.")
    sampler: Sampler = Field(default_factory=Sampler, description="TPE sampler settings.")
    pruner: Pruner = Field(default_factory=Pruner, description="Pruner settings.")
    max_retry: int = Field(2, ge=0, description="Times a trial killed with its process is "
                           "run again with the same parameters.")
    no_finish_penalty_s: float = Field(1000.0, gt=0, description="Objective of a trial "
                                       "without a clean lap.")


def load_tune_spec(path: str | Path) -> tuple[TuneSpec, str]:
    """Read and validate a tune file (search keys checked against AgentConfig's fields)."""
    path = Path(path)
    text = read_user_text(path, "tune")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise UserInputError(f"{path}: not valid TOML: {err}") from None
    try:
        spec = TuneSpec.model_validate(raw)
    except ValidationError as err:
        raise UserInputError(describe_errors(err, path, text)) from None
    try:
        check_name(spec.name, "tune name")
    except UserInputError as err:
        raise error_at(path, text, ("name",), str(err)) from None
    from formula_tourney.agents.variants import AgentConfig

    allowed = [k for k in AgentConfig.model_fields if k not in ("name", "family")]
    for key in spec.search:
        if key not in allowed:
            raise error_at(path, text, ("search", key),
                           f"unknown hyperparameter; allowed values: {', '.join(allowed)}")
    return spec, text


def _train_kwargs(spec: TuneSpec, variant: str, overrides: dict[str, Any]) -> dict[str, Any]:
    train = spec.train
    kwargs: dict[str, Any] = {
        "variant": variant, "overrides": overrides, "train_tracks": list(train.train_tracks),
        "test_tracks": list(train.test_tracks or train.train_tracks),
        "reference": train.setup.reference, "lac": train.setup.lac, "seed": train.seed,
    }
    for key in JobSettings.model_fields:
        value = getattr(train, key)
        if key == "variant_overrides" and value:
            kwargs["overrides"] = {**value, **overrides}
        elif key not in ("seeds", "variant_overrides") and value is not None:
            kwargs[key] = value
    return kwargs


def suggest(trial: Any, search: dict[str, SearchParam]) -> dict[str, Any]:
    """Draw one point of the search space (public Optuna API only)."""
    params: dict[str, Any] = {}
    for name, p in search.items():
        kind = p.kind()
        if kind == "categorical" and all(_primitive(c) for c in p.choices or []):
            params[name] = trial.suggest_categorical(name, p.choices)
        elif kind == "categorical":
            # Persistent storages keep only primitives: store lists (e.g. hidden = [64, 64])
            # as their JSON text, decoded again by decode_params.
            raw = trial.suggest_categorical(name, [json.dumps(c) for c in p.choices or []])
            params[name] = json.loads(raw)
        elif kind == "int":
            params[name] = trial.suggest_int(name, int(p.low), int(p.high),
                                             step=int(p.step or 1), log=p.log)
        else:
            params[name] = trial.suggest_float(name, float(p.low), float(p.high),
                                               step=p.step, log=p.log)
    return params


def _primitive(value: Any) -> bool:
    return value is None or isinstance(value, bool | int | float | str)


def decode_params(params: dict[str, Any], search: dict[str, SearchParam]) -> dict[str, Any]:
    """Trial parameters as hyperparameter values (JSON-encoded list choices decoded)."""
    out = dict(params)
    for name, p in search.items():
        if name in out and p.choices is not None and not all(_primitive(c) for c in p.choices):
            out[name] = json.loads(out[name])
    return out


# ------------------------------------------------------------------------------ storage


def _storage(url: str | None, journal: Path, max_retry: int) -> Any:
    import optuna

    if url is None:
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend

        journal.parent.mkdir(parents=True, exist_ok=True)
        return JournalStorage(JournalFileBackend(str(journal)))
    if url.startswith(("sqlite:", "postgresql", "mysql")):
        import inspect
        import warnings

        callback_cls = getattr(optuna.storages, "RetryHeartbeatStaleTrialCallback", None) or (
            optuna.storages.RetryFailedTrialCallback
        )
        # Optuna 4.9 renamed failed_trial_callback to heartbeat_stale_trial_callback.
        params = inspect.signature(optuna.storages.RDBStorage).parameters
        key = ("heartbeat_stale_trial_callback" if "heartbeat_stale_trial_callback" in params
               else "failed_trial_callback")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.storages.RDBStorage(
                url, heartbeat_interval=HEARTBEAT_INTERVAL_S, grace_period=HEARTBEAT_GRACE_S,
                **{key: callback_cls(max_retry=max_retry)},
            )
    return url  # e.g. a gRPC proxy; Optuna parses it


def _retry_count(trial: Any) -> int:
    return len(trial.system_attrs.get("retry_history", []))


def fail_and_retry(study: Any, trial: Any, max_retry: int, why: str) -> bool:
    """Mark a RUNNING trial failed and enqueue its parameters again (as Optuna's
    RetryFailedTrialCallback does for stale heartbeats). Returns whether it was re-enqueued."""
    import optuna
    from optuna.trial import TrialState

    study._storage.set_trial_system_attr(trial._trial_id, "fail_reason", why)
    study._storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)
    if _retry_count(trial) >= max_retry:
        return False
    history = list(trial.system_attrs.get("retry_history", [])) + [trial.number]
    study.add_trial(
        optuna.trial.create_trial(
            state=TrialState.WAITING, params=trial.params, distributions=trial.distributions,
            user_attrs={k: v for k, v in trial.user_attrs.items() if k != "worker"},
            system_attrs={"failed_trial": history[0], "retry_history": history},
        )
    )
    return True


def _counted(study: Any) -> int:
    from optuna.trial import TrialState

    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


# ------------------------------------------------------------------------------ workers


def _objective(trial: Any, spec: TuneSpec, variant: str, trial_root: Path) -> float:
    import optuna

    from formula_tourney.tourney.plan import Job
    from formula_tourney.tourney.runner import job_metrics, run_job

    trial.set_user_attr("worker", _worker_tag(os.getpid()))
    overrides = suggest(trial, spec.search)
    out_dir = trial_root / f"trial-{trial.number}"
    job = Job(job_id=f"tune/{variant}/trial-{trial.number}", kind="train", part="tune",
              out_dir=str(out_dir), config=_train_kwargs(spec, variant, overrides),
              meta={"variant": variant, "trial": trial.number, "part": "tune"})
    track = spec.train.train_tracks[0]
    penalty = spec.no_finish_penalty_s
    every = int(job.config.get("test_every_episodes") or 10)
    episodes = int(job.config.get("episodes") or 100)

    def progress(info: dict[str, Any]) -> None:
        # training.loop reports after every episode; best_lap_s there is the best clean *test*
        # lap on the first train track so far, so it changes only at the periodic tests.
        episode = int(info.get("episode", 0))
        if episode % every and episode != episodes:
            return
        lap = info.get("best_lap_s")
        lap = penalty if lap is None or math.isnan(float(lap)) else float(lap)
        trial.report(lap, step=episode)
        if trial.should_prune():
            raise optuna.TrialPruned(f"pruned at episode {episode}: best test lap {lap:.2f} s")

    run_job(job, progress)
    lap = job_metrics(out_dir, track)["best_lap_s"]
    trial.set_user_attr("best_lap_s", None if math.isnan(lap) else lap)
    return penalty if math.isnan(lap) else lap


def _tune_worker(spec_json: str, variant: str, storage_url: str | None, journal: str,
                 study_name: str, trials: int, trial_root: str) -> None:
    """A worker process: load the study (never create it) and run trials until enough."""
    import optuna
    from optuna.study import MaxTrialsCallback
    from optuna.trial import TrialState

    from formula_tourney.tourney.executors import _die_with_parent

    _die_with_parent(os.getppid())
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    spec = TuneSpec.model_validate_json(spec_json)
    storage = _storage(storage_url, Path(journal), spec.max_retry)
    study = optuna.load_study(study_name=study_name, storage=storage,
                              sampler=_sampler(spec), pruner=_pruner(spec))
    if _counted(study) >= trials:
        return
    study.optimize(
        lambda t: _objective(t, spec, variant, Path(trial_root)),
        callbacks=[MaxTrialsCallback(trials, states=(TrialState.COMPLETE, TrialState.PRUNED))],
        catch=(Exception,),
        gc_after_trial=True,
    )


def _sampler(spec: TuneSpec) -> Any:
    import optuna

    return optuna.samplers.TPESampler(seed=spec.sampler.seed,
                                      n_startup_trials=spec.sampler.n_startup_trials)


def _pruner(spec: TuneSpec) -> Any:
    import optuna

    if spec.pruner.kind == "none":
        return optuna.pruners.NopPruner()
    return optuna.pruners.MedianPruner(n_startup_trials=spec.pruner.n_startup_trials,
                                       n_warmup_steps=spec.pruner.n_warmup_steps)


# ------------------------------------------------------------------------------ parent


def run_tune(
    path: str | Path,
    variant: str,
    trials: int,
    workers: int | None = None,
    storage: str | None = None,
    resume: bool = False,
    write_best: str | Path | None = None,
    results_dir: str | Path = "results",
    show_progress: bool = True,
) -> dict[str, Any]:
    """Create (or resume) the study in the parent, run trials in worker processes, report."""
    import optuna
    from optuna.trial import TrialState

    from formula_tourney.agents.variants import VARIANTS, get_variant

    spec, text = load_tune_spec(path)
    if variant not in VARIANTS:
        raise UserInputError(f"--variant {variant!r}: unknown; allowed values: "
                             f"{', '.join(VARIANTS)}")
    if trials < 1:
        raise UserInputError(f"--trials must be >= 1, got {trials}")
    get_variant(variant, {})
    if write_best is not None:
        from formula_tourney.tourney.spec import load_spec

        load_spec(write_best)  # a broken target file fails now, not after hours of tuning
    root = Path(results_dir) / spec.name
    journal = root / "optuna" / f"{variant}.journal"
    study_name = f"{spec.name}-{variant}"
    workers = workers or _cores()
    with RunLock(root, what="tune"):
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        store = _storage(storage, journal, spec.max_retry)
        names = [s.study_name for s in optuna.get_all_study_summaries(store)]
        if study_name in names and not resume:
            raise UserInputError(f"study {study_name!r} already exists in "
                                 f"{storage or journal}; add --resume to continue it")
        if study_name not in names and resume:
            raise UserInputError(f"--resume: no study {study_name!r} in {storage or journal}")
        study = optuna.create_study(study_name=study_name, storage=store, direction="minimize",
                                    sampler=_sampler(spec), pruner=_pruner(spec),
                                    load_if_exists=resume)
        study.set_user_attr("search", json.loads(json.dumps(
            {k: v.model_dump() for k, v in spec.search.items()})))
        retried = 0
        if storage is None:
            # Nothing else can hold this journal (we hold the folder lock): RUNNING is stale.
            for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
                retried += fail_and_retry(study, trial, spec.max_retry,
                                          "process died (found at resume)")
        retried += _run_workers(spec, variant, storage, journal, study, study_name, trials,
                                workers, root / "tune" / variant, show_progress)
        result = _summarise(study, variant, storage or str(journal), retried, spec)
    if write_best is not None and result["best"] is not None:
        write_best_params(Path(write_best), variant, result["best"]["params"])
        result["written_to"] = str(write_best)
    return result


def _worker_tag(pid: int | None) -> str:
    """host:pid of a trial's process: pids alone collide between machines sharing an RDB."""
    import socket

    return f"{socket.gethostname()}:{pid}"


def _cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 1


def _run_workers(spec: TuneSpec, variant: str, storage: str | None, journal: Path, study: Any,
                 study_name: str, trials: int, workers: int, trial_root: Path,
                 show_progress: bool) -> int:
    """Keep ``workers`` processes running trials until the study has ``trials`` counted ones;
    a worker that dies has its RUNNING trial failed and re-enqueued, and is replaced."""
    from multiprocessing.connection import wait

    from optuna.trial import TrialState

    from formula_tourney.commands.output import message
    from formula_tourney.tourney.executors import THREAD_ENV

    for key in THREAD_ENV:
        os.environ.setdefault(key, "1")
    ctx = mp.get_context("spawn")
    args = (spec.model_dump_json(), variant, storage, str(journal), study_name, trials,
            str(trial_root))
    procs = []
    for _ in range(min(workers, trials)):
        proc = ctx.Process(target=_tune_worker, args=args, daemon=True)
        proc.start()
        procs.append(proc)
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
                    if trial.user_attrs.get("worker") == _worker_tag(proc.pid):
                        retried += fail_and_retry(study, trial, spec.max_retry,
                                                  f"worker exit code {proc.exitcode}")
                if _counted(study) < trials and deaths <= trials * (spec.max_retry + 1):
                    new = ctx.Process(target=_tune_worker, args=args, daemon=True)
                    new.start()
                    procs.append(new)
            if show_progress:
                message(f"tune {study_name}: {_counted(study)}/{trials} trials")
    finally:
        for proc in procs:
            proc.terminate()
            proc.join(timeout=5)
    return retried


def _summarise(study: Any, variant: str, where: str, retried: int,
               spec: TuneSpec) -> dict[str, Any]:
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    rows = [{"number": t.number, "state": t.state.name, "value": t.value,
             "params": decode_params(t.params, spec.search),
             "best_lap_s": t.user_attrs.get("best_lap_s"),
             "retry_of": t.system_attrs.get("failed_trial")} for t in trials]
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    best = None
    if complete:
        top = min(complete, key=lambda t: t.value)
        best = {"number": top.number, "value": top.value,
                "params": decode_params(top.params, spec.search),
                "best_lap_s": top.user_attrs.get("best_lap_s")}
    counts = {s.name: sum(t.state == s for t in trials) for s in TrialState}
    return {"study": study.study_name, "variant": variant, "storage": where, "trials": rows,
            "counts": counts, "best": best, "retried": retried}


def render_tune(console: Any, result: dict[str, Any]) -> None:
    from rich.table import Table

    table = Table(title=f"{result['study']} ({result['storage']})")
    for col in ("trial", "state", "objective s", "params"):
        table.add_column(col)
    for row in result["trials"]:
        value = "-" if row["value"] is None else f"{row['value']:.2f}"
        table.add_row(str(row["number"]), row["state"], value, json.dumps(row["params"]))
    console.print(table)
    if result["best"]:
        console.print(f"best: trial {result['best']['number']} {result['best']['params']}")
    if result.get("written_to"):
        console.print(f"written to {result['written_to']}")


# ------------------------------------------------------------------------------ --write-best


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise UserInputError(f"cannot write {value!r} to TOML")


def write_best_params(path: Path, variant: str, params: dict[str, Any]) -> None:
    """Merge ``params`` into ``[variants.<variant>] overrides`` of a tournament file.

    Edits the text (comments and layout elsewhere survive): an existing ``overrides`` line or
    ``[variants.X.overrides]`` table is replaced, else the entry is added. The result is
    validated as a tournament before it atomically replaces the file.
    """
    from formula_tourney.tourney.spec import parse_spec

    text = path.read_text(encoding="utf-8")
    current = tomllib.loads(text).get("variants", {}).get(variant, {}).get("overrides", {})
    merged = {**current, **params}
    inline = "overrides = {" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in merged.items())
    inline += "}"
    lines = text.splitlines()
    header = f"[variants.{variant}]"
    sub = f"[variants.{variant}.overrides]"
    stripped = [ln.strip() for ln in lines]
    if sub in stripped:
        start = stripped.index(sub)
        end = start + 1
        while end < len(lines) and not stripped[end].startswith("["):
            end += 1
        body = [f"{k} = {_toml_value(v)}" for k, v in merged.items()]
        lines[start + 1:end] = body + [""]
    elif header in stripped:
        start = stripped.index(header)
        end = start + 1
        while end < len(lines) and not stripped[end].startswith("["):
            end += 1
        for i in range(start + 1, end):
            if stripped[i].startswith("overrides"):
                lines[i] = inline
                break
        else:
            lines.insert(start + 1, inline)
    else:
        lines += ["", header, inline]
    new_text = "\n".join(lines).rstrip("\n") + "\n"
    from formula_tourney.tourney.plan import validate_plan

    validate_plan(parse_spec(new_text, path), path, new_text, Path("results"))
    atomic_write_text(path, new_text)
