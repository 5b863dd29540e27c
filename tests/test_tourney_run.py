"""Running tournaments for real (tiny jobs): promotion, resume after kill -9, failure isolation,
the lock and Ray. Jobs use the real trainer with a handful of 30-step episodes; only the failure
tests inject a fault at the start of chosen jobs (runner.FAULTS_ENV)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tourney_fixtures import TINY

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.lock import RunLock
from formula_tourney.tourney.runner import FAULTS_ENV
from formula_tourney.tourney.store import Store

# Two 30-step episodes (6 s of driving) cannot lap a 2.3 km oval: nobody is promoted from p1.
PROMOTED_P2 = """
[[parts]]
name = "p2"
promoted_from = "p1"
promotion = { best_per_family = false, top_k = 1 }
train_tracks = ["oval"]

[[parts]]
name = "p3"
promoted_from = "p2"
train_tracks = ["oval"]
"""

DECLARED_P2 = """
[[parts]]
name = "p2"
entrants = ["WIN1"]
train_tracks = ["oval"]
baselines = [{ bot = "follower", reference = "centre", laps = 1 }]
"""

REPO = Path(__file__).resolve().parents[1]


def tiny(tmp_path: Path, entrants: str = '["WIN1", "MS2"]', p2: str = DECLARED_P2) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY.format(entrants=entrants, p2=p2), encoding="utf-8")
    return path


def rows(results: Path) -> dict[str, dict]:
    db = sqlite3.connect(results / "tiny" / "index.sqlite")
    db.row_factory = sqlite3.Row
    out = {r["job_id"]: dict(r) for r in db.execute("SELECT * FROM jobs")}
    db.close()
    return out


def test_lock_refuses_a_second_run(tmp_path: Path) -> None:
    path = tiny(tmp_path)
    with RunLock(tmp_path / "res" / "tiny"), pytest.raises(UserInputError,
                                                           match="another run is using"):
        run_tournament(path, workers=1, results_dir=tmp_path / "res")
    assert not (tmp_path / "res" / "tiny" / "index.sqlite").exists()
    # released: a later lock succeeds
    with RunLock(tmp_path / "res" / "tiny"):
        pass


def test_failure_isolation_and_retries(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An exception, a NaN divergence and a crashed worker each fail only their own job."""
    monkeypatch.setenv(FAULTS_ENV, json.dumps(
        {"p1/MS2-*": "raise", "p1/PER40k-*": "diverge", "p1/WIN4-*": "exit"}))
    path = tiny(tmp_path, '["WIN1", "MS2", "PER40k", "WIN4"]', PROMOTED_P2)
    result = run_tournament(path, workers=2, retries=1, results_dir=tmp_path / "res")
    jobs = rows(tmp_path / "res")
    assert jobs["p1/WIN1-MOT/seed-0"]["status"] == "done"
    assert jobs["p1/MS2-MOT/seed-0"]["reason"].startswith("InjectedFault: injected fault")
    assert jobs["p1/PER40k-MOT/seed-0"]["reason"].startswith("diverged (NaN loss)")
    assert jobs["p1/WIN4-MOT/seed-0"]["reason"] == "worker process exited with code 3"
    for job_id in ("p1/MS2-MOT/seed-0", "p1/PER40k-MOT/seed-0", "p1/WIN4-MOT/seed-0"):
        assert jobs[job_id]["status"] == "failed" and jobs[job_id]["attempts"] == 2
    assert (tmp_path / "res/tiny/p1/MS2-MOT/seed-0/error.txt").read_text().count("Injected")
    assert result["this_run"]["retried"] == 3 and result["this_run"]["failed"] == 3
    # the survivor never lapped: nobody is promoted, and the parts waiting on p1 fail with why
    parts = {p["part"]: p for p in result["parts"]}
    assert parts["p1"]["status"] == "done" and parts["p1"]["reason"] == "3 of 4 jobs failed"
    assert parts["p1"]["promoted"] == {"p2": []}
    assert parts["p2"]["status"] == "failed"
    assert parts["p2"]["reason"] == "no entrant of p1 met the promotion rule"
    assert parts["p3"]["reason"] == "source part p2 failed"
    decisions = {r["entrant"]: r["decision"] for r in parts["p1"]["ranking"]}
    assert decisions["WIN1-MOT"] == "no clean lap"


