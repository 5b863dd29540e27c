"""benchmarks/general_driver.py: a run read at a shorter budget is the run as it stood then, the
general model is the report's, and a lap counts near the limit only within the margin."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pandas as pd
import pytest
from report_fixtures import build_generated_tournament

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "general_driver.py"
_SPEC = importlib.util.spec_from_file_location("general_driver", _PATH)
gd = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(gd)

LIMITS = {"oval": 33.8, "technical": 66.3, "flowing": 98.3}
TRACKS = list(LIMITS)


def _tests() -> pd.DataFrame:
    """Two test rounds of one run trained on generated tracks: at 100 CPU-s a model that laps
    the oval near the limit; at 500 CPU-s one that laps all three, the oval slowly."""
    rows = []
    for episode, cpu_s, laps in ((40, 100.0, {"oval": 35.0}),
                                 (80, 500.0, {"oval": 44.0, "technical": 80.0,
                                              "flowing": 110.0})):
        for track in TRACKS:
            lap = laps.get(track, math.nan)
            rows.append({"job_id": "j", "episode": episode, "track": track, "best_lap_s": lap,
                         "damage": 0.0, "finished": math.isfinite(lap), "cpu_s": cpu_s,
                         "checkpoint": f"checkpoints/ep-{episode}.pt", "distance_m": 1.0})
    return pd.DataFrame(rows)


def test_a_run_read_at_a_shorter_budget_keeps_only_the_models_tested_by_then() -> None:
    early = gd.run_at_budget(_tests(), "gen-0", TRACKS, 0.5, LIMITS, 300.0, 1.15)
    assert (early["episode"], early["lapped"], early["within"]) == (40, 1, 1)
    assert math.isnan(early["fastest_s"]["flowing"])
    late = gd.run_at_budget(_tests(), "gen-0", TRACKS, 0.5, LIMITS, 900.0, 1.15)
    # the report's rule: the most unseen tracks lapped wins, however slowly
    assert (late["episode"], late["lapped"]) == (80, 3)
    assert late["ratios"]["oval"] == 44.0 / 33.8
    assert late["within"] == 1  # flowing 110 / 98.3 = 1.119; oval 1.30 and technical 1.21 miss
    assert late["fastest_s"]["oval"] == 35.0  # the fastest clean lap of any checkpoint


def test_a_run_without_a_clean_lap_counts_zero_and_the_line_is_strict_json() -> None:
    tests = _tests().assign(damage=1.0)
    fig = gd.run_at_budget(tests, "gen-0", TRACKS, 0.5, LIMITS, 900.0, 1.15)
    assert (fig["episode"], fig["lapped"], fig["within"]) == (None, 0, 0)
    line = json.dumps(gd.finite_or_none({"a": [math.nan, 1.0], "b": math.inf}))
    assert json.loads(line) == {"a": [None, 1.0], "b": None}


def test_the_benchmark_reads_a_tournament_as_the_report_does(tmp_path: Path, capsys,
                                                             monkeypatch) -> None:
    root = build_generated_tournament(tmp_path)
    monkeypatch.setattr("sys.argv", ["general_driver.py", str(root)])
    gd.main()
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (whole,) = out["budgets"]
    # seed 0 laps the oval and flowing from episode 200 on, fastest at 300; seed 1 never laps
    assert [(r["seed"], r["episode"], r["lapped"]) for r in whole["runs"]] == [
        (0, 300, 2), (1, None, 0)]
    assert whole["median_lapped"] == 1.0
    assert [r["env_steps_at_last_test"] for r in whole["runs"]] == [45000, 45000]  # episode 300
    assert whole["fastest_any"]["flowing"]["lap_s"] == 79.0
    assert whole["fastest_any"]["technical"]["runs_lapping"] == 0
    assert whole["goal_met"] is False  # no baselines here: no limit, so no lap counts near it


def test_a_missing_tournament_is_a_one_line_error(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.setattr("sys.argv", ["general_driver.py", str(tmp_path / "nothing")])
    with pytest.raises(SystemExit) as exc:
        gd.main()
    assert exc.value.code == 2
    assert capsys.readouterr().err.startswith("error: ")
