"""Reading a tournament's index (``index.sqlite``) read-only, with the layout's column names.

The parent process alone writes the index (``tourney.store``); readers such as the report use
this module so that a reader never opens the database for writing, never needs the store's code,
and sees one frame per table with the columns of ``layout.INDEX_TABLES`` (a column an older
store lacks is present and empty). The ``jobs`` table holds every kind of job; its ``attrs`` and
``result`` objects arrive spread into columns, and :func:`rows_of_kind` picks one kind's rows
with that kind's columns (``tourney.kinds``). An index of the older layout (a table per job
kind, ``layout.LEGACY_JOB_TABLES``) reads as if it were the current one: :func:`legacy_job_rows`
turns its rows into ``jobs`` rows, for the report here and for ``tourney.store``'s migration.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.results import layout as L
from formula_tourney.results.folder import CorruptResultError

OPTIONAL_TABLES = ("general_models",)
"""Tables an index may lack without that being a gap (only parts with general-model selection
write it, and older stores did not have it)."""

JOB_COLUMNS = [c for c in L.INDEX_TABLES["jobs"] if c not in L.JOB_JSON_COLUMNS]
"""The ``jobs`` columns every kind shares, as a reader sees them (``attrs`` and ``result``
spread out after them)."""


def index_path(root: str | Path) -> Path:
    return Path(root) / L.INDEX_FILE


@contextmanager
def _open(root: str | Path) -> Iterator[tuple[sqlite3.Connection, set[str]]]:
    """A read-only connection and the names of the tables the file holds."""
    db = index_path(root)
    if not db.is_file():
        raise UserInputError(f"{Path(root)}: no {L.INDEX_FILE} (not a tournament results folder)")
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    except sqlite3.Error as err:
        raise CorruptResultError(f"{db}: cannot open the results index ({err})") from None
    try:
        try:
            present = {row[0] for row in con.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
        except sqlite3.DatabaseError as err:
            raise CorruptResultError(f"{db}: not a results index ({err})") from None
        yield con, present
    finally:
        con.close()


def decode_job(row: Mapping[str, Any]) -> dict[str, Any]:
    """A ``jobs`` row as one flat dict: the shared columns, then its ``attrs`` and ``result``
    keys (JSON text or already decoded)."""
    out = {k: v for k, v in row.items() if k not in L.JOB_JSON_COLUMNS}
    for col in L.JOB_JSON_COLUMNS:
        value = row.get(col)
        if isinstance(value, str):
            value = json.loads(value)
        out.update(value or {})
    return out


def is_legacy(con: sqlite3.Connection, present: set[str]) -> bool:
    """Whether the index has the older layout: a table per job kind, no ``kind`` column."""
    if present & {"baselines", "races"}:
        return True
    if "jobs" not in present:
        return False
    return "kind" not in {row[1] for row in con.execute("PRAGMA table_info(jobs)")}


def _table(con: sqlite3.Connection, present: set[str], table: str) -> list[dict[str, Any]]:
    if table not in present:
        return []
    cursor = con.cursor()
    cursor.row_factory = sqlite3.Row  # on this cursor only: the connection may be the store's
    return [dict(r) for r in cursor.execute(f"SELECT * FROM {table}")]  # noqa: S608 (fixed)


def _num(value: Any) -> Any:
    return None if value is None else float(value)


def legacy_job_rows(con: sqlite3.Connection, present: set[str]) -> list[dict[str, Any]]:
    """The rows of an older index's ``jobs``, ``baselines`` and ``races`` tables as rows of the
    current ``jobs`` table (``attrs`` and ``result`` as dicts). A baseline drive or a race series
    is keyed by its folder, as its job id has always been; its part's position comes from the
    ``parts`` table; a result is there only for a job that finished."""
    positions = {r["part"]: r["position"] for r in _table(con, present, "parts")}
    out = []
    for r in _table(con, present, "jobs"):
        attrs = {"study": r.get("study"), "entrant": r.get("entrant"),
                 "variant": r.get("variant"), "family": r.get("family"), "seed": r.get("seed"),
                 "reference": r.get("reference"),
                 "lac": None if r.get("lac") is None else bool(r["lac"]),
                 "train_tracks": json.loads(r["train_tracks"]) if r.get("train_tracks") else []}
        result = {"best_lap_s": r.get("best_lap_s"),
                  "finished": None if r.get("finished") is None else bool(r["finished"]),
                  "damage": r.get("damage"), "train_seconds": r.get("train_seconds"),
                  "test_distance_m": r.get("test_distance_m")}  # fmt: skip
        out.append(_row(r, r["job_id"], "train", r.get("position"), attrs, result))
    for r in _table(con, present, "baselines"):
        attrs = {"bot": r["bot"], "track": r["track"], "reference": r["reference"]}
        result = {"best_lap_s": _num(r.get("best_lap_s")), "damage": _num(r.get("damage")),
                  "finished": None if r.get("finished") is None else bool(r["finished"]),
                  "reference_limit_s": _num(r.get("reference_limit_s"))}
        out.append(_row(r, r["path"], "baseline", positions.get(r["part"]), attrs, result))
    for r in _table(con, present, "races"):
        attrs = {"track": r["track"], "races": r["races"],
                 "entrants": json.loads(r["entrants"]) if r.get("entrants") else []}
        out.append(_row(r, r["path"], "race", positions.get(r["part"]), attrs, {}))
    return out


def _row(old: dict[str, Any], job_id: str, kind: str, position: Any, attrs: dict[str, Any],
         result: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {c: old.get(c) for c in JOB_COLUMNS}
    row.update(job_id=job_id, kind=kind, position=position, attempts=old.get("attempts") or 0,
               attrs=attrs, result=result if old.get("status") == "done" else None)
    return row


def read_index(root: str | Path, problems: list[str] | None = None) -> dict[str, pd.DataFrame]:
    """The index tables of the tournament folder ``root``: ``jobs`` (every kind, ``attrs`` and
    ``result`` spread into columns after :data:`JOB_COLUMNS`), ``parts`` and
    ``general_models``, each with at least the columns of ``layout.INDEX_TABLES``.

    No index.sqlite: UserInputError (not a tournament results folder). A file that is not an
    SQLite database: CorruptResultError naming it. A table the file lacks (a half-written or
    foreign index) reads as an empty frame and, when ``problems`` is given, adds a line to it.
    An index of the older layout reads through :func:`legacy_job_rows`.
    """
    db = index_path(root)
    frames: dict[str, pd.DataFrame] = {}
    with _open(root) as (con, present):
        try:
            legacy = is_legacy(con, present)
            jobs = (legacy_job_rows(con, present) if legacy
                    else _table(con, present, "jobs"))  # fmt: skip
        except (sqlite3.Error, ValueError) as err:
            raise CorruptResultError(f"{db}: cannot read the jobs ({err})") from None
        if "jobs" not in present and problems is not None:
            problems.append(f"{db}: table 'jobs' missing; read as empty")
        flat = [decode_job(r) for r in jobs]
        extra = list(dict.fromkeys(k for r in flat for k in r if k not in JOB_COLUMNS))
        frames["jobs"] = pd.DataFrame(flat, columns=[*JOB_COLUMNS, *extra])
        for table, columns in L.INDEX_TABLES.items():
            if table == "jobs":
                continue
            if table not in present:
                if problems is not None and table not in OPTIONAL_TABLES:
                    problems.append(f"{db}: table {table!r} missing; read as empty")
                frames[table] = pd.DataFrame(columns=columns)
                continue
            try:
                frame = pd.read_sql_query(f"SELECT * FROM {table}", con)  # noqa: S608 (fixed)
            except (sqlite3.Error, pd.errors.DatabaseError) as err:
                raise CorruptResultError(f"{db}: cannot read table {table!r} ({err})") from None
            for col in columns:
                if col not in frame.columns:
                    frame[col] = pd.NA
            frames[table] = frame[columns]
    return frames


def rows_of_kind(jobs: pd.DataFrame, kind: str, columns: Sequence[str]) -> pd.DataFrame:
    """The rows of ``read_index``'s ``jobs`` frame of one kind, with exactly ``columns`` (the
    kind's: ``tourney.kinds.JobKind.columns``; one no row has is present and empty)."""
    frame = jobs.loc[jobs["kind"] == kind].reset_index(drop=True)
    for col in columns:
        if col not in frame.columns:
            frame[col] = pd.NA
    return frame[list(columns)]


def read_meta(root: str | Path) -> dict[str, str]:
    """The index's ``meta`` key/value table (``spec``: the tournament spec as JSON, ...); empty
    when the index has none. Errors as ``read_index``."""
    db = index_path(root)
    with _open(root) as (con, present):
        if "meta" not in present:
            return {}
        try:
            return {str(k): str(v) for k, v in con.execute("SELECT key, value FROM meta")}
        except sqlite3.DatabaseError as err:
            raise CorruptResultError(f"{db}: cannot read table 'meta' ({err})") from None


__all__ = ["JOB_COLUMNS", "OPTIONAL_TABLES", "decode_job", "index_path", "is_legacy",
           "legacy_job_rows", "read_index", "read_meta", "rows_of_kind"]
