"""The report's cost table: the stored estimate beside the measured cost, by hand."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from formula_tourney.report.cost import cost_table, measured
from formula_tourney.report.load import TournamentData
from formula_tourney.results.layout import ESTIMATE_FILE


def data_with(root, jobs: pd.DataFrame) -> TournamentData:
    empty = pd.DataFrame()
    parts = pd.DataFrame({"part": ["p1", "p2"], "position": [0, 1]})
    return TournamentData(root=root, name="t", jobs=jobs, parts=parts, baselines=empty,
                          tests=empty, episodes=empty, laps=empty)  # fmt: skip


JOBS = pd.DataFrame({
    "part": ["p1", "p1", "p2"],
    "wall_s": [100.0, 120.0, 60.0],
    "train_seconds": [90.0, 110.0, 50.0],
    "started_at": ["2026-12-01T10:00:00Z", "2026-12-01T10:00:00Z", "2026-12-01T10:02:00Z"],
    "finished_at": ["2026-12-01T10:01:40Z", "2026-12-01T10:02:00Z", "2026-12-01T10:03:00Z"],
})  # fmt: skip


def test_measured_sums_job_seconds_and_spans_the_wall() -> None:
    m = measured(JOBS)
    assert m == {"jobs": 3.0, "cpu_s": 280.0, "train_s": 250.0, "wall_s": 180.0}


def test_cost_table_sets_the_estimate_beside_the_measurement(tmp_path) -> None:
    est = {"parts": [{"part": "p1", "jobs": 2, "cpu_s": 200.0, "cpu_s_low": 180.0,
                      "cpu_s_high": 230.0},
                     {"part": "p2", "jobs": 1, "cpu_s": 80.0, "cpu_s_low": 70.0,
                      "cpu_s_high": 90.0}],
           "total": {"jobs": 3, "cpu_s": 280.0, "cpu_s_low": 250.0, "cpu_s_high": 320.0,
                     "wall_s": 150.0}}  # fmt: skip
    (tmp_path / ESTIMATE_FILE).write_text(json.dumps(est))
    table = cost_table(data_with(tmp_path, JOBS))
    rows = {r["part"]: r for r in table.records}
    assert rows["p1"]["measured"]["cpu_s"] == pytest.approx(220.0)
    text = {row["label"]: row["text"] for row in table.rows}
    # 220 against 200 estimated: +10 %; p2 60 against 80: -25 %; total 280 against 280: +0 %
    assert text["p1"][("cost", "CPU measured")] == "220.0 s (+10%)"
    assert text["p2"][("cost", "CPU measured")] == "60.0 s (-25%)"
    assert text["total"][("cost", "CPU measured")] == "280.0 s (+0%)"
    assert text["total"][("cost", "CPU ~95%")] == "250.0-320.0 s"
    assert text["total"][("cost", "wall measured")] == "180.0 s"
    assert text["p1"][("cost", "jobs")] == "2 (est. 2)"
    assert not table.notes


def test_cost_table_without_an_estimate_says_how_to_get_one(tmp_path) -> None:
    table = cost_table(data_with(tmp_path, JOBS))
    assert any("--estimate" in note for note in table.notes)
    text = {row["label"]: row["text"] for row in table.rows}
    assert text["total"][("cost", "CPU measured")] == "280.0 s"


def test_a_corrupt_estimate_is_a_problem_line_naming_the_file(tmp_path) -> None:
    (tmp_path / ESTIMATE_FILE).write_text("{not json")
    data = data_with(tmp_path, JOBS)
    cost_table(data)
    assert any(ESTIMATE_FILE in p for p in data.problems)
