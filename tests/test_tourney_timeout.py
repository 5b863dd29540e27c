"""A job past ``--job-timeout-s`` is stopped and failed, "timed out after N s", and not retried;
the other jobs go on. On the local pool: its worker process is stopped and replaced."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from cluster_fixtures import index_rows, tiny_file

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.job_events import Event
from formula_tourney.tourney.runner import FAULTS_ENV

LIMIT_S = 10.0
"""Above what a tiny training job takes on a loaded 2-core machine (about 4 s), far below the
sleeping job's minute."""


def test_a_job_past_its_time_limit_is_stopped_and_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(FAULTS_ENV, json.dumps({"p1/MS2-*": "sleep:60"}))
    events: list[Event] = []
    result = run_tournament(
        tiny_file(tmp_path),
        workers=2,
        retries=1,
        job_timeout_s=LIMIT_S,
        results_dir=tmp_path / "res",
        on_event=events.append,
    )
    jobs = index_rows(tmp_path / "res")
    slow, fast = jobs["p1/MS2-MOT/seed-0"], jobs["p1/WIN1-MOT/seed-0"]
    assert (slow["status"], slow["reason"], slow["attempts"]) == (
        "failed",
        "timed out after 10 s",
        1,
    )
    assert LIMIT_S <= slow["wall_s"] < LIMIT_S + 5  # from its start in the worker
    assert fast["status"] == "done" and fast["wall_s"] < LIMIT_S
    assert result["this_run"]["failed"] == 1 and result["this_run"]["retried"] == 0
    started = next(e.pid for e in events if e.kind == "started" and e.job_id == slow["job_id"])
    with pytest.raises(ProcessLookupError):  # its worker was stopped
        os.kill(started, 0)


def test_a_time_limit_must_be_positive(tmp_path: Path) -> None:
    with pytest.raises(UserInputError, match="--job-timeout-s must be > 0, got 0"):
        run_tournament(
            tiny_file(tmp_path), workers=1, job_timeout_s=0, results_dir=tmp_path / "res"
        )
    assert not (tmp_path / "res").exists()
