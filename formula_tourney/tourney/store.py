"""The results store: the one module that knows the layout of ``results/<tournament>/``.

Write side (parent process only): ``index.sqlite`` with tables ``jobs``, ``parts``,
``baselines``, ``general_models`` and ``meta``. Job folders are written by workers (through
``training.loop.train`` and ``tourney.runner``), each file atomically, ``summary.json`` last, so a
folder with ``summary.json`` is a finished job whatever the index says: :meth:`Store.reconcile`
trusts the files after a crash. Read side: small helpers for the report.

Layout (docs/CONTRACTS.md, "tourney store")::

    <root>/index.sqlite
    <root>/.lock                                   held by the running ``run`` (tourney.lock)
    <root>/<part>/<entrant>/seed-<n>/              one training job (training.loop.train)
    <root>/<part>/_baselines/<bot>-<ref>-<track>/  one baseline drive (result.json, trace.parquet)
    <root>/optuna/<variant>.journal                tune studies (JournalFileBackend)
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

SUMMARY_FILE = "summary.json"
INDEX_FILE = "index.sqlite"
BASELINE_DIR = "_baselines"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS jobs (
    job_id TEXT PRIMARY KEY, study TEXT, part TEXT, entrant TEXT, variant TEXT, family TEXT,
    seed INTEGER, reference TEXT, lac INTEGER, train_tracks TEXT,
    status TEXT NOT NULL DEFAULT 'pending', reason TEXT, attempts INTEGER NOT NULL DEFAULT 0,
    path TEXT, started_at TEXT, finished_at TEXT, wall_s REAL,
    position INTEGER, config_hash TEXT, worker_pid INTEGER,
    best_lap_s REAL, finished INTEGER, damage REAL, train_seconds REAL, test_distance_m REAL
);
CREATE TABLE IF NOT EXISTS parts (
    part TEXT PRIMARY KEY, study TEXT, position INTEGER, status TEXT NOT NULL DEFAULT 'pending',
    entrants TEXT, promoted TEXT, reason TEXT, ranking TEXT, source TEXT
);
CREATE TABLE IF NOT EXISTS baselines (
    part TEXT, bot TEXT, track TEXT, reference TEXT, best_lap_s REAL, damage REAL,
    finished INTEGER, reference_limit_s REAL, status TEXT NOT NULL DEFAULT 'pending', reason TEXT,
    path TEXT, PRIMARY KEY (part, bot, track, reference)
);
CREATE TABLE IF NOT EXISTS general_models (
    part TEXT, job_id TEXT PRIMARY KEY, entrant TEXT, seed INTEGER, episode INTEGER,
    checkpoint TEXT, train_track TEXT, train_lap_s REAL, laps TEXT, chosen INTEGER
);
"""

JOB_STATUSES = ("pending", "running", "done", "failed")


