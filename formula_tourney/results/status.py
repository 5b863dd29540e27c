"""Where a tournament stands, read from another shell while its ``run`` may still be writing.

``formula-tourney status RESULTS/NAME`` renders :func:`tournament_status`. Everything comes from
files a run keeps current: the index (``results.index``: a read-only SQLite connection, so a
reader never blocks the run's writes, which go through WAL), ``estimate.json`` (``run
--estimate``) and the run's lock file, whose text names the pid of the ``run`` that holds the
folder. Nothing here writes or takes a lock.

A job the index calls ``running`` while no live ``run`` holds the folder (the run was killed,
or its machine went down) is counted as **interrupted**: nobody is working on it, and the next
``run`` of the tournament puts it back to pending and starts it again.
"""

from __future__ import annotations

import math
import os
import time
from calendar import timegm
from pathlib import Path
from typing import Any

import pandas as pd
from pydantic import BaseModel, ConfigDict, Field

from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import CorruptResultError, read_json_file
from formula_tourney.results.index import index_path, read_index
from formula_tourney.results.layout import ESTIMATE_FILE, LOCK_FILE

STATES = ("done", "running", "interrupted", "pending", "failed")
"""The states ``status`` counts, in the order it shows them."""


class TournamentStatus(BaseModel):
    """What ``status`` shows: job counts, CPU time against the estimate, and an ETA."""

    model_config = ConfigDict(extra="forbid")

    tournament: str = Field(description="The tournament folder read.")
    run_pid: int | None = Field(description="Pid of the run named by the lock file; None when "
                                "no run has held the folder.")
    run_alive: bool = Field(description="Whether that run is alive on this machine.")
    counts: dict[str, dict[str, int]] = Field(
        description="Per job kind (train, baseline, race, ...): jobs in each of STATES.")
    total: dict[str, int] = Field(description="Jobs in each of STATES over all kinds.")
    parts_not_planned: list[str] = Field(
        description="Parts whose jobs are not in the index yet (they wait for a promotion); "
        "their jobs are in no count.")
    cpu_s_spent: float = Field(
        description="CPU seconds spent: finished and failed jobs' own seconds (wall_s, else "
        "train_seconds) plus the seconds running jobs have run so far.")
    cpu_s_estimate: float | None = Field(
        description="The whole tournament's CPU seconds from estimate.json; None without one.")
    workers: int = Field(description="Workers the ETA divides by (1 where nothing says).")
    workers_basis: str = Field(description="Where the worker count comes from.")
    eta_s: float | None = Field(description="Seconds until the planned jobs are done; None "
                                "when no job has finished to time the rest by.")
    eta_basis: str = Field(description="How the ETA was computed, in words.")


def _lock_pid(root: Path) -> int | None:
    """The pid the lock file names (``run pid N``; ``tourney.lock`` writes it), or None."""
    try:
        text = (root / LOCK_FILE).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    words = text.split()
    return int(words[-1]) if words and words[-1].isdigit() else None


def pid_alive(pid: int | None) -> bool:
    """Whether process ``pid`` exists on this machine (signal 0 only checks, sends nothing)."""
    if pid is None or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process: it exists
    return True


def _epoch_s(stamp: Any) -> float:
    """A ``started_at`` stamp (UTC, ``%Y-%m-%dT%H:%M:%SZ``) as epoch seconds; nan if absent."""
    if not isinstance(stamp, str) or not stamp:
        return math.nan
    try:
        return float(timegm(time.strptime(stamp.rstrip("Z")[:19], "%Y-%m-%dT%H:%M:%S")))
    except ValueError:
        return math.nan


def _job_seconds(jobs: pd.DataFrame) -> pd.Series:
    """Each job's own seconds: ``wall_s``, else the trainer's ``train_seconds``."""
    wall = pd.to_numeric(jobs["wall_s"], errors="coerce")
    if "train_seconds" in jobs.columns:
        wall = wall.fillna(pd.to_numeric(jobs["train_seconds"], errors="coerce"))
    return wall


