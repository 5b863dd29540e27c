"""The Optuna side of tuning: storage, sampler and pruner, suggestions, and trial retries.

Shared by the parent (``tourney.tune.run``, which creates the study) and the worker processes
(``tourney.tune.worker``, which load it and run trials). Each worker samples from its own random
stream, derived from ``[sampler] seed``, the study's size when the run started and the worker's
serial number: workers that all started from one seed drew the same parameters.
"""

from __future__ import annotations

import inspect
import json
import socket
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.storages import JournalStorage
from optuna.storages.journal import JournalFileBackend
from optuna.trial import TrialState

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import make_dirs
from formula_tourney.tourney.tune.spec import SearchParam, TuneSpec

HEARTBEAT_INTERVAL_S = 30
HEARTBEAT_GRACE_S = 120


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


STORAGE_SCHEMES = ("sqlite", "postgresql", "mysql")
"""``--storage`` URLs taken (SQLAlchemy's, with an optional driver: ``postgresql+psycopg2``)."""


def storage_for(url: str | None, journal: Path, max_retry: int) -> Any:
    """The study's storage: the journal file, or the RDB at ``url``. A URL of another scheme,
    or one that cannot be opened (a folder that does not exist, a server that does not answer),
    is one UserInputError naming it; nothing is written then."""
    if url is None:
        make_dirs(journal.parent, "study folder")
        return JournalStorage(JournalFileBackend(str(journal)))
    scheme = url.split(":", 1)[0].split("+", 1)[0] if ":" in url else ""
    if scheme not in STORAGE_SCHEMES:
        raise UserInputError(f"--storage {url!r}: unknown scheme {scheme!r}; allowed: "
                             f"{', '.join(f'{s}://...' for s in STORAGE_SCHEMES)}")
    try:
        return _rdb_storage(url, max_retry)
    except Exception as err:  # SQLAlchemy's errors run over many lines and name no option
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise UserInputError(f"--storage {url!r}: cannot open the study storage ({first})") \
            from None


def _rdb_storage(url: str, max_retry: int) -> Any:
    """Optuna's RDB storage with heartbeats and a retry of stale trials."""
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


def retry_count(trial: Any) -> int:
    return len(trial.system_attrs.get("retry_history", []))


def fail_and_retry(study: Any, trial: Any, max_retry: int, why: str) -> bool:
    """Mark a RUNNING trial failed and enqueue its parameters again (as Optuna's
    RetryFailedTrialCallback does for stale heartbeats). Returns whether it was re-enqueued."""
    study._storage.set_trial_system_attr(trial._trial_id, "fail_reason", why)
    study._storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)
    if retry_count(trial) >= max_retry:
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


def counted(study: Any) -> int:
    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


def sampler_seed(spec: TuneSpec, start_trials: int, serial: int) -> int | None:
    """The seed of one worker's sampler: reproducible from the file, distinct per worker."""
    if spec.sampler.seed is None:
        return None
    stream = np.random.SeedSequence([spec.sampler.seed, start_trials, serial])
    return int(stream.generate_state(1)[0])


def make_sampler(spec: TuneSpec, seed: int | None) -> Any:
    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=spec.sampler.n_startup_trials)


def make_pruner(spec: TuneSpec) -> Any:
    if spec.pruner.kind == "none":
        return optuna.pruners.NopPruner()
    return optuna.pruners.MedianPruner(n_startup_trials=spec.pruner.n_startup_trials,
                                       n_warmup_steps=spec.pruner.n_warmup_steps)


def worker_tag(pid: int | None) -> str:
    """host:pid of a trial's process: pids alone collide between machines sharing an RDB."""
    return f"{socket.gethostname()}:{pid}"
