"""Job kinds: the registry, the one ``jobs`` table that holds every kind, and an index of the
older layout (a table per kind) read by the report and migrated by a resumed run."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pandas as pd
import pytest
from tourney_fixtures import TINY

from formula_tourney.errors import UserInputError
from formula_tourney.report.load import load_tournament
from formula_tourney.results import layout as L
from formula_tourney.results.index import JOB_COLUMNS, read_index
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.kinds import KINDS, kind_of
from formula_tourney.tourney.runner import run_job
from formula_tourney.tourney.store import Store

# p1 trains two entrants and drives one baseline; `final` races the two and a bot.
TOURNAMENT = TINY.format(entrants='["WIN1", "MS2"]', p2="""
[[parts]]
name = "final"
kind = "race"
promoted_from = "p1"
promotion = { best_per_family = false, unfinished = "by_distance" }
train_tracks = ["oval"]
race = { races = 1, laps = 1, bots = ["follower"], lap_limit_s = 40.0 }
""").replace('train_tracks = ["oval"]\n', 'train_tracks = ["oval"]\nbaselines = [{ bot = '
             '"follower", reference = "centre", laps = 1 }]\n', 1)

JOB_IDS = {"p1/WIN1-MOT/seed-0": "train", "p1/MS2-MOT/seed-0": "train",
           "p1/_baselines/follower-centre-oval": "baseline", "final/_races": "race"}

# The index before the one jobs table, as the earlier store created it.
LEGACY_SCHEMA = """
CREATE TABLE jobs (
    job_id TEXT PRIMARY KEY, study TEXT, part TEXT, entrant TEXT, variant TEXT, family TEXT,
    seed INTEGER, reference TEXT, lac INTEGER, train_tracks TEXT,
    status TEXT NOT NULL DEFAULT 'pending', reason TEXT, attempts INTEGER NOT NULL DEFAULT 0,
    path TEXT, started_at TEXT, finished_at TEXT, wall_s REAL,
    position INTEGER, config_hash TEXT, worker_pid INTEGER,
    best_lap_s REAL, finished INTEGER, damage REAL, train_seconds REAL, test_distance_m REAL
);
CREATE TABLE baselines (
    part TEXT, bot TEXT, track TEXT, reference TEXT, best_lap_s REAL, damage REAL,
    finished INTEGER, reference_limit_s REAL, status TEXT NOT NULL DEFAULT 'pending', reason TEXT,
    path TEXT, PRIMARY KEY (part, bot, track, reference)
);
CREATE TABLE races (
    part TEXT PRIMARY KEY, track TEXT, races INTEGER, entrants TEXT,
    status TEXT NOT NULL DEFAULT 'pending', reason TEXT, attempts INTEGER NOT NULL DEFAULT 0,
    path TEXT, started_at TEXT, finished_at TEXT, wall_s REAL, config_hash TEXT
);
"""


def test_registry_names_every_kind_and_refuses_an_unknown_one(tmp_path: Path) -> None:
    assert list(KINDS) == ["train", "baseline", "race"]
    for name, kind in KINDS.items():
        assert kind_of(name) is kind and kind.name == name
        own = [*kind.attrs, *kind.result_fields]
        assert not set(own) & set(JOB_COLUMNS), name  # its keys never hide a shared column
        assert kind.columns == [*JOB_COLUMNS, *own]
    with pytest.raises(UserInputError, match="unknown job kind 'tune'; known kinds: train, "
                                             "baseline, race"):
        kind_of("tune")
    job = Job(job_id="p/x", kind="tune", part="p", out_dir=str(tmp_path / "x"))
    with pytest.raises(UserInputError, match="unknown job kind 'tune'"):
        run_job(job)
    assert not (tmp_path / "x").exists()


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The tournament run once to the end (kept read-only: tests copy it)."""
    tmp = tmp_path_factory.mktemp("kinds")
    path = tmp / "t.toml"
    path.write_text(TOURNAMENT, encoding="utf-8")
    run_tournament(path, workers=1, results_dir=tmp / "res")
    return path, tmp / "res"


def _copy(finished: tuple[Path, Path], tmp_path: Path) -> tuple[Path, Path]:
    path, res = finished
    shutil.copytree(res, tmp_path / "res")
    return path, tmp_path / "res"


def _table(index: Path, sql: str) -> list[dict]:
    with sqlite3.connect(index) as db:
        db.row_factory = sqlite3.Row
        return [dict(r) for r in db.execute(sql)]


def test_one_jobs_table_holds_every_kind(finished: tuple[Path, Path]) -> None:
    index = finished[1] / "tiny" / L.INDEX_FILE
    tables = {r["name"] for r in _table(index, "SELECT name FROM sqlite_master "
                                               "WHERE type='table'")}
    assert tables == {"meta", "jobs", "parts", "general_models"}
    rows = {r["job_id"]: r for r in _table(index, "SELECT * FROM jobs")}
    assert {j: r["kind"] for j, r in rows.items()} == JOB_IDS
    assert all(r["status"] == "done" and r["attempts"] == 1 for r in rows.values())
    win1 = rows["p1/WIN1-MOT/seed-0"]
    assert json.loads(win1["attrs"])["entrant"] == "WIN1-MOT"
    assert json.loads(win1["result"])["train_seconds"] > 0
    drive = json.loads(rows["p1/_baselines/follower-centre-oval"]["result"])
    assert drive["finished"] is True and drive["reference_limit_s"] > 10.0
    race = json.loads(rows["final/_races"]["attrs"])
    assert race["races"] == 1 and sorted(race["entrants"]) == ["MS2-MOT", "WIN1-MOT",
                                                               "follower"]


