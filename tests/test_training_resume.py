"""A training job resumed from its resume file continues bit for bit (``training.resume``).

Every test compares the job tables of an interrupted and resumed run with those of the same
run left alone, without the columns that measure the machine (``benchmarks/determinism.py``,
``MACHINE_TIME_KEYS``). The interruption is a real SIGKILL of a training process, an exception
that abandons a run in this process (only the files survive, as after a kill), or SIGTERM.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest
import torch
from training_fixtures import SMALL

from formula_tourney.agents.family_entrant import FamilyEntrant
from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import JOB_TABLES
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.store import Store
from formula_tourney.training import loop
from formula_tourney.training.resume import (
    PREEMPTED,
    Preempted,
    preemption_requested,
    sigterm_checkpoints,
)
from formula_tourney.training.run_spec import RunSpec, build_run_spec

MACHINE_TIME = {"seconds", "wall_s", "started_at", "finished_at", "worker_pid",
                "train_seconds", "cpu_s"}  # fmt: skip
TESTS_DIR = Path(__file__).parent


def _spec(variant: str = "WIN1", demos: dict | None = None, **agent: object) -> RunSpec:
    """A run of ~300 steps on the ring that writes its resume file every few steps."""
    return build_run_spec(
        variant=variant, overrides={**SMALL, "exploration_steps": 5000, **agent},
        train_tracks=["ring"], device="cpu",
        seed=4, demos=demos,
        schedule={"episodes": 6, "max_steps": 60, "test_every_episodes": 2, "test_starts": 2,
                  "test_max_steps": 60, "save_test_checkpoints": True,
                  "resume_every_cpu_s": 0.05},
    )  # fmt: skip


def _tables(job: Path) -> dict[str, pd.DataFrame]:
    folder = JobFolder(job)
    return {name: folder.table(name).drop(columns=MACHINE_TIME, errors="ignore")
            for name in JOB_TABLES}  # fmt: skip


def _assert_same_run(a: Path, b: Path, episodes: int = 6) -> None:
    ta, tb = _tables(a), _tables(b)
    for name in JOB_TABLES:
        pd.testing.assert_frame_equal(ta[name], tb[name], check_exact=True)
    assert len(ta["episodes"]) == episodes and ta["episodes"]["updates"].iloc[-1] > 50
    assert not JobFolder(b).resume_path.exists()  # a finished job deletes it


@pytest.fixture
def resume_log(caplog: pytest.LogCaptureFixture) -> pytest.LogCaptureFixture:
    """What ``training.resume`` logs (its INFO line says that a run resumed, and from where)."""
    caplog.set_level(logging.INFO, logger="formula_tourney.training.resume")
    return caplog


class _Abandoned(Exception):
    """Stands for a kill: the run is dropped mid-way, only its files remain."""


def _interrupt_after(episode: int, job: Path):  # noqa: ANN202 - a progress callback
    """A progress callback that abandons the run after ``episode`` once a resume file exists."""

    def progress(info: dict) -> None:
        if info["episode"] >= episode and JobFolder(job).resume_path.exists():
            raise _Abandoned

    return progress


@pytest.mark.parametrize(
    ("variant", "demos", "agent"),
    [("WIN1", None, {}), ("PER40k", None, {}), ("SAC", None, {}), ("TD3", None, {}),
     ("CrossQ", None, {}),
     ("WIN1", {"laps": 1, "line": "centre", "bc_steps": 5, "bc_weight": 0.5}, {})],
    ids=["WIN1", "PER", "SAC", "TD3", "CrossQ", "demos"],
)  # fmt: skip
def test_an_abandoned_run_resumes_to_the_uninterrupted_tables(
    tmp_path: Path,
    ring_tracks: None,
    resume_log: pytest.LogCaptureFixture,
    variant: str,
    demos: dict | None,
    agent: dict,
) -> None:
    spec = _spec(variant, demos, **agent)
    loop.train(spec, tmp_path / "whole")
    job = tmp_path / "resumed"
    with pytest.raises(_Abandoned):
        loop.train(spec, job, _interrupt_after(3, job))
    assert JobFolder(job).resume_path.exists() and not JobFolder(job).is_finished()
    summary = loop.train(spec, job)
    assert summary["episodes"] == 6
    assert f"resuming from {JobFolder(job).resume_path}: " in resume_log.text
    _assert_same_run(tmp_path / "whole", job)


RUNNER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {tests!r})
    from training_fixtures import ring_track
    from formula_tourney.training import envs, loop, run_spec
    envs.load_track = ring_track
    run_spec.check_track_name = lambda name, base_dir=None: name
    spec = run_spec.RunSpec.model_validate_json({spec!r})
    loop.train(spec, {job!r}, lambda info: time.sleep(0.4))
""")