def now_iso() -> str:
    """UTC timestamp with seconds, as stored in started_at/finished_at."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def job_rel_path(part: str, entrant: str, seed: int) -> str:
    """Job folder relative to the tournament root; equal to the job id."""
    return f"{part}/{entrant}/seed-{seed}"


def baseline_rel_path(part: str, bot: str, reference: str, track: str) -> str:
    """Baseline folder relative to the tournament root."""
    return f"{part}/{BASELINE_DIR}/{bot}-{reference}-{track}"


def is_finished(job_dir: Path) -> bool:
    """A job folder is finished when its summary.json (written last) exists and parses."""
    path = job_dir / SUMMARY_FILE
    if not path.is_file():
        return False
    try:
        json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return True


class Store:
    """Index and folders of one tournament. Only the parent process constructs a writing Store."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._db: sqlite3.Connection | None = None

    # ------------------------------------------------------------------ connection and meta
    @property
    def index_path(self) -> Path:
        return self.root / INDEX_FILE

    def exists(self) -> bool:
        """Whether a run has already created this tournament's index."""
        return self.index_path.is_file()

    @property
    def db(self) -> sqlite3.Connection:
        if self._db is None:
            self.root.mkdir(parents=True, exist_ok=True)
            # WAL: the report can read while the parent writes; synchronous=NORMAL is still
            # crash-safe for committed transactions in WAL mode (only the last may be lost).
            self._db = sqlite3.connect(self.index_path, timeout=30, isolation_level=None)
            self._db.row_factory = sqlite3.Row
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
        return self._db

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        db = self.db
        db.execute("BEGIN IMMEDIATE")
        try:
            yield db
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")

    def get_meta(self, key: str) -> str | None:
        row = self.db.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_meta(self, key: str, value: str) -> None:
        with self.transaction() as db:
            db.execute("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)", (key, value))

    # ------------------------------------------------------------------ plan
    def add_part(self, part: str, study: str, position: int, source: str | None) -> None:
        """Insert a part if new (a resumed run keeps its status and promotion)."""
        with self.transaction() as db:
            db.execute(
                "INSERT OR IGNORE INTO parts(part, study, position, status, source) "
                "VALUES (?, ?, ?, 'pending', ?)",
                (part, study, position, source),
            )

    def part(self, part: str) -> dict[str, Any] | None:
        row = self.db.execute("SELECT * FROM parts WHERE part=?", (part,)).fetchone()
        return None if row is None else _decode_part(dict(row))

    def set_part(self, part: str, **values: Any) -> None:
        """Update columns of a part; lists and dicts are stored as JSON."""
        if not values:
            return
        cols = ", ".join(f"{key}=?" for key in values)
        args = [json.dumps(v) if isinstance(v, list | dict) else v for v in values.values()]
        with self.transaction() as db:
            db.execute(f"UPDATE parts SET {cols} WHERE part=?", (*args, part))

    def add_jobs(self, rows: Iterable[dict[str, Any]]) -> None:
        """Insert planned training jobs that are not in the index yet (resume keeps the rest)."""
        with self.transaction() as db:
            for row in rows:
                db.execute(
                    "INSERT OR IGNORE INTO jobs(job_id, study, part, entrant, variant, family, "
                    "seed, reference, lac, train_tracks, status, attempts, path, position, "
                    "config_hash) VALUES (?,?,?,?,?,?,?,?,?,?,'pending',0,?,?,?)",
                    (
                        row["job_id"], row["study"], row["part"], row["entrant"],
                        row["variant"], row["family"], row["seed"], row["reference"],
                        int(row["lac"]), json.dumps(row["train_tracks"]), row["path"],
                        row["position"], row["config_hash"],
                    ),
                )

    def add_baselines(self, rows: Iterable[dict[str, Any]]) -> None:
        with self.transaction() as db:
            for row in rows:
                db.execute(
                    "INSERT OR IGNORE INTO baselines(part, bot, track, reference, status, path) "
                    "VALUES (?,?,?,?,'pending',?)",
                    (row["part"], row["bot"], row["track"], row["reference"], row["path"]),
                )

    # ------------------------------------------------------------------ job lifecycle
    def job(self, job_id: str) -> dict[str, Any] | None:
        row = self.db.execute("SELECT * FROM jobs WHERE job_id=?", (job_id,)).fetchone()
        return None if row is None else dict(row)

    def job_rows(self, part: str | None = None) -> list[dict[str, Any]]:
        if part is None:
            rows = self.db.execute("SELECT * FROM jobs ORDER BY position, job_id").fetchall()
        else:
            rows = self.db.execute(
                "SELECT * FROM jobs WHERE part=? ORDER BY position, job_id", (part,)
            ).fetchall()
        return [dict(r) for r in rows]

    def mark_running(self, job_id: str, worker_pid: int | None) -> None:
        with self.transaction() as db:
            db.execute(
                "UPDATE jobs SET status='running', attempts=attempts+1, started_at=?, "
                "worker_pid=?, reason=NULL WHERE job_id=?",
                (now_iso(), worker_pid, job_id),
            )

    def mark_done(self, job_id: str, metrics: dict[str, Any], wall_s: float | None) -> None:
        with self.transaction() as db:
            db.execute(
                "UPDATE jobs SET status='done', reason=NULL, finished_at=?, wall_s=?, "
                "best_lap_s=?, finished=?, damage=?, train_seconds=?, test_distance_m=? "
                "WHERE job_id=?",
                (
                    now_iso(), wall_s, _num(metrics.get("best_lap_s")),
                    int(bool(metrics.get("finished"))), _num(metrics.get("damage")),
                    _num(metrics.get("seconds")), _num(metrics.get("distance_m")), job_id,
                ),
            )

    def mark_failed(self, job_id: str, reason: str, wall_s: float | None) -> None:
        with self.transaction() as db:
            db.execute(
                "UPDATE jobs SET status='failed', reason=?, finished_at=?, wall_s=? "
                "WHERE job_id=?",
                (reason[:2000], now_iso(), wall_s, job_id),
            )

    def mark_pending(self, job_id: str) -> None:
        with self.transaction() as db:
            db.execute("UPDATE jobs SET status='pending', worker_pid=NULL WHERE job_id=?",
                       (job_id,))

    def set_baseline(self, key: tuple[str, str, str, str], **values: Any) -> None:
        cols = ", ".join(f"{k}=?" for k in values)
        with self.transaction() as db:
            db.execute(
                f"UPDATE baselines SET {cols} WHERE part=? AND bot=? AND track=? AND reference=?",
                (*[_num(v) if isinstance(v, float) else v for v in values.values()], *key),
            )

    def baseline_rows(self, part: str | None = None) -> list[dict[str, Any]]:
        sql = "SELECT * FROM baselines"
        args: tuple[Any, ...] = ()
        if part is not None:
            sql += " WHERE part=?"
            args = (part,)
        return [dict(r) for r in self.db.execute(sql + " ORDER BY part, bot, track", args)]

    def set_general_models(self, part: str, rows: list[dict[str, Any]]) -> None:
        with self.transaction() as db:
            db.execute("DELETE FROM general_models WHERE part=?", (part,))
            for row in rows:
                db.execute(
                    "INSERT INTO general_models(part, job_id, entrant, seed, episode, checkpoint,"
                    " train_track, train_lap_s, laps, chosen) VALUES (?,?,?,?,?,?,?,?,?,?)",
                    (
                        part, row["job_id"], row["entrant"], row["seed"], row["episode"],
                        row["checkpoint"], row["train_track"], _num(row["train_lap_s"]),
                        json.dumps(row["laps"]), int(row["chosen"]),
                    ),
                )

    def reconcile(self) -> dict[str, int]:
        """After a crash or kill -9 of the parent: trust the job folders over the index.

        A folder with ``summary.json`` is done (the parent may have died before recording it);
        a 'running' job without one was interrupted and goes back to 'pending'. Returns counts.
        """
        fixed = {"recovered_done": 0, "requeued": 0}
        for row in self.job_rows():
            if row["status"] == "done":
                continue
            job_dir = self.root / row["path"]
            if is_finished(job_dir):
                from formula_tourney.tourney.runner import job_metrics

                train_track = json.loads(row["train_tracks"])[0]
                self.mark_done(row["job_id"], job_metrics(job_dir, train_track), None)
                fixed["recovered_done"] += 1
            elif row["status"] == "running":
                self.mark_pending(row["job_id"])
                fixed["requeued"] += 1
        with self.transaction() as db:
            db.execute("UPDATE baselines SET status='pending' WHERE status='running'")
            db.execute("UPDATE parts SET status='pending' WHERE status='running'")
        return fixed

    # ------------------------------------------------------------------ read helpers (report)
    def jobs(self) -> Any:
        """All jobs as a DataFrame (train_tracks decoded to lists, lac as bool)."""
        import pandas as pd

        frame = pd.DataFrame(self.job_rows())
        if not frame.empty:
            frame["train_tracks"] = frame["train_tracks"].map(json.loads)
            frame["lac"] = frame["lac"].astype(bool)
        return frame

    def parts(self) -> Any:
        import pandas as pd

        rows = self.db.execute("SELECT * FROM parts ORDER BY position").fetchall()
        return pd.DataFrame([_decode_part(dict(r)) for r in rows])

    def baselines(self) -> Any:
        import pandas as pd

        return pd.DataFrame(self.baseline_rows())

    def general_models(self) -> Any:
        import pandas as pd

        rows = [dict(r) for r in self.db.execute("SELECT * FROM general_models ORDER BY job_id")]
        for row in rows:
            row["laps"] = json.loads(row["laps"])
            row["chosen"] = bool(row["chosen"])
        return pd.DataFrame(rows)

    def job_dir(self, job_id: str) -> Path:
        row = self.job(job_id)
        return self.root / (row["path"] if row else job_id)

    def read_job_table(self, job_id: str, table: str) -> Any:
        """One of a job's tables: 'tests', 'episodes' or 'laps' (an empty frame if absent)."""
        import pandas as pd

        if table not in ("tests", "episodes", "laps"):
            raise ValueError(f"unknown job table {table!r}; allowed: tests, episodes, laps")
        path = self.job_dir(job_id) / f"{table}.parquet"
        return pd.read_parquet(path) if path.is_file() else pd.DataFrame()


def _decode_part(row: dict[str, Any]) -> dict[str, Any]:
    for key in ("entrants", "promoted", "ranking"):
        if row.get(key):
            row[key] = json.loads(row[key])
    return row


def _num(value: Any) -> float | None:
    """SQLite has no NaN: store it as NULL."""
    if value is None:
        return None
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return None if value != value else value