def _start_cli(tmp_path: Path, extra: list[str], env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(tiny(tmp_path)), "--workers",
         "2", "--results", str(tmp_path / "res"), "--json", *extra],
        cwd=REPO, env={**os.environ, **env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
    )


def _wait_running(results: Path, job_id: str, proc: subprocess.Popen) -> int:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        index = results / "tiny" / "index.sqlite"
        if index.exists():
            try:
                row = rows(results).get(job_id)
            except sqlite3.OperationalError:
                row = None
            if row and row["status"] == "running" and row["worker_pid"]:
                return int(row["worker_pid"])
        time.sleep(0.2)
    raise AssertionError(f"{job_id} never ran")


def test_kill_9_of_a_worker_loses_nothing_and_retries(tmp_path: Path) -> None:
    # MS2 sleeps 4 s at its start, so the kill lands while it runs; the retry finishes it.
    proc = _start_cli(tmp_path, ["--retries", "1"],
                      {FAULTS_ENV: json.dumps({"p1/MS2-*": "sleep:4"})})
    pid = _wait_running(tmp_path / "res", "p1/MS2-MOT/seed-0", proc)
    os.kill(pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    jobs = rows(tmp_path / "res")
    assert jobs["p1/MS2-MOT/seed-0"]["status"] == "done"
    assert jobs["p1/MS2-MOT/seed-0"]["attempts"] == 2
    assert all(j["status"] == "done" for j in jobs.values()), jobs
    assert json.loads(out)["this_run"]["retried"] == 1


def test_kill_9_of_the_parent_then_resume(tmp_path: Path) -> None:
    proc = _start_cli(tmp_path, [], {FAULTS_ENV: json.dumps({"p*/MS2-*": "sleep:30",
                                                             "p2/*": "sleep:30"})})
    worker = _wait_running(tmp_path / "res", "p1/MS2-MOT/seed-0", proc)
    deadline = time.monotonic() + 120  # wait until WIN1 has finished in the other worker
    while rows(tmp_path / "res")["p1/WIN1-MOT/seed-0"]["status"] != "done":
        assert time.monotonic() < deadline
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    for _ in range(50):  # the orphaned worker follows its parent (PR_SET_PDEATHSIG)
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        raise AssertionError("worker outlived its parent")
    assert rows(tmp_path / "res")["p1/MS2-MOT/seed-0"]["status"] == "running"
    result = run_tournament(tiny(tmp_path), workers=2, results_dir=tmp_path / "res")
    assert result["this_run"]["skipped"] == 1  # p1's WIN1 was not trained again
    jobs = rows(tmp_path / "res")
    assert jobs["p1/WIN1-MOT/seed-0"]["attempts"] == 1
    assert jobs["p1/MS2-MOT/seed-0"]["attempts"] == 2
    assert all(j["status"] == "done" for j in jobs.values())
    store = Store(tmp_path / "res" / "tiny")
    tests = store.read_job_table("p1/WIN1-MOT/seed-0", "tests")
    assert list(tests["track"].unique()) == ["oval"]
    # a third run has nothing left to do
    again = run_tournament(tiny(tmp_path), workers=2, results_dir=tmp_path / "res")
    assert again["this_run"]["done"] == 0 and again["this_run"]["skipped"] == 4  # + the drive
    base = store.jobs("baseline")
    assert list(base["status"]) == ["done"] and base["reference_limit_s"].iloc[0] > 10.0


@pytest.mark.ray
def test_ray_local_run(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    path = tmp_path / "tiny.toml"
    path.write_text(TINY.format(entrants='["WIN1"]', p2=""), encoding="utf-8")
    result = run_tournament(path, workers=1, executor="ray", results_dir=tmp_path / "res")
    jobs = rows(tmp_path / "res")
    assert [j["status"] for j in jobs.values()] == ["done"]
    assert result["executor"] == "ray"
    assert (tmp_path / "res/tiny/p1/WIN1-MOT/seed-0/summary.json").is_file()
