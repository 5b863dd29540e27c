"""Race parts in a tournament: `run` races them through the scheduler, resumes per race file,
and the report shows the standings race_standings computes from the same files."""

from __future__ import annotations

import json
import sqlite3

import pytest
from rich.console import Console
from tourney_fixtures import TINY

from formula_tourney.commands.tourney_view import render_results
from formula_tourney.errors import UserInputError
from formula_tourney.report.build import build_report
from formula_tourney.report.race_standings import standings
from formula_tourney.results.folder import RaceFolder
from formula_tourney.tourney import race_worker
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.spec import load_spec
from formula_tourney.tourney.store import Store

RACE_PART = """
[[parts]]
name = "final"
kind = "race"
promoted_from = "p1"
promotion = {{ best_per_family = false, unfinished = "by_distance" }}
train_tracks = ["oval"]
race = {{ races = 2, laps = 1, bots = ["follower"], lap_limit_s = 40.0, points = [10, 6, 4] }}
"""
NAMES = ["MS2-MOT", "WIN1-MOT", "follower"]


def _file(tmp_path, p2=RACE_PART):
    path = tmp_path / "t.toml"
    path.write_text(TINY.format(entrants='["WIN1", "MS2"]', p2=p2.format()), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def raced(tmp_path_factory):
    """The tiny tournament run once: p1 trains two entrants, `final` races them and a bot."""
    tmp = tmp_path_factory.mktemp("race_part")
    path, res = _file(tmp), tmp / "res"
    result = run_tournament(path, workers=1, results_dir=res)
    return path, res, result


def _texts(folder: RaceFolder) -> dict[int, str]:
    return {k: (folder.path / f"race-{k}.json").read_text() for k in folder.race_numbers()}


def test_run_races_the_race_part_after_its_source_promotes(raced):
    _path, res, result = raced
    store = Store(res / "tiny")
    assert store.part("final")["status"] == "done"
    row = store.job("final/_races")
    assert row["status"] == "done" and row["attempts"] == 1 and row["races"] == 2
    assert sorted(row["entrants"]) == NAMES
    final = next(p for p in result["parts"] if p["part"] == "final")
    assert final["race"]["raced"] == 2 and final["race"]["status"] == "done"
    assert result["failures"] == [] and result["this_run"]["done"] == 3  # 2 trainings + series
    folder = RaceFolder(res / "tiny" / "final" / "_races")
    series = folder.series()
    assert sorted(e["name"] for e in series["entrants"]) == NAMES
    for e in series["entrants"]:
        if e.get("kind") != "bot":
            assert e["checkpoint"].startswith(e["job_id"] + "/checkpoints/")
    races = folder.races()
    assert len(races) == 2 and {len(r["results"]) for r in races} == {3}
    grids = [{r["name"]: r["grid"] for r in race["results"]} for race in races]
    assert all(grids[0][n] != grids[1][n] for n in NAMES)  # rotated by one slot
    table = standings(races, series["points"])
    assert sum(r["points"] for r in table["rows"]) <= 2 * (10 + 6 + 4)
    console = Console(record=True, width=200)
    render_results(console, result)
    assert "final (main, race): done; series done, 2/2 races" in console.export_text()


def test_a_deleted_race_file_is_raced_again_to_the_same_standings(raced):
    path, res, _ = raced
    folder = RaceFolder(res / "tiny" / "final" / "_races")
    before, texts = standings(folder.races(), [10, 6, 4]), _texts(folder)
    kept_ns = (folder.path / "race-0.json").stat().st_mtime_ns
    (folder.path / "race-1.json").unlink()
    again = run_tournament(path, workers=1, results_dir=res)
    assert (folder.path / "race-0.json").stat().st_mtime_ns == kept_ns  # not raced again
    assert again["this_run"]["done"] == 1 and again["this_run"]["skipped"] >= 2
    assert _texts(folder) == texts  # race 0 kept as it was, race 1 raced again identically
    assert standings(folder.races(), [10, 6, 4]) == before
    assert Store(res / "tiny").job("final/_races")["attempts"] == 2
    # Nothing missing: a further run races nothing.
    assert run_tournament(path, workers=1, results_dir=res)["this_run"]["done"] == 0


def test_an_index_without_the_series_row_recovers_it_from_the_files(raced):
    path, res, _ = raced
    with sqlite3.connect(res / "tiny" / "index.sqlite") as db:  # an older run closed it at once
        db.execute("DELETE FROM jobs WHERE kind='race'")
    again = run_tournament(path, workers=1, results_dir=res)
    assert again["this_run"]["done"] == 0 and again["this_run"]["recovered"] == 1
    assert Store(res / "tiny").job("final/_races")["status"] == "done"


def test_other_race_settings_on_resume_are_refused_before_anything_runs(raced, tmp_path):
    path, res, _ = raced
    changed = tmp_path / "t.toml"
    changed.write_text(path.read_text().replace("laps = 1,", "laps = 2,"), encoding="utf-8")
    mtime = (res / "tiny" / "final" / "_races" / "series.json").stat().st_mtime_ns
    with pytest.raises(UserInputError, match="final/_races already raced"):
        run_tournament(changed, workers=1, results_dir=res)
    assert (res / "tiny" / "final" / "_races" / "series.json").stat().st_mtime_ns == mtime


def test_one_crashing_race_keeps_the_others_and_a_retry_races_only_it(raced, tmp_path,
                                                                     monkeypatch):
    _path, res, _ = raced
    series = RaceFolder(res / "tiny" / "final" / "_races").series()
    spec = {k: series[k] for k in ("part", "track", "races", "seed", "points", "settings")}
    spec.update(races=3, models=[e for e in series["entrants"] if e.get("kind") != "bot"],
                bots=[{"bot": "follower", "name": "follower"}])
    job = Job(job_id="final/_races", kind="race", part="final", out_dir=str(tmp_path / "r"),
              spec=spec, config_hash="h1", meta={"root": str(res / "tiny")})
    real = race_worker.race_k

    def flaky(entrants, settings, base, qualifying, seed, k):
        if k == 1:
            raise RuntimeError("boom")
        return real(entrants, settings, base, qualifying, seed, k)

    monkeypatch.setattr(race_worker, "race_k", flaky)
    with pytest.raises(race_worker.RaceSeriesError, match="1 of 3 races failed .race 1: "
                       "RuntimeError: boom"):
        race_worker.run_race_job(job)
    folder = RaceFolder(job.out_dir)
    assert folder.race_numbers() == [0, 2] and not folder.is_finished()
    kept = _texts(folder)
    raced_now = []
    monkeypatch.setattr(race_worker, "race_k", lambda *a: raced_now.append(a[-1]) or real(*a))
    race_worker.run_race_job(job)
    assert raced_now == [1] and folder.is_complete(3)
    assert {k: v for k, v in _texts(folder).items() if k != 1} == kept
    # Another series (other hash) in the same folder starts afresh.
    other = Job(**{**job.__dict__, "config_hash": "h2",
                   "spec": {**spec, "races": 1}})
    raced_now.clear()
    race_worker.run_race_job(other)
    assert raced_now == [0] and folder.race_numbers() == [0]
    assert folder.series()["config_hash"] == "h2" and folder.qualifying()["config_hash"] == "h2"


def test_the_report_shows_the_race_table_race_standings_computes(raced, tmp_path):
    _path, res, _ = raced
    folder = RaceFolder(res / "tiny" / "final" / "_races")
    expected = standings(folder.races(), folder.series()["points"])
    report = build_report("tiny", res, out_dir=tmp_path / "rep",
                          formats=("markdown", "latex", "html"))
    doc = json.loads(json.dumps(report.to_json()))
    table = doc["tables"]["races-final"]
    rows = [{k: v for k, v in r.items() if k != "group"} for r in table["records"]
            if r["group"] == "standings"]
    assert rows == json.loads(json.dumps(expected["rows"]))
    ahead = {r["name"]: r["ahead"] for r in table["records"] if r["group"] != "standings"}
    assert ahead == json.loads(json.dumps(expected["ahead"]))
    by_label = {r["label"].replace(" (blind)", ""): r for r in table["rows"]}
    for r in expected["rows"]:
        cells = by_label[r["name"]]["cells"]
        assert cells["standings | points"] == r["points"]
        assert cells["standings | contacts/race"] == r["contacts_per_race"]
        assert cells["standings | clean"] == r["clean_rate"]
    assert "Race part final: 2 races on oval" in report.markdown
    assert "contacts/race" in (tmp_path / "rep" / "report.html").read_text()
    assert (tmp_path / "rep" / "races-final.tex").is_file()
    for k in (0, 1):
        for kind in ("positions", "gaps"):
            assert {p.suffix for p in report.figures[f"final-race-{k}-{kind}"]} == {".png",
                                                                                   ".pdf"}


def test_dry_run_shows_the_race_part(tmp_path):
    out = run_tournament(_file(tmp_path), dry_run=True, results_dir=tmp_path / "res")
    final = out["plan"]["parts"][1]
    assert (final["kind"], final["races"], final["race_laps"], final["race_bots"]) == (
        "race", 2, 1, ["follower"])
    console = Console(record=True, width=200)
    render_results(console, out)
    text = console.export_text()
    assert "2 races x 1 laps of oval; standing start, grid by qualifying" in text
    assert "points 10-6-4" in text and "+ bots follower" in text
    assert "jobs per promoted variant" not in text.split("final")[1]
    assert not (tmp_path / "res").exists()


@pytest.mark.parametrize("p2, text", [
    ('\n[[parts]]\nname = "final"\nkind = "race"\nentrants = ["WIN1"]\n'
     'train_tracks = ["oval"]\n', "promoted_from"),
    ('\n[[parts]]\nname = "p2"\npromoted_from = "p1"\ntrain_tracks = ["oval"]\n'
     'race = {{ races = 2 }}\n', "kind"),
    ('\n[[parts]]\nname = "final"\nkind = "race"\npromoted_from = "p1"\n'
     'train_tracks = ["oval"]\nrace = {{ races = 0 }}\n', "races"),
    ('\n[[parts]]\nname = "final"\nkind = "race"\npromoted_from = "p1"\n'
     'train_tracks = ["oval"]\nrace = {{ laps = 2, points = [-1] }}\n', "points"),
])
def test_race_part_settings_are_checked(tmp_path, p2, text):
    with pytest.raises(UserInputError, match=text):
        load_spec(_file(tmp_path, p2))
