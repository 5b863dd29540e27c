"""``formula-tourney run`` through its command line: exit codes (0 done, 2 bad input or unreadable
results, 3 jobs failed, 130 interrupted), ``--retry-failed`` after a killed worker, and corrupt
results (``--rebuild-index``). Jobs are the real trainer with two 30-step episodes; failures are
injected with runner.FAULTS_ENV."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tourney_fixtures import TINY

from formula_tourney.cli import main
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.runner import FAULTS_ENV

REPO = Path(__file__).resolve().parents[1]

# Nobody laps the oval in 6 s of driving: promotion classifies entrants by distance.
PROMOTED = """
[[parts]]
name = "p2"
promoted_from = "p1"
promotion = { best_per_family = false, top_k = 1, unfinished = "by_distance" }
train_tracks = ["oval"]
"""


def tiny(folder: Path, entrants: str = '["WIN1", "MS2"]', more: str = PROMOTED) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "tiny.toml"
    path.write_text(TINY.format(entrants=entrants, p2=more), encoding="utf-8")
    return path


def cli(path: Path, results: Path, *extra: str, faults: dict | None = None,
        timeout: float = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != FAULTS_ENV}
    if faults:
        env[FAULTS_ENV] = json.dumps(faults)
    return subprocess.run(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(path), "--workers", "2",
         "--results", str(results), "--json", *extra],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout,
    )


def rows(results: Path) -> dict[str, dict]:
    db = sqlite3.connect(results / "tiny" / "index.sqlite")
    db.row_factory = sqlite3.Row
    out = {r["job_id"]: dict(r) for r in db.execute("SELECT * FROM jobs")}
    db.close()
    return out


def test_killed_worker_exit_3_then_retry_failed_reruns_it(tmp_path: Path) -> None:
    """Bug 5 and bug 6: a run whose jobs failed exited 0, and a job whose worker died in a part
    that then closed was never retried although the CLI said "run again to retry them"."""
    path, results = tiny(tmp_path), tmp_path / "res"
    first = cli(path, results, faults={"p1/MS2-*": "exit"})
    assert first.returncode == 3, first.stderr
    assert "1 job(s) failed; run again with --retry-failed to re-run them" in first.stderr
    out = json.loads(first.stdout)
    assert [(f["job_id"], f["reason"]) for f in out["failures"]] == [
        ("p1/MS2-MOT/seed-0", "worker process exited with code 3")]
    parts = {p["part"]: p for p in out["parts"]}
    assert parts["p1"]["status"] == "done" and parts["p2"]["status"] == "done"
    assert parts["p1"]["promoted"] == {"p2": ["WIN1"]}  # the failed seed has no distance

    again = cli(path, results)  # a plain resume leaves a closed part alone
    assert again.returncode == 3, again.stderr
    assert rows(results)["p1/MS2-MOT/seed-0"]["attempts"] == 1

    retried = cli(path, results, "--retry-failed")
    assert retried.returncode == 0, retried.stderr
    out = json.loads(retried.stdout)
    assert out["failures"] == [] and out["this_run"]["reopened"] == 2
    jobs = rows(results)
    assert jobs["p1/MS2-MOT/seed-0"]["status"] == "done"
    assert jobs["p1/MS2-MOT/seed-0"]["attempts"] == 2
    assert all(j["status"] == "done" for j in jobs.values()), jobs
    parts = {p["part"]: p for p in out["parts"]}
    promoted = parts["p1"]["promoted"]["p2"]
    assert len(promoted) == 1
    assert {r["entrant"]: r["done"] for r in parts["p1"]["ranking"]} == {
        "WIN1-MOT": 1, "MS2-MOT": 1}
    # p2 holds exactly the jobs of the entrant promoted this time
    assert sorted(j for j in jobs if j.startswith("p2/")) == [f"p2/{promoted[0]}-MOT/seed-0"]
    assert parts["p2"]["entrants"] == [f"{promoted[0]}-MOT"]


def test_ctrl_c_exits_130_and_the_job_resumes(tmp_path: Path) -> None:
    """Bug 5: Ctrl-C printed "interrupted" and exited 0 (cli.main dropped the exit code)."""
    path, results = tiny(tmp_path, '["WIN1"]', ""), tmp_path / "res"
    env = {**os.environ, FAULTS_ENV: json.dumps({"p1/*": "sleep:60"})}
    proc = subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(path), "--workers", "1",
         "--results", str(results)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        # a suite started in the background (`cmd &` in a script) ignores SIGINT, and children
        # inherit that: give the run the default Ctrl-C a terminal would
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 120
    while True:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the job never started"
        try:
            job = rows(results).get("p1/WIN1-MOT/seed-0") if (
                results / "tiny" / "index.sqlite").exists() else None
        except sqlite3.OperationalError:
            job = None
        if job and job["status"] == "running" and job["worker_pid"]:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted: finished jobs are kept" in err
    assert rows(results)["p1/WIN1-MOT/seed-0"]["status"] == "pending"


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished one-job tournament (tiny.toml and res/ in one folder), copied by each test."""
    folder = tmp_path_factory.mktemp("finished")
    result = run_tournament(tiny(folder, '["WIN1"]', ""), workers=1, results_dir=folder / "res")
    assert result["failures"] == []
    return folder


