"""The results index: ``index.sqlite`` of one tournament, written by the parent process only.

Tables ``jobs``, ``parts``, ``baselines``, ``general_models``, ``races`` (one row per race
part's series: status only, the results are the race files) and ``meta``; their schema, the file
names and the folder layout are ``results.layout``'s. Job folders are written by workers, each
file atomically, ``summary.json`` last, so a folder with ``summary.json`` is a finished job
whatever the index says: :meth:`Store.reconcile` trusts the files after a crash. An index that
is not SQLite, or lacks a column, is a ``CorruptResultError`` naming the file;
:meth:`Store.move_aside` makes room to rebuild it from the folders (``run --rebuild-index``).
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.results.folder import CorruptResultError, JobFolder
from formula_tourney.results.layout import INDEX_FILE, INDEX_SCHEMA, INDEX_TABLES, JOB_TABLES

JobMetrics = Callable[[Path, str | None], Mapping[str, Any]]
"""Reads a finished job folder (and the config hash the index expects of it) into the index's
numbers (``tourney.outcomes.job_metrics``)."""

REBUILD_HINT = "run again with --rebuild-index to move it aside and rebuild it from the job folders"


def now_iso() -> str:
    """UTC timestamp with seconds, as stored in started_at/finished_at."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


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
            db = sqlite3.connect(self.index_path, timeout=30, isolation_level=None)
            db.row_factory = sqlite3.Row
            try:
                # WAL: the report can read while the parent writes; synchronous=NORMAL is still
                # crash-safe for committed transactions in WAL mode (only the last may be lost).
                db.execute("PRAGMA journal_mode=WAL")
                db.execute("PRAGMA synchronous=NORMAL")
                self._check_columns(db)  # before the schema script adds to a foreign file
                db.executescript(INDEX_SCHEMA)
            except sqlite3.DatabaseError as err:
                db.close()
                raise self._corrupt(err) from None
            except CorruptResultError:
                db.close()
                raise
            self._db = db
        return self._db

    def _check_columns(self, db: sqlite3.Connection) -> None:
        for table, columns in INDEX_TABLES.items():
            have = {row[1] for row in db.execute(f"PRAGMA table_info({table})")}
            missing = [c for c in columns if c not in have]
            if have and missing:
                raise CorruptResultError(
                    f"{self.index_path}: not a results index of this version (table {table} "
                    f"lacks {', '.join(missing)}); {REBUILD_HINT}"
                )

    def _corrupt(self, err: sqlite3.DatabaseError) -> CorruptResultError:
        return CorruptResultError(f"{self.index_path}: cannot read the results index ({err}); "
                                  f"{REBUILD_HINT}")

    def check(self) -> None:
        """Open the index now: CorruptResultError naming it when it is not a readable index."""
        _ = self.db

    def move_aside(self) -> Path | None:
        """Rename the index (and its WAL files) out of the way so that the next open rebuilds it
        from the job folders; ``index.sqlite.corrupt`` when it cannot be read, else
        ``index.sqlite.old``. Returns the new path, None when there was no index."""
        self.close()
        if not self.index_path.exists():
            return None
        try:
            self.check()
            suffix = ".old"
        except CorruptResultError:
            suffix = ".corrupt"
        self.close()
        target = self.index_path.with_name(self.index_path.name + suffix)
        for extra in ("-wal", "-shm"):  # a stale WAL must never be replayed into the new index
            side = self.index_path.with_name(self.index_path.name + extra)
            if side.exists():
                os.replace(side, target.with_name(target.name + extra))
        os.replace(self.index_path, target)
        return target

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        db = self.db
        try:
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")
        except sqlite3.DatabaseError as err:
            if isinstance(err, sqlite3.OperationalError) and "locked" in str(err):
                raise
            raise self._corrupt(err) from None

    def _query(self, sql: str, args: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
        """Rows of a read; a damaged page is a CorruptResultError naming the index."""
        try:
            return self.db.execute(sql, args).fetchall()
        except sqlite3.DatabaseError as err:
            raise self._corrupt(err) from None

    def get_meta(self, key: str) -> str | None:
        rows = self._query("SELECT value FROM meta WHERE key=?", (key,))
        return None if not rows else str(rows[0][0])

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
        rows = self._query("SELECT * FROM parts WHERE part=?", (part,))
        return None if not rows else _decode_part(dict(rows[0]))

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
        rows = self._query("SELECT * FROM jobs WHERE job_id=?", (job_id,))
        return None if not rows else dict(rows[0])

    def job_rows(self, part: str | None = None) -> list[dict[str, Any]]:
        if part is None:
            rows = self._query("SELECT * FROM jobs ORDER BY position, job_id")
        else:
            rows = self._query("SELECT * FROM jobs WHERE part=? ORDER BY position, job_id", (part,))
        return [dict(r) for r in rows]

    def drop_jobs_except(self, part: str, keep: Iterable[str]) -> int:
        """Forget a part's jobs that its (re-computed) entrants no longer include; their folders
        stay on disk and are picked up again if those entrants come back. Returns how many."""
        keep = set(keep)
        gone = [r["job_id"] for r in self.job_rows(part) if r["job_id"] not in keep]
        with self.transaction() as db:
            db.executemany("DELETE FROM jobs WHERE job_id=?", [(j,) for j in gone])
            db.executemany("DELETE FROM general_models WHERE job_id=?", [(j,) for j in gone])
        return len(gone)

    def set_worker_pid(self, job_id: str, pid: int) -> None:
        with self.transaction() as db:
            db.execute("UPDATE jobs SET worker_pid=? WHERE job_id=?", (pid, job_id))

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
        return [dict(r) for r in self._query(sql + " ORDER BY part, bot, track", args)]

    def add_race(self, row: Mapping[str, Any]) -> None:
        """Record a race part's series (part, track, races, entrants, path, config_hash). A
        series already recorded keeps its status unless its config hash changed (other
        entrants or settings: another series), which makes it pending again."""
        with self.transaction() as db:
            db.execute(
                "INSERT OR IGNORE INTO races(part, track, races, entrants, status, attempts, "
                "path, config_hash) VALUES (?,?,?,?,'pending',0,?,?)",
                (row["part"], row["track"], row["races"], json.dumps(row["entrants"]),
                 row["path"], row["config_hash"]),
            )
            db.execute(
                "UPDATE races SET status='pending', reason=NULL, track=?, races=?, entrants=?, "
                "config_hash=? WHERE part=? AND config_hash IS NOT ?",
                (row["track"], row["races"], json.dumps(row["entrants"]), row["config_hash"],
                 row["part"], row["config_hash"]),
            )

    def race(self, part: str) -> dict[str, Any] | None:
        rows = self._query("SELECT * FROM races WHERE part=?", (part,))
        return None if not rows else _decode_race(dict(rows[0]))

    def set_race(self, part: str, **values: Any) -> None:
        """Update a race series' row; ``attempts=+1`` counts one more attempt."""
        bump = values.pop("attempts", None) == "+1"
        cols = [f"{k}=?" for k in values] + (["attempts=attempts+1"] if bump else [])
        if not cols:
            return
        with self.transaction() as db:
            db.execute(f"UPDATE races SET {', '.join(cols)} WHERE part=?",
                       (*[_num(v) if isinstance(v, float) else v for v in values.values()],
                        part))

    def race_rows(self) -> list[dict[str, Any]]:
        return [_decode_race(dict(r)) for r in self._query("SELECT * FROM races ORDER BY part")]

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

    def reconcile(self, job_metrics: JobMetrics) -> dict[str, int]:
        """After a crash or kill -9 of the parent: trust the job folders over the index.

        A folder with ``summary.json`` is done (the parent may have died before recording it;
        ``job_metrics`` reads its numbers); a 'running' job without one was interrupted and goes
        back to 'pending'. A finished folder whose files cannot be read is a CorruptResultError
        naming the file. Returns counts.
        """
        fixed = {"recovered_done": 0, "requeued": 0}
        for row in self.job_rows():
            if row["status"] == "done":
                continue
            if self.recover(row["job_id"], job_metrics):
                fixed["recovered_done"] += 1
            elif row["status"] == "running":
                self.mark_pending(row["job_id"])
                fixed["requeued"] += 1
        with self.transaction() as db:
            db.execute("UPDATE baselines SET status='pending' WHERE status='running'")
            db.execute("UPDATE races SET status='pending' WHERE status='running'")
            db.execute("UPDATE parts SET status='pending' WHERE status='running'")
        return fixed

    def recover(self, job_id: str, job_metrics: JobMetrics) -> bool:
        """Mark a job done from its folder if that folder is finished; whether it was."""
        row = self.job(job_id) or {}
        job_dir = self.root / (row.get("path") or job_id)
        if not JobFolder(job_dir).is_finished():
            return False
        try:
            metrics = job_metrics(job_dir, row.get("config_hash"))
        except CorruptResultError as err:
            raise CorruptResultError(f"{err}; remove the job folder {job_dir} to run that job "
                                     "again") from None
        self.mark_done(job_id, dict(metrics), None)
        return True

    # ------------------------------------------------------------------ read helpers (report)
    def jobs(self) -> pd.DataFrame:
        """All jobs as a DataFrame (train_tracks decoded to lists, lac as bool)."""
        frame = pd.DataFrame(self.job_rows())
        if not frame.empty:
            frame["train_tracks"] = frame["train_tracks"].map(json.loads)
            frame["lac"] = frame["lac"].astype(bool)
        return frame

    def parts(self) -> pd.DataFrame:
        rows = self._query("SELECT * FROM parts ORDER BY position")
        return pd.DataFrame([_decode_part(dict(r)) for r in rows])

    def baselines(self) -> pd.DataFrame:
        return pd.DataFrame(self.baseline_rows())

    def general_models(self) -> pd.DataFrame:
        rows = [dict(r) for r in self._query("SELECT * FROM general_models ORDER BY job_id")]
        for row in rows:
            row["laps"] = json.loads(row["laps"])
            row["chosen"] = bool(row["chosen"])
        return pd.DataFrame(rows)

    def job_dir(self, job_id: str) -> Path:
        row = self.job(job_id)
        return self.root / (row["path"] if row else job_id)

    def read_job_table(self, job_id: str, table: str) -> pd.DataFrame:
        """One of a job's tables (``results.layout.JOB_TABLES``: tests, episodes, laps); an
        empty frame with its columns when the job has not written it."""
        if table not in JOB_TABLES:
            raise ValueError(f"unknown job table {table!r}; allowed: {', '.join(JOB_TABLES)}")
        return JobFolder(self.job_dir(job_id)).table(table)


def _decode_part(row: dict[str, Any]) -> dict[str, Any]:
    for key in ("entrants", "promoted", "ranking"):
        if row.get(key):
            row[key] = json.loads(row[key])
    return row


def _decode_race(row: dict[str, Any]) -> dict[str, Any]:
    if row.get("entrants"):
        row["entrants"] = json.loads(row["entrants"])
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