def _make_legacy(index: Path) -> None:
    """Rewrite the index in the older layout: a table per kind, as the earlier store wrote."""
    rows = _table(index, "SELECT * FROM jobs")
    with sqlite3.connect(index) as db:
        db.execute("DROP TABLE jobs")
        db.executescript(LEGACY_SCHEMA)
        for r in rows:
            a, res = json.loads(r["attrs"]), json.loads(r["result"] or "{}")
            if r["kind"] == "train":
                db.execute(
                    "INSERT INTO jobs VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                    (r["job_id"], a["study"], r["part"], a["entrant"], a["variant"],
                     a["family"], a["seed"], a["reference"], int(a["lac"]),
                     json.dumps(a["train_tracks"]), r["status"], r["reason"], r["attempts"],
                     r["path"], r["started_at"], r["finished_at"], r["wall_s"], r["position"],
                     r["config_hash"], r["worker_pid"], res["best_lap_s"],
                     int(res["finished"]), res["damage"], res["train_seconds"],
                     res["test_distance_m"]))
            elif r["kind"] == "baseline":
                db.execute("INSERT INTO baselines VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                           (r["part"], a["bot"], a["track"], a["reference"],
                            res["best_lap_s"], res["damage"], int(res["finished"]),
                            res["reference_limit_s"], r["status"], r["reason"], r["path"]))
            else:
                db.execute("INSERT INTO races VALUES (?,?,?,?,?,?,?,?,?,?,?,?)",
                           (r["part"], a["track"], a["races"], json.dumps(a["entrants"]),
                            r["status"], r["reason"], r["attempts"], r["path"],
                            r["started_at"], r["finished_at"], r["wall_s"], r["config_hash"]))


def test_an_index_of_the_older_layout_reads_and_resumes(finished: tuple[Path, Path],
                                                        tmp_path: Path) -> None:
    path, res = _copy(finished, tmp_path)
    root = res / "tiny"
    before = load_tournament(root)
    current = {r["job_id"]: r for r in _table(root / L.INDEX_FILE, "SELECT * FROM jobs")}
    _make_legacy(root / L.INDEX_FILE)
    # read as it is (the report never writes): the same jobs and drives as the current index
    jobs = read_index(root)["jobs"].set_index("job_id")
    assert jobs["kind"].to_dict() == JOB_IDS
    old = load_tournament(root)
    assert old.problems == before.problems
    cols = ["job_id", "entrant", "seed", "status", "best_lap_s", "lac", "train_tracks"]
    pd.testing.assert_frame_equal(old.jobs[cols], before.jobs[cols], check_dtype=False)
    drive = ["bot", "track", "best_lap_s", "reference_limit_s", "finished", "status"]
    pd.testing.assert_frame_equal(old.baselines[drive], before.baselines[drive],
                                  check_dtype=False)
    assert len(old.tests) == len(before.tests) > 0
    # resumed: migrated in place, nothing runs again, every attempt count kept
    result = run_tournament(path, workers=1, results_dir=res)
    assert result["this_run"]["done"] == 0 and result["this_run"]["skipped"] == 4
    assert result["this_run"]["recovered"] == 0 and result["failures"] == []
    index = root / L.INDEX_FILE
    tables = {r["name"] for r in _table(index, "SELECT name FROM sqlite_master "
                                               "WHERE type='table'")}
    assert "baselines" not in tables and "races" not in tables
    rows = {r["job_id"]: r for r in _table(index, "SELECT * FROM jobs")}
    assert {j: r["kind"] for j, r in rows.items()} == JOB_IDS
    assert rows["p1/WIN1-MOT/seed-0"]["attempts"] == 1 and rows["final/_races"]["attempts"] == 1
    for job_id, row in current.items():  # the same attrs and results, as the same JSON
        assert json.loads(rows[job_id]["attrs"]) == json.loads(row["attrs"]), job_id
        assert json.loads(rows[job_id]["result"]) == json.loads(row["result"]), job_id
    assert Store(root).job("p1/MS2-MOT/seed-0")["train_seconds"] > 0


def test_a_done_job_whose_files_are_gone_goes_by_its_kind(finished: tuple[Path, Path],
                                                          tmp_path: Path) -> None:
    """In the closed part p1 a training run (reopen_part) runs again and re-opens p1, so the
    baseline drive (rerun_if_open) runs again too; the race series (reopen_part) races again.
    The run's summary lists each lost job with its reason."""
    path, res = _copy(finished, tmp_path)
    root = res / "tiny"
    (root / "p1/WIN1-MOT/seed-0/summary.json").unlink()
    shutil.rmtree(root / "p1/_baselines/follower-centre-oval")
    (root / "final/_races/race-0.json").unlink()
    result = run_tournament(path, workers=1, results_dir=res)
    assert result["this_run"]["done"] == 3 and result["this_run"]["skipped"] == 1
    assert result["this_run"]["lost"] == 3
    assert {(x["job_id"], x["action"]) for x in result["lost"]} == {
        ("p1/WIN1-MOT/seed-0", "run again"), ("p1/_baselines/follower-centre-oval", "run again"),
        ("final/_races", "run again")}
    rows = {r["job_id"]: r for r in _table(root / L.INDEX_FILE, "SELECT * FROM jobs")}
    assert all(r["status"] == "done" for r in rows.values())
    assert rows["final/_races"]["attempts"] == 2 and rows["p1/WIN1-MOT/seed-0"]["attempts"] == 2
    assert (root / "final/_races/race-0.json").is_file()
    assert (root / "p1/_baselines/follower-centre-oval/result.json").is_file()
    assert (root / "p1/WIN1-MOT/seed-0/summary.json").is_file()