def copy_of(finished: Path, tmp_path: Path) -> tuple[Path, Path]:
    shutil.copytree(finished, tmp_path / "t")
    return tmp_path / "t" / "tiny.toml", tmp_path / "t" / "res"


def test_garbage_index_is_an_error_then_rebuilt(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Bug 8: a garbage index.sqlite gave a sqlite3.DatabaseError traceback."""
    path, results = copy_of(finished, tmp_path)
    index = results / "tiny" / "index.sqlite"
    for side in ("index.sqlite-wal", "index.sqlite-shm"):
        (results / "tiny" / side).unlink(missing_ok=True)
    index.write_bytes(b"not a database " * 200)
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--results", str(results)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"error: {index}: cannot read the results index" in err, err
    assert "--rebuild-index" in err and "Traceback" not in err

    main(["run", str(path), "--results", str(results), "--rebuild-index", "--json"])  # exit 0
    out = json.loads(capsys.readouterr().out)
    assert out["index_moved_to"] == f"{index}.corrupt"
    assert (results / "tiny" / "index.sqlite.corrupt").read_bytes().startswith(b"not a database")
    assert out["this_run"]["done"] == 0 and out["this_run"]["recovered"] == 1
    assert rows(results)["p1/WIN1-MOT/seed-0"]["status"] == "done"


def test_truncated_table_of_a_running_job_names_the_file(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Bug 8: a truncated tests.parquet of a job marked running gave a pyarrow traceback on
    every re-run."""
    path, results = copy_of(finished, tmp_path)
    db = sqlite3.connect(results / "tiny" / "index.sqlite")
    db.execute("UPDATE jobs SET status='running'")
    db.commit()
    db.close()
    tests = results / "tiny" / "p1" / "WIN1-MOT" / "seed-0" / "tests.parquet"
    tests.write_bytes(tests.read_bytes()[: tests.stat().st_size // 2])
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--results", str(results)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"error: {tests}: cannot read the job's tests table" in err, err
    assert f"remove the job folder {tests.parent}" in err and "Traceback" not in err


def test_rebuilt_index_never_adopts_a_folder_of_other_settings(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Rebuilding from the folders after the file changed: the finished folder holds another
    run specification than the job now has, and is refused instead of counted as done."""
    path, results = copy_of(finished, tmp_path)
    path.write_text(path.read_text().replace("episodes = 2", "episodes = 3"), encoding="utf-8")
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--results", str(results), "--rebuild-index"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    config = results / "tiny" / "p1" / "WIN1-MOT" / "seed-0" / "config.json"
    assert f"error: {config}: this finished job was trained with other settings" in err, err
    assert (results / "tiny" / "index.sqlite.old").is_file()
