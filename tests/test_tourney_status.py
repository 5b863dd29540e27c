"""``formula-tourney status`` on a live tournament: started in the background, read while its run
writes, killed with SIGKILL, read again (its running job is then "interrupted"); and its errors."""

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

from formula_tourney.cli import main
from formula_tourney.results import layout as L
from formula_tourney.tourney.runner import FAULTS_ENV

REPO = Path(__file__).resolve().parents[1]


def status(folder: Path) -> tuple[int, dict]:
    proc = subprocess.run([sys.executable, "-m", "formula_tourney.cli", "status", str(folder),
                           "--json"], cwd=REPO, capture_output=True, text=True, timeout=120)
    return proc.returncode, (json.loads(proc.stdout) if proc.returncode == 0 else
                             {"stderr": proc.stderr})


def test_status_of_a_running_then_killed_tournament(tmp_path: Path) -> None:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY.format(entrants='["WIN1", "MS2"]', p2=""), encoding="utf-8")
    folder = tmp_path / "res" / "tiny"
    # MS2's job sleeps a minute before it trains: it is surely running when status reads
    env = {**os.environ, FAULTS_ENV: json.dumps({"p1/MS2-*": "sleep:60"})}
    run = subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(path), "--workers", "1",
         "--results", str(tmp_path / "res")],
        cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: the kill below takes its workers too
    )
    try:
        deadline = time.monotonic() + 180
        while True:
            assert run.poll() is None, "the run ended before its job ran"
            assert time.monotonic() < deadline, "MS2's job never started"
            code, live = status(folder) if (folder / "index.sqlite").exists() else (2, {})
            if code == 0 and live["counts"].get("train", {}).get("running"):
                break
            time.sleep(0.3)
        train = live["counts"]["train"]
        assert live["run_alive"] and live["run_pid"] == run.pid
        # one worker: MS2 runs; WIN1 is done or still pending, nothing failed
        assert train["running"] == 1 and train["interrupted"] == 0 and train["failed"] == 0
        assert train["done"] + train["pending"] == 1
        assert live["workers"] == 1 and live["workers_basis"] == "jobs running now"
        assert live["cpu_s_estimate"] is None
    finally:
        os.killpg(run.pid, signal.SIGKILL)
        run.wait(timeout=60)
    code, after = status(folder)
    assert code == 0
    train = after["counts"]["train"]
    assert not after["run_alive"]
    assert train["running"] == 0 and train["interrupted"] == 1
    assert train["done"] + train["pending"] == 1 and train["failed"] == 0
    with sqlite3.connect(folder / "index.sqlite") as db:  # status wrote nothing
        assert db.execute("SELECT count(*) FROM jobs WHERE status='running'").fetchone()[0] == 1


def test_status_counts_time_and_eta_from_a_finished_job(tmp_path: Path) -> None:
    folder = tmp_path / "cup"
    folder.mkdir()
    with sqlite3.connect(folder / L.INDEX_FILE) as db:
        db.executescript(L.INDEX_SCHEMA)
        db.executemany(
            "INSERT INTO jobs (job_id, kind, part, status, attempts, path, wall_s, result) "
            "VALUES (?, 'train', 'p1', ?, 1, ?, ?, ?)",
            [("p1/a/seed-0", "done", "p1/a/seed-0", 100.0, '{"train_seconds": 90.0}'),
             ("p1/a/seed-1", "done", "p1/a/seed-1", None, '{"train_seconds": 200.0}'),
             ("p1/b/seed-0", "failed", "p1/b/seed-0", 30.0, None),
             ("p1/b/seed-1", "pending", "p1/b/seed-1", None, None),
             ("p1/b/seed-2", "pending", "p1/b/seed-2", None, None)])
        db.execute("INSERT INTO parts (part, study, position, status, entrants, promoted) "
                   "VALUES ('p1', 's', 0, 'running', '[]', '[]'), "
                   "('p2', 's', 1, 'pending', '[]', '[]')")
    (folder / L.ESTIMATE_FILE).write_text(json.dumps({"total": {"cpu_s": 3600.0,
                                                                "workers": 2}}))
    code, st = status(folder)
    assert code == 0
    assert st["total"] == {"done": 2, "running": 0, "interrupted": 0, "pending": 2, "failed": 1}
    assert st["cpu_s_spent"] == pytest.approx(100.0 + 200.0 + 30.0)  # wall_s, else train_s
    assert st["cpu_s_estimate"] == 3600.0 and st["workers"] == 2
    assert st["eta_s"] == pytest.approx(2 * 150.0 / 2)  # 2 jobs x mean 150 s / 2 workers
    assert st["parts_not_planned"] == ["p2"]


def test_status_errors_name_the_file(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["status", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(tmp_path / "index.sqlite") in err
    (tmp_path / "index.sqlite").write_text("not a database")
    with pytest.raises(SystemExit) as exc:
        main(["status", str(tmp_path)])
    assert exc.value.code == 2
    assert str(tmp_path / "index.sqlite") in capsys.readouterr().err
