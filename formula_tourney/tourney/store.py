"""The results index: ``index.sqlite`` of one tournament, written by the parent process only.

Tables ``jobs`` (every job of every kind, one row per job id: its kind, status, attempts and
times, with ``attrs`` and ``result`` JSON objects whose keys its ``tourney.kinds`` object
declares), ``parts``, ``general_models`` and ``meta``; their schema, the file names and the
folder layout are ``results.layout``'s. The store knows no kind: it keeps rows by job id and
hands them back flat (``results.index.decode_job``). Job folders are written by workers, each
file atomically, the finishing file last, so the folders are the truth after a crash: the
scheduler records a finished folder the index missed (``tourney.kinds.JobKind.finished``).
An index of the older layout (a table per kind) is migrated in place, in one transaction, the
first time a run opens it. An index that is not SQLite, or lacks a column, is a
``CorruptResultError`` naming the file; :meth:`Store.move_aside` makes room to rebuild it from
the folders (``run --rebuild-index``).
"""

from __future__ import annotations

import json
import os
import re
import sqlite3
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import CorruptResultError, JobFolder
from formula_tourney.results.index import decode_job, is_legacy, legacy_job_rows
from formula_tourney.results.layout import INDEX_FILE, INDEX_SCHEMA, INDEX_TABLES, JOB_TABLES
from formula_tourney.safeio import make_dirs

