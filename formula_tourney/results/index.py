"""Reading a tournament's index (``index.sqlite``) read-only, with the layout's column names.

The parent process alone writes the index (``tourney.store``); readers such as the report use
this module so that a reader never opens the database for writing, never needs the store's code,
and sees one frame per table with exactly the columns of ``layout.INDEX_TABLES`` (a column an
older store lacks is present and empty).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.results import layout as L
from formula_tourney.results.folder import CorruptResultError

OPTIONAL_TABLES = ("general_models", "races")
"""Tables an index may lack without that being a gap (only parts with general-model selection
write it, and older stores did not have it)."""


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


def read_index(root: str | Path, problems: list[str] | None = None) -> dict[str, pd.DataFrame]:
    """The index tables of the tournament folder ``root``: ``jobs``, ``parts``, ``baselines`` and
    ``general_models``, each with the columns of ``layout.INDEX_TABLES``.

    No index.sqlite: UserInputError (not a tournament results folder). A file that is not an
    SQLite database: CorruptResultError naming it. A table the file lacks (a half-written or
    foreign index) reads as an empty frame and, when ``problems`` is given, adds a line to it.
    """
    db = index_path(root)
    frames: dict[str, pd.DataFrame] = {}
    with _open(root) as (con, present):
        for table, columns in L.INDEX_TABLES.items():
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


__all__ = ["OPTIONAL_TABLES", "index_path", "read_index", "read_meta"]