def _estimate(root: Path) -> dict[str, Any] | None:
    path = root / ESTIMATE_FILE
    if not path.is_file():
        return None
    est = read_json_file(path, "the cost estimate")
    return est.get("total") if isinstance(est, dict) else None


def tournament_status(root: str | Path, now_s: float | None = None) -> TournamentStatus:
    """The status of the tournament folder ``root`` (``RESULTS/NAME``).

    A missing or unreadable index, or an unreadable estimate.json: UserInputError naming the
    file. ``now_s`` (epoch seconds) times the running jobs; default the clock.
    """
    root = Path(root)
    db = index_path(root)
    if not db.is_file():
        raise UserInputError(f"{db}: no such file (not a tournament results folder, or its run "
                             "has not started)")
    try:
        index = read_index(root)
        estimate = _estimate(root)
    except CorruptResultError as err:
        raise UserInputError(str(err)) from None
    now = time.time() if now_s is None else now_s
    jobs = index["jobs"]
    pid = _lock_pid(root)
    alive = pid_alive(pid)
    state = jobs["status"].astype(str)
    if not alive:
        state = state.where(state != "running", "interrupted")
    counts: dict[str, dict[str, int]] = {}
    for kind, grp in state.groupby(jobs["kind"].astype(str), sort=False):
        counts[str(kind)] = {s: int((grp == s).sum()) for s in STATES}
    total = {s: int((state == s).sum()) for s in STATES}
    parts = index["parts"]
    planned = set(jobs["part"].astype(str))
    not_planned = [str(p) for p in parts.sort_values("position")["part"] if str(p) not in planned]

    seconds = _job_seconds(jobs)
    elapsed = pd.Series([max(0.0, now - _epoch_s(s)) for s in jobs["started_at"]],
                        index=jobs.index, dtype=float)
    finished = state.isin(["done", "failed"])
    spent = float(seconds[finished].sum()) + float(elapsed[state == "running"].sum())

    if estimate and estimate.get("workers"):
        workers, w_basis = int(estimate["workers"]), f"{ESTIMATE_FILE}"
    elif alive and total["running"]:
        workers, w_basis = total["running"], "jobs running now"
    else:
        workers, w_basis = 1, "assumed 1 (no estimate.json and no job running)"
    eta, eta_basis = _eta(jobs, state, seconds, elapsed, workers)
    if not_planned:
        eta_basis += f"; the jobs of {len(not_planned)} part(s) not planned yet are not counted"
    return TournamentStatus(
        tournament=str(root), run_pid=pid, run_alive=alive, counts=counts, total=total,
        parts_not_planned=not_planned, cpu_s_spent=spent,
        cpu_s_estimate=(float(estimate["cpu_s"]) if estimate and "cpu_s" in estimate
                        else None),
        workers=workers, workers_basis=w_basis, eta_s=eta, eta_basis=eta_basis,
    )


def _eta(jobs: pd.DataFrame, state: pd.Series, seconds: pd.Series, elapsed: pd.Series,
         workers: int) -> tuple[float | None, str]:
    """Remaining job seconds over the workers: each pending or interrupted job costs the mean
    finished job of its kind (of any kind where its own has none finished), each running one
    that mean less what it has run."""
    done = state == "done"
    if not done.any():
        return None, "no job has finished yet to time the rest by"
    overall = float(seconds[done].mean())
    kinds = jobs["kind"].astype(str)
    means = seconds[done].groupby(kinds[done]).mean().to_dict()
    work = 0.0
    left = 0
    for k in jobs.index[state.isin(["pending", "interrupted", "running"])]:
        mean = float(means.get(kinds[k], overall))
        ran = float(elapsed[k]) if state[k] == "running" and math.isfinite(elapsed[k]) else 0.0
        work += max(mean - ran, 0.0)
        left += 1
    basis = (f"{left} job(s) left x the mean of {int(done.sum())} finished job(s) of their kind "
             f"({overall:.0f} s over all kinds), less what running jobs have run, "
             f"/ {workers} worker(s)")
    return work / workers, basis


__all__ = ["STATES", "TournamentStatus", "pid_alive", "tournament_status"]