def test_a_sigkilled_run_resumes_to_the_uninterrupted_tables(
    tmp_path: Path, ring_tracks: None, resume_log: pytest.LogCaptureFixture
) -> None:
    spec = _spec()
    job = tmp_path / "killed"
    code = RUNNER.format(tests=str(TESTS_DIR), spec=spec.model_dump_json(), job=str(job))
    child = subprocess.Popen([sys.executable, "-c", code], env={**os.environ})
    try:
        deadline = time.monotonic() + 60
        while not JobFolder(job).resume_path.exists():
            assert child.poll() is None, "the training process ended before its resume file"
            assert time.monotonic() < deadline
            time.sleep(0.05)
        child.send_signal(signal.SIGKILL)
        assert child.wait(10) == -signal.SIGKILL
    finally:
        if child.poll() is None:
            child.kill()
    assert not JobFolder(job).is_finished()
    loop.train(spec, job)
    assert f"resuming from {JobFolder(job).resume_path}: " in resume_log.text
    loop.train(spec, tmp_path / "whole")
    _assert_same_run(tmp_path / "whole", job)


def test_sigterm_mid_episode_writes_the_resume_file_and_the_resumed_run_is_the_same(
    tmp_path: Path,
    ring_tracks: None,
    monkeypatch: pytest.MonkeyPatch,
    resume_log: pytest.LogCaptureFixture,
) -> None:
    spec = build_run_spec(
        variant="WIN1", overrides=SMALL, train_tracks=["ring"], device="cpu", seed=4,
        schedule={"episodes": 6, "max_steps": 60, "test_every_episodes": 2, "test_starts": 2,
                  "test_max_steps": 60},  # the default schedule: no file before SIGTERM
    )  # fmt: skip
    job = tmp_path / "stopped"
    observe, steps, sent = FamilyEntrant.observe, [0], []

    def terminate_mid_episode(self: FamilyEntrant, transitions: list) -> None:
        observe(self, transitions)
        steps[0] += 1
        if steps[0] >= 130 and not sent and not (transitions[0].terminated
                                                 or transitions[0].truncated):  # fmt: skip
            sent.append(steps[0])
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(FamilyEntrant, "observe", terminate_mid_episode)
    handler = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Preempted, match=r"preempted \(resumable\)"):
        loop.train(spec, job)
    assert PREEMPTED == "preempted (resumable)"
    assert JobFolder(job).resume_path.exists() and not JobFolder(job).is_finished()
    assert signal.getsignal(signal.SIGTERM) is handler  # the loop's handler is gone
    saved = torch.load(JobFolder(job).resume_path, weights_only=True)["loop"]
    assert saved["env_steps"] == sent[0] and len(saved["actions"]) > 0  # mid-episode
    loop.train(spec, job)
    assert f"resuming from {JobFolder(job).resume_path}: " in resume_log.text
    loop.train(spec, tmp_path / "whole")
    _assert_same_run(tmp_path / "whole", job)


def test_sigterm_stops_a_run_of_several_cars_without_a_resume_file(
    tmp_path: Path, ring_tracks: None
) -> None:
    """Several cars are mid-episode at different steps: such a run starts again when run
    again, and says so."""
    spec = build_run_spec(
        variant="WIN1", overrides=SMALL, train_tracks=["ring"], device="cpu", seed=4,
        schedule={"episodes": 6, "max_steps": 60, "test_every_episodes": 2, "test_starts": 1,
                  "test_max_steps": 30, "cars": 2, "resume_every_cpu_s": 1e-6},
    )  # fmt: skip

    def terminate(info: dict) -> None:
        os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(Preempted, match="a run of 2 cars starts again when run again"):
        loop.train(spec, tmp_path / "job", terminate)
    assert not JobFolder(tmp_path / "job").resume_path.exists()