REBUILD_HINT = "run again with --rebuild-index to move it aside and rebuild it from the job folders"
_NOT_DAMAGED = re.compile(r"disk is full|disk I/O error|readonly|read-only|unable to open")
"""SQLite's words for a failure of the disk or the folder, not of the index's content."""


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
            make_dirs(self.root, "results folder")
            db = sqlite3.connect(self.index_path, timeout=30, isolation_level=None)
            db.row_factory = sqlite3.Row
            try:
                # WAL: the report can read while the parent writes; synchronous=NORMAL is still
                # crash-safe for committed transactions in WAL mode (only the last may be lost).
                db.execute("PRAGMA journal_mode=WAL")
                db.execute("PRAGMA synchronous=NORMAL")
                self._migrate(db)
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

    def _migrate(self, db: sqlite3.Connection) -> None:
        """Turn an index of the older layout (a table per job kind) into the current one, in
        one transaction: its rows as ``results.index.legacy_job_rows`` reads them."""
        present = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if not is_legacy(db, present):
            return
        try:
            rows = legacy_job_rows(db, present)
        except ValueError as err:  # a JSON column that is not JSON
            raise CorruptResultError(f"{self.index_path}: cannot read the older index's jobs "
                                     f"({err}); {REBUILD_HINT}") from None
        db.execute("BEGIN IMMEDIATE")
        try:
            for table in ("jobs", "baselines", "races"):
                db.execute(f"DROP TABLE IF EXISTS {table}")
            for statement in INDEX_SCHEMA.split(";"):
                if statement.strip():
                    db.execute(statement)
            _insert(db, rows)
            for row in rows:
                db.execute("UPDATE jobs SET status=?, reason=?, attempts=?, started_at=?, "
                           "finished_at=?, wall_s=?, worker_pid=?, result=? WHERE job_id=?",
                           (row["status"] or "pending", row["reason"], row["attempts"],
                            row["started_at"], row["finished_at"], row["wall_s"],
                            row["worker_pid"], _json(row["result"]), row["job_id"]))
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")

    def _check_columns(self, db: sqlite3.Connection) -> None:
        for table, columns in INDEX_TABLES.items():
            have = {row[1] for row in db.execute(f"PRAGMA table_info({table})")}
            missing = [c for c in columns if c not in have]
            if have and missing:
                raise CorruptResultError(
                    f"{self.index_path}: not a results index of this version (table {table} "
                    f"lacks {', '.join(missing)}); {REBUILD_HINT}"
                )

    def _corrupt(self, err: sqlite3.DatabaseError) -> UserInputError:
        """The error of a failed read or write: a full disk or a folder that cannot be written
        is said as such (the index is intact: the same command resumes once it is fixed); any
        other database error is a damaged index, which ``--rebuild-index`` replaces."""
        if isinstance(err, sqlite3.OperationalError) and _NOT_DAMAGED.search(str(err)):
            return UserInputError(f"{self.index_path}: cannot write the results index ({err}); "
                                  "the index is intact: free space (or fix the folder's "
                                  "permissions) and run the same command again to resume")
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
                if db.in_transaction:  # SQLite ends it itself on a full disk: keep that error
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

    def add_jobs(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Record planned jobs of any kind (``tourney.kinds.JobKind.index_row``: job_id, kind,
        part, position, path, config_hash, attrs). A job already recorded keeps its status,
        attempts and result; its attrs and config hash become the plan's, so a job of changed
        settings no longer matches a finished folder of the old ones."""
        with self.transaction() as db:
            _insert(db, rows)

    # ------------------------------------------------------------------ job lifecycle
    def job(self, job_id: str) -> dict[str, Any] | None:
        """One job's row, flat (shared columns, then its attrs and result keys)."""
        rows = self._query("SELECT * FROM jobs WHERE job_id=?", (job_id,))
        return None if not rows else decode_job(dict(rows[0]))

    def rows(self, kind: str | None = None, part: str | None = None) -> list[dict[str, Any]]:
        """Flat rows of the jobs of one kind and/or part (all when None), in plan order."""
        where = [(col, value) for col, value in (("kind", kind), ("part", part))
                 if value is not None]
        sql = "SELECT * FROM jobs"
        if where:
            sql += " WHERE " + " AND ".join(f"{col}=?" for col, _ in where)
        rows = self._query(sql + " ORDER BY position, job_id", tuple(v for _, v in where))
        return [decode_job(dict(r)) for r in rows]

    def drop_jobs_except(self, part: str, kind: str, keep: Iterable[str]) -> int:
        """Forget a part's jobs of one kind that its (re-computed) plan no longer includes;
        their folders stay on disk and are picked up again if those jobs come back. Returns
        how many."""
        keep = set(keep)
        gone = [r["job_id"] for r in self.rows(kind, part) if r["job_id"] not in keep]
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

    def mark_done(self, job_id: str, result: Mapping[str, Any], wall_s: float | None) -> None:
        """The job finished: its kind's result (``JobKind.result``) and the wall time of this
        attempt (None when recovered from its folder)."""
        with self.transaction() as db:
            db.execute(
                "UPDATE jobs SET status='done', reason=NULL, finished_at=?, wall_s=?, result=? "
                "WHERE job_id=?",
                (now_iso(), wall_s, _json(dict(result)), job_id),
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

    def reconcile(self) -> int:
        """After a crash or kill -9 of the parent: the jobs and parts it left running go back
        to pending (the scheduler then records the finished folders among them, from the
        files). Returns how many jobs."""
        with self.transaction() as db:
            requeued = db.execute("UPDATE jobs SET status='pending', worker_pid=NULL "
                                  "WHERE status='running'").rowcount
            db.execute("UPDATE parts SET status='pending' WHERE status='running'")
        return requeued

    # ------------------------------------------------------------------ read helpers (report)
    def jobs(self, kind: str | None = None) -> pd.DataFrame:
        """The jobs of one kind (all when None) as a DataFrame of flat rows."""
        return pd.DataFrame(self.rows(kind))

    def parts(self) -> pd.DataFrame:
        rows = self._query("SELECT * FROM parts ORDER BY position")
        return pd.DataFrame([_decode_part(dict(r)) for r in rows])

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


def _insert(db: sqlite3.Connection, rows: Iterable[Mapping[str, Any]]) -> None:
    for row in rows:
        db.execute(
            "INSERT INTO jobs(job_id, kind, part, position, path, config_hash, attrs) "
            "VALUES (?,?,?,?,?,?,?) ON CONFLICT(job_id) DO UPDATE SET kind=excluded.kind, "
            "part=excluded.part, position=excluded.position, path=excluded.path, "
            "config_hash=excluded.config_hash, attrs=excluded.attrs",
            (row["job_id"], row["kind"], row["part"], row["position"], row["path"],
             row["config_hash"], _json(row["attrs"])),
        )


def _json(value: Mapping[str, Any] | None) -> str | None:
    """A JSON object for the index: NaN becomes null (JSON has none)."""
    if value is None:
        return None
    return json.dumps({k: _num(v) if isinstance(v, float) else v for k, v in value.items()})


def _num(value: Any) -> float | None:
    """SQLite has no NaN: store it as NULL."""
    if value is None:
        return None
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return None if value != value else value
