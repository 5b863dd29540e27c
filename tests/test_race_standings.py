"""A series' standings from scripted races against a hand computation; the series' grids; files."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from formula_tourney.race.series import rotated_grid
from formula_tourney.report.race_standings import markdown, standings
from formula_tourney.results.folder import RaceFolder


def _row(name, position, status="finished", contacts=0, caused=0, damage=0.0, kind="model",
         sees=True):
    return {"name": name, "position": position, "status": status, "contacts": contacts,
            "caused": caused, "damage": damage, "kind": kind, "sees_opponents": sees}


RACES = [
    {"results": [_row("A", 1), _row("B", 2), _row("C", 3, contacts=1, damage=50.0)]},
    {"results": [_row("B", 1, contacts=1, damage=20.0), _row("A", 2),
                 _row("C", 3, status="retired", contacts=1, caused=1, damage=6000.0)]},
    {"results": [_row("A", 1), _row("C", 2), _row("B", 3, kind="bot", sees=False)]},
]


def test_standings_of_scripted_races_equal_the_hand_computation():
    table = standings(RACES)
    rows = {r["name"]: r for r in table["rows"]}
    assert [r["name"] for r in table["rows"]] == ["A", "B", "C"]
    # Points 25-18-15: A 25 + 18 + 25, B 18 + 25 + 15, C 15 + 0 (retired) + 18.
    assert [rows[n]["points"] for n in "ABC"] == [68.0, 58.0, 33.0]
    assert [rows[n]["wins"] for n in "ABC"] == [2, 1, 0]
    assert rows["A"]["mean_position"] == pytest.approx(4 / 3)
    assert rows["B"]["mean_position"] == pytest.approx(2.0)
    assert rows["C"]["mean_position"] == pytest.approx(8 / 3)
    assert 1.0 <= rows["A"]["position_low"] <= 4 / 3 <= rows["A"]["position_high"] <= 2.0
    ahead = table["ahead"]
    assert ahead["A"]["B"] == pytest.approx(2 / 3) and ahead["B"]["A"] == pytest.approx(1 / 3)
    assert ahead["A"]["C"] == 1.0 and ahead["C"]["B"] == pytest.approx(1 / 3)
    # Clean: finished, no contact, no damage.
    assert [rows[n]["clean_rate"] for n in "ABC"] == pytest.approx([1.0, 2 / 3, 1 / 3])
    assert [rows[n]["contacts_per_race"] for n in "ABC"] == pytest.approx([0.0, 1 / 3, 2 / 3])
    assert rows["C"]["caused_per_race"] == pytest.approx(1 / 3) and rows["C"]["dnf"] == 1
    assert "| 1 | A | 68 | 2 |" in markdown(table)


def test_configurable_points():
    rows = {r["name"]: r for r in standings(RACES, points=[10, 5])["rows"]}
    assert [rows[n]["points"] for n in "ABC"] == [25.0, 15.0, 5.0]


def test_rotated_grids_start_everyone_from_every_slot():
    base = [2, 0, 1]
    grids = [rotated_grid(base, k) for k in range(3)]
    assert grids == [[2, 0, 1], [0, 1, 2], [1, 2, 0]]
    for car in range(3):
        assert sorted(g.index(car) for g in grids) == [0, 1, 2]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "formula_tourney.cli", "race", *args],
                          capture_output=True, text=True, timeout=600)


def test_cli_series_writes_the_races_folder(tmp_path):
    out = tmp_path / "series"
    done = _cli("--bots", "follower,follower", "--track", "oval", "--laps", "1", "--races", "2",
                "--points", "10,6", "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)
    assert doc["standings"]["races"] == 2 and len(doc["races"]) == 2
    folder = RaceFolder(out)
    assert folder.is_finished() and len(folder.races()) == 2
    assert folder.series()["races"] == 2
    # The folder's standings are the printed ones, recomputed from the files.
    assert standings(folder.races(), [10, 6]) == doc["standings"]
    assert (folder.figures_path / "race-1-positions.png").is_file()
    grids = [{r["name"]: r["grid"] for r in race["results"]} for race in folder.races()]
    assert grids[0]["follower"] != grids[1]["follower"]  # rotated


def test_cli_series_bad_input(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    for args, text in ((["--races", "0"], "--races"), (["--points", "a,b"], "--points"),
                       (["--out", str(tmp_path / "full")], "--out")):
        done = _cli("--bots", "follower", "--track", "oval", "--laps", "1", *args)
        assert done.returncode == 2 and text in done.stderr, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full"]