def test_a_sigterm_that_no_step_saw_is_passed_on_after_the_run() -> None:
    """A run that ends before a step boundary sees SIGTERM leaves the signal to the process's
    own handler (a pool worker then ends), once the loop's handler is gone."""
    received: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, _frame: received.append(signum))
    try:
        with sigterm_checkpoints():
            os.kill(os.getpid(), signal.SIGTERM)
            assert preemption_requested() and received == []
        assert received == [signal.SIGTERM] and not preemption_requested()
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_resume_file_of_another_config_or_corrupt_is_ignored_with_its_name(
    tmp_path: Path, ring_tracks: None, caplog: pytest.LogCaptureFixture
) -> None:
    spec = _spec()
    job = tmp_path / "job"
    with pytest.raises(_Abandoned):
        loop.train(spec, job, _interrupt_after(2, job))
    resume_file = JobFolder(job).resume_path
    other = _spec(actor_lr=3e-4)
    caplog.set_level(logging.WARNING, logger="formula_tourney.training.resume")
    loop.train(other, tmp_path / "other-whole")
    stale = resume_file.read_bytes()
    loop.train(other, job)  # another configuration: starts afresh
    assert f"resume file {resume_file} was written by another configuration" in caplog.text
    _assert_same_run(tmp_path / "other-whole", job)

    resume_file.write_bytes(stale[: len(stale) // 2])  # truncated by a full disk, say
    caplog.clear()
    loop.train(spec, job)
    assert f"resume file {resume_file} cannot be read" in caplog.text
    loop.train(spec, tmp_path / "whole")
    _assert_same_run(tmp_path / "whole", job)


def test_a_readable_resume_file_that_does_not_fit_is_refused(
    tmp_path: Path, ring_tracks: None
) -> None:
    spec = _spec()
    job = tmp_path / "job"
    with pytest.raises(_Abandoned):
        loop.train(spec, job, _interrupt_after(2, job))
    state = torch.load(JobFolder(job).resume_path, weights_only=True)
    state["entrant"]["noises"] = []  # a damaged state behind a matching hash
    with pytest.raises(UserInputError, match="resume file .*resume.pt does not fit this run"):
        loop.train(spec, job, resume=state)


def _worker_pid(index: Path, job_id: str) -> int:
    """The pid of the worker running ``job_id`` (the index has it once the job started)."""
    for _ in range(500):
        with contextlib.suppress(sqlite3.OperationalError):  # the parent may be writing
            db = sqlite3.connect(index)
            pid = db.execute("SELECT worker_pid FROM jobs WHERE job_id=?", (job_id,)).fetchone()
            db.close()
            if pid and pid[0]:
                return int(pid[0])
        time.sleep(0.02)
    raise AssertionError(f"{job_id} has no worker in {index}")


LONG_JOB = """\
name = "tiny"

[defaults]
seeds = 1
episodes = 12
max_steps = 40
test_every_episodes = 10
test_starts = 1
test_max_steps = 30
device = "cpu"

[variants.WIN1]
overrides = { hidden = [32, 32], batch_size = 16, learning_starts = 16 }

[[parts]]
name = "p1"
entrants = ["WIN1"]
train_tracks = ["oval"]
"""


def test_sigterm_to_a_pool_worker_preempts_its_job_and_a_rerun_resumes_it(
    tmp_path: Path,
) -> None:
    """The worker saves at the next step, the job fails as preempted (resumable), and running
    the tournament again continues the job to the tables of an undisturbed tournament."""
    path = tmp_path / "tiny.toml"
    path.write_text(LONG_JOB, encoding="utf-8")
    job_id = "p1/WIN1-MOT/seed-0"
    results = tmp_path / "res"
    run = subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(path), "--workers", "1",
         "--results", str(results), "--json"],
        env=os.environ.copy(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        job = results / "tiny" / job_id
        deadline = time.monotonic() + 120
        while not JobFolder(job).config_path.exists():  # written once training has begun
            assert run.poll() is None, run.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.02)
        assert not JobFolder(job).resume_path.exists()  # not before 300 CPU-s: only SIGTERM
        os.kill(_worker_pid(results / "tiny" / "index.sqlite", job_id), signal.SIGTERM)
        run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
    store = Store(results / "tiny")
    (row,) = store.jobs("train").to_dict("records")
    assert row["status"] == "failed" and PREEMPTED in row["reason"], row
    assert JobFolder(job).resume_path.exists()
    again = run_tournament(path, workers=1, results_dir=results, retry_failed=True)
    assert again["this_run"]["done"] == 1
    # resumed, not started afresh: the first attempt's TensorBoard events are still there
    assert len(list(JobFolder(job).tb_dir.glob("events.*"))) == 2
    whole = run_tournament(path, workers=1, results_dir=tmp_path / "whole")
    assert whole["this_run"]["done"] == 1
    _assert_same_run(tmp_path / "whole" / "tiny" / job_id, job, episodes=12)
