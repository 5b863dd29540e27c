"""The report reads results only through the results layout: the read-only index reader and the
job-folder readers; every unreadable file is a problem line naming it, never a traceback."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from report_fixtures import build_tournament

from formula_tourney.errors import UserInputError
from formula_tourney.report.load import DEFAULT_UNSEEN_FINISH_RATE, load_tournament
from formula_tourney.results import layout as L
from formula_tourney.results.folder import CorruptResultError
from formula_tourney.results.index import JOB_COLUMNS, read_index, read_meta, rows_of_kind
from formula_tourney.tourney.kinds import BASELINE


@pytest.fixture()
def root(tmp_path: Path) -> Path:
    return build_tournament(tmp_path)


def test_read_index_has_the_layouts_columns(root: Path, tmp_path: Path) -> None:
    problems: list[str] = []
    index = read_index(root, problems)
    assert problems == []
    assert {k: list(v.columns) for k, v in index.items() if k != "jobs"} == {
        k: v for k, v in L.INDEX_TABLES.items() if k != "jobs"}
    jobs = index["jobs"]  # one table: the shared columns, then each kind's attrs and result
    assert list(jobs.columns[:len(JOB_COLUMNS)]) == JOB_COLUMNS
    assert jobs["kind"].value_counts().to_dict() == {"train": 34, "baseline": 9}
    drives = rows_of_kind(jobs, BASELINE.name, BASELINE.columns)
    assert list(drives.columns) == BASELINE.columns and len(drives) == 9
    assert drives.loc[drives["track"] == "flowing", "best_lap_s"].max() == 77.39
    assert index["general_models"]["job_id"].tolist() == ["part3/per1m-rc/seed-1"]
    # a table a foreign index lacks reads as empty, and says so; general_models is optional
    with sqlite3.connect(root / L.INDEX_FILE) as con:
        con.execute("DROP TABLE parts")
        con.execute("DROP TABLE general_models")
    index = read_index(root, problems)
    assert index["parts"].empty and list(index["parts"].columns) == L.INDEX_TABLES["parts"]
    assert problems == [f"{root / L.INDEX_FILE}: table 'parts' missing; read as empty"]
    with pytest.raises(UserInputError, match="not a tournament results folder"):
        read_index(tmp_path / "nowhere")


def test_garbage_index_names_the_file(tmp_path: Path) -> None:
    (tmp_path / L.INDEX_FILE).write_bytes(b"\x00garbage" * 100)
    for reader in (read_index, read_meta, load_tournament):
        with pytest.raises(CorruptResultError, match=f"{tmp_path / L.INDEX_FILE}: not a results"):
            reader(tmp_path)


def test_old_layout_and_corrupt_config_are_problems(root: Path) -> None:
    old = root / "part1" / "win4" / "seed-1" / L.CONFIG_FILE
    old.write_text(json.dumps({"variant": "win4", "train_tracks": ["oval"]}))  # layout 1
    bad = root / "part1" / "win4" / "seed-2" / L.CONFIG_FILE
    bad.write_text("{not json")
    data = load_tournament(root, part="part1")
    problems = "\n".join(data.problems)
    assert "part1/win4/seed-1: written by another version; cannot read" in problems
    assert f"part1/win4/seed-2: {bad}: cannot read the job's config.json" in problems
    # the old folder is not read at all; the corrupt config's tables still are
    assert "part1/win4/seed-1" not in set(data.tests["job_id"])
    assert "part1/win4/seed-2" in set(data.tests["job_id"])
    assert "part1/win4/seed-1" not in data.configs and "part1/win4/seed-0" in data.configs
    assert data.configs["part1/win4/seed-0"]["schedule"]["episodes"] == 300


def test_corrupt_trace_is_a_problem(root: Path) -> None:
    trace = root / "part1" / "win4" / "seed-0" / L.TRACES_DIR / "oval.parquet"
    trace.write_bytes(b"PAR1 truncated")
    data = load_tournament(root, part="part1")
    assert data.read_trace("part1/win4/seed-0", "oval") is None
    assert data.problems[-1].startswith(f"part1/win4/seed-0: {trace}: cannot read")
    assert data.read_trace("part1/win4/seed-0", "flowing") is None  # none written: no problem
    assert len([p for p in data.problems if "oval.parquet" in p]) == 1


def test_selection_rule_comes_from_the_stored_spec(root: Path) -> None:
    spec = {"name": "fixture-cup", "parts": [
        {"name": "part3", "selection": {"kind": "general", "min_unseen_finish_rate": 0.9}},
        {"name": "part1", "selection": {"kind": "best"}},
    ]}
    with sqlite3.connect(root / L.INDEX_FILE) as con:
        con.execute("INSERT INTO meta VALUES ('spec', ?)", (json.dumps(spec),))
    data = load_tournament(root)
    assert data.unseen_finish_rates == {"part3": 0.9}
    assert data.unseen_finish_rate(["part3"]) == 0.9
    assert data.unseen_finish_rate(["part1"]) == DEFAULT_UNSEEN_FINISH_RATE == 0.5
