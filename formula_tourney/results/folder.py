"""Reading and writing one job folder (or baseline folder) through one set of names.

Writers are atomic (temporary file, then rename), so a crash never leaves a file that a resume
would trust. Readers turn a corrupt or foreign file into :class:`CorruptResultError`, a
``UserInputError`` whose message names the file, never a pyarrow or JSON traceback.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.results import layout as L
from formula_tourney.safeio import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_parquet,
    atomic_write_text,
)


class CorruptResultError(UserInputError):
    """A results file exists but cannot be read (truncated, not Parquet/JSON, wrong columns)."""


class OldSchemaError(UserInputError):
    """A job folder written by another layout version than this tool reads."""


def read_json_file(path: Path, what: str) -> Any:
    """A JSON file's content; CorruptResultError naming the file when it does not parse."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise
    except (OSError, ValueError) as err:
        raise CorruptResultError(f"{path}: cannot read {what} ({err})") from None


def read_parquet_file(path: Path, what: str, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """A Parquet file as a frame with at least ``columns`` (missing ones are an error)."""
    try:
        frame = pd.read_parquet(path)
    except FileNotFoundError:
        raise
    except Exception as err:  # pyarrow raises several types for a truncated or foreign file
        raise CorruptResultError(
            f"{path}: cannot read {what} ({type(err).__name__}: {err})"
        ) from None
    if columns is not None:
        missing = [c for c in columns if c not in frame.columns]
        if missing:
            raise CorruptResultError(f"{path}: {what} lacks column(s) {', '.join(missing)}")
    return frame


def empty_table(name: str) -> pd.DataFrame:
    """An empty job table with its columns."""
    return pd.DataFrame(columns=L.JOB_TABLES[name])


class JobFolder:
    """One job's folder: ``JobFolder(path).tests()`` reads, ``.write_tables(...)`` writes."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    # ------------------------------------------------------------------------------ paths
    @property
    def config_path(self) -> Path:
        return self.path / L.CONFIG_FILE

    @property
    def summary_path(self) -> Path:
        return self.path / L.SUMMARY_FILE

    @property
    def tb_dir(self) -> Path:
        return self.path / L.TB_DIR

    def table_path(self, name: str) -> Path:
        if name not in L.JOB_TABLES:
            raise ValueError(f"unknown job table {name!r}; allowed: {', '.join(L.JOB_TABLES)}")
        return self.path / f"{name}.parquet"

    def trace_path(self, track: str) -> Path:
        return self.path / L.TRACES_DIR / f"{L.trace_name(track)}.parquet"

    def checkpoint_path(self, name: str) -> Path:
        """``best.pt``, ``last.pt`` or ``ep-<N>.pt`` inside ``checkpoints/``."""
        return self.path / L.CHECKPOINTS_DIR / name

    @property
    def resume_path(self) -> Path:
        """The resume file of an unfinished training job (``training.resume``)."""
        return self.path / L.RESUME_FILE

    def checkpoint_rel(self, name: str) -> str:
        """The checkpoint's path relative to the folder (as stored in tests.parquet)."""
        return f"{L.CHECKPOINTS_DIR}/{name}"

    # ------------------------------------------------------------------------------ state
    def is_finished(self) -> bool:
        """Finished when summary.json (written last) exists and parses."""
        if not self.summary_path.is_file():
            return False
        try:
            json.loads(self.summary_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        return True

    # ------------------------------------------------------------------------------ writers
    def write_config(self, run_spec: Mapping[str, Any], beyond_paper: Sequence[str] = ()) -> Path:
        """config.json: the layout version, the run specification (plain JSON data) and what in
        it goes beyond the paper (empty for a replication), which every table labels."""
        return atomic_write_json(self.config_path, {
            "schema_version": L.SCHEMA_VERSION, "run_spec": dict(run_spec),
            "beyond_paper": list(beyond_paper),
        })  # fmt: skip

    def write_tables(
        self,
        episodes: Sequence[Mapping[str, Any]],
        tests: Sequence[Mapping[str, Any]],
        laps: Sequence[Mapping[str, Any]],
    ) -> None:
        """The three job tables, each with exactly its declared columns."""
        for name, rows in (("episodes", episodes), ("tests", tests), ("laps", laps)):
            frame = pd.DataFrame(list(rows), columns=L.JOB_TABLES[name])
            atomic_write_parquet(self.table_path(name), frame)

    def write_trace(self, track: str, trace: pd.DataFrame) -> Path:
        return atomic_write_parquet(self.trace_path(track), trace)

    def write_summary(self, summary: Mapping[str, Any]) -> Path:
        return atomic_write_json(self.summary_path, dict(summary))

    def write_tourney_meta(self, meta: Mapping[str, Any]) -> Path:
        return atomic_write_json(self.path / L.TOURNEY_META_FILE, dict(meta))

    def write_error(self, text: str) -> Path:
        return atomic_write_text(self.path / L.ERROR_FILE, text)

    def write_resume(self, data: bytes) -> Path:
        """The resume file, atomically: a kill while writing leaves the previous one."""
        return atomic_write_bytes(self.resume_path, data)

    def remove_resume(self) -> None:
        """A finished job needs no resume file."""
        self.resume_path.unlink(missing_ok=True)

    # ------------------------------------------------------------------------------ readers
    def _config_document(self) -> dict[str, Any]:
        """config.json as written; a folder of another layout version raises OldSchemaError
        saying what it is, so a report of an older results folder says what it cannot read
        instead of guessing."""
        data = read_json_file(self.config_path, "the job's config.json")
        version = data.get("schema_version") if isinstance(data, dict) else None
        if version != L.SCHEMA_VERSION or not isinstance(data.get("run_spec"), dict):
            found = "unversioned (layout 1)" if version is None else f"layout {version}"
            raise OldSchemaError(
                f"{self.config_path}: written by another version of formula-tourney ({found}); "
                f"this version reads layout {L.SCHEMA_VERSION}: re-run the job to upgrade it"
            )
        return data

    def config(self) -> dict[str, Any]:
        """The run specification stored in config.json (as plain data)."""
        return dict(self._config_document()["run_spec"])

    def beyond_paper(self) -> list[str]:
        """What the run adds to the paper's setup (e.g. "SAC", "demos"), empty for the paper's."""
        return [str(x) for x in self._config_document().get("beyond_paper") or []]

    def summary(self) -> dict[str, Any]:
        data = read_json_file(self.summary_path, "the job's summary.json")
        if not isinstance(data, dict):
            raise CorruptResultError(f"{self.summary_path}: expected a JSON object")
        return data

    def table(self, name: str) -> pd.DataFrame:
        """A job table, every row (tests and laps: at every test grip); an empty frame with its
        columns when the job has not written it yet. Columns added within the layout
        (``ADDED_COLUMNS``) that an older file lacks are filled in."""
        path = self.table_path(name)
        if not path.is_file():
            return empty_table(name)
        added = L.ADDED_COLUMNS.get(name, ())
        required = [c for c in L.JOB_TABLES[name] if c not in added]
        frame = read_parquet_file(path, f"the job's {name} table", required)
        for col in added:
            if col not in frame.columns:
                frame[col] = float("nan")
        grips = (
            pd.to_numeric(frame["grip_scale"], errors="coerce") if "grip_scale" in added else None
        )
        if grips is not None and grips.isna().any():  # no grip recorded: the run's own grip
            frame["grip_scale"] = grips.fillna(self.own_grip_scale())
        return frame[L.JOB_TABLES[name]]

    def own_grip_scale(self) -> float:
        """The grip the run's own tests ran at: its env ``grip_scale``; the default, 1, when
        config.json is missing or unreadable (the reader of the tables reports that file)."""
        try:
            env = self.config().get("env") or {}
        except (FileNotFoundError, CorruptResultError):
            return 1.0
        grip = env.get("grip_scale", 1.0)
        if isinstance(grip, bool) or not isinstance(grip, int | float):
            raise CorruptResultError(
                f"{self.config_path}: run_spec.env.grip_scale is {grip!r}, "
                "not a number (a grip scale such as 1.0)"
            )
        return float(grip)

    def at_own_grip(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Rows of a tests or laps table at the run's own grip: what the best lap, promotion,
        the index and the paper's tables read (the other ``test_grip_scales`` feed the
        per-grip tables only)."""
        if frame.empty:
            return frame
        grips = pd.to_numeric(frame["grip_scale"], errors="coerce")
        return frame.loc[grips == self.own_grip_scale()].reset_index(drop=True)

    def tests(self) -> pd.DataFrame:
        """The tests at the run's own grip (:meth:`grip_tests` has every grip)."""
        return self.at_own_grip(self.table("tests"))

    def grip_tests(self) -> pd.DataFrame:
        """Every test row, each with the grip it ran at and the reference limit at that grip."""
        return self.table("tests")

    def episodes(self) -> pd.DataFrame:
        return self.table("episodes")

    def laps(self) -> pd.DataFrame:
        """The test laps at the run's own grip."""
        return self.at_own_grip(self.table("laps"))

    def trace(self, track: str) -> pd.DataFrame | None:
        """The best clean test lap's trace on ``track``, None when the job has none."""
        path = self.trace_path(track)
        if not path.is_file():
            return None
        return read_parquet_file(path, f"the trace of {track}")


class BaselineFolder:
    """One baseline drive's folder: result.json and the driven lap's trace."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @property
    def result_path(self) -> Path:
        return self.path / L.BASELINE_RESULT_FILE

    @property
    def trace_path(self) -> Path:
        return self.path / L.BASELINE_TRACE_FILE

    def is_finished(self) -> bool:
        if not self.result_path.is_file():
            return False
        try:
            json.loads(self.result_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        return True

    def write_result(self, result: Mapping[str, Any]) -> Path:
        return atomic_write_json(self.result_path, dict(result))

    def write_trace(self, trace: pd.DataFrame) -> Path:
        return atomic_write_parquet(self.trace_path, trace)

    def holds(self, config_hash: str) -> bool:
        """Whether the folder holds a finished drive of these settings (the bot's car, laps):
        a drive of other settings, or one from before drives carried a hash, is driven anew."""
        return self.is_finished() and self.result().get("config_hash") == config_hash

    def result(self) -> dict[str, Any]:
        data = read_json_file(self.result_path, "the baseline's result.json")
        if not isinstance(data, dict):
            raise CorruptResultError(f"{self.result_path}: expected a JSON object")
        return data

    def trace(self) -> pd.DataFrame | None:
        if not self.trace_path.is_file():
            return None
        return read_parquet_file(self.trace_path, "the baseline's trace")


class RaceFolder:
    """A series of races: one JSON per race, ``series.json`` (written last), the standings."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @property
    def series_path(self) -> Path:
        return self.path / L.RACE_SERIES_FILE

    @property
    def figures_path(self) -> Path:
        return self.path / L.RACE_FIGURES_DIR

    def is_finished(self) -> bool:
        return self.series_path.is_file()

    def is_complete(self, races: int) -> bool:
        """``series.json`` and every one of ``races`` race files are there (a deleted race file
        makes a finished series resumable again)."""
        return self.is_finished() and set(range(races)) <= set(self.race_numbers())

    def race_numbers(self) -> list[int]:
        """Numbers k of the race files present, in order."""
        if not self.path.is_dir():
            return []
        found = (L.RACE_FILE_RE.match(f.name) for f in self.path.iterdir())
        return sorted(int(m.group(1)) for m in found if m)

    def write_race(self, k: int, doc: Mapping[str, Any]) -> Path:
        return atomic_write_json(self.path / L.race_file_name(k), dict(doc))

    def write_qualifying(self, doc: Mapping[str, Any]) -> Path:
        return atomic_write_json(self.path / L.RACE_QUALIFYING_FILE, dict(doc))

    def qualifying(self) -> dict[str, Any] | None:
        """The kept qualifying (``L.RACE_QUALIFYING_FILE``), None when there is none."""
        path = self.path / L.RACE_QUALIFYING_FILE
        if not path.is_file():
            return None
        data = read_json_file(path, "the races' qualifying.json")
        if not isinstance(data, dict):
            raise CorruptResultError(f"{path}: expected a JSON object")
        return data

    def clear(self) -> None:
        """Remove the races, qualifying, series and derived files: a series starting afresh."""
        if self.path.exists():
            shutil.rmtree(self.path)
        self.path.mkdir(parents=True, exist_ok=True)

    def write_series(self, series: Mapping[str, Any]) -> Path:
        """Last: marks the series finished."""
        return atomic_write_json(self.series_path, dict(series))

    def write_standings(self, table: Mapping[str, Any], markdown: str) -> list[Path]:
        return [
            atomic_write_json(self.path / L.RACE_STANDINGS_FILE, dict(table)),
            atomic_write_text(self.path / L.RACE_STANDINGS_MD, markdown),
        ]

    def races(self) -> list[dict[str, Any]]:
        """Every race document, in race order."""
        found = []
        if self.path.is_dir():
            for f in self.path.iterdir():
                m = L.RACE_FILE_RE.match(f.name)
                if m:
                    found.append((int(m.group(1)), f))
        out = []
        for _, f in sorted(found):
            data = read_json_file(f, "a race result")
            if not isinstance(data, dict) or "results" not in data:
                raise CorruptResultError(f"{f}: not a race result")
            out.append(data)
        return out

    def series(self) -> dict[str, Any]:
        data = read_json_file(self.series_path, "the races' series.json")
        if not isinstance(data, dict):
            raise CorruptResultError(f"{self.series_path}: expected a JSON object")
        return data


__all__ = [
    "BaselineFolder",
    "CorruptResultError",
    "JobFolder",
    "OldSchemaError",
    "RaceFolder",
    "empty_table",
    "read_json_file",
    "read_parquet_file",
]
