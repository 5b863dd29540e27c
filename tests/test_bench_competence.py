"""benchmarks/time_to_competence.py's pure functions: milestones from a tests table, the
clean-start rate, medians with misses as infinity and the goal flags. No training."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from simtracks import stadium

from formula_tourney.sim import kernels as K
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.training.evaluate import run_test_episode

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "time_to_competence.py"
_SPEC = importlib.util.spec_from_file_location("time_to_competence", _PATH)
ttc = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(ttc)

NAN = math.nan


def _tests(
    rounds: list[tuple[int, list[tuple[float, float]]]], track: str = "oval"
) -> pd.DataFrame:
    """A tests table: per round (episode, [(best_lap_s, damage) per start])."""
    rows = []
    for episode, drives in rounds:
        for k, (lap, damage) in enumerate(drives):
            rows.append({"episode": episode, "env_steps": episode * 1000, "track": track,
                         "start_s_m": 100.0 * k, "finished": math.isfinite(lap),
                         "best_lap_s": lap, "laps": int(math.isfinite(lap)), "damage": damage,
                         "reward": 0.0, "steps": 10, "termination": "max_steps",
                         "checkpoint": "", "distance_m": 1.0})  # fmt: skip
    return pd.DataFrame(rows)


# centre bot 35.4 s, mincurv bot 34.7 s
TABLE = _tests([
    (5, [(NAN, 0.0), (NAN, 1.0), (NAN, 0.0)]),       # nothing
    (10, [(36.0, 0.0), (NAN, 2.0), (NAN, 0.0)]),     # a lap, but damage elsewhere: not clean
    (15, [(36.0, 0.0), (35.8, 0.0), (NAN, 0.0)]),    # (a): clean 35.8
    (20, [(35.2, 0.0), (35.3, 0.0), (35.1, 0.0)]),   # (b): 35.1 < 35.4
    (25, [(34.9, 0.0), (NAN, 0.0), (NAN, 0.0)]),     # clean 34.9, not < 34.7
    (30, [(34.6, 0.0), (34.65, 0.0), (34.5, 0.0)]),  # (c): 34.5
])  # fmt: skip
CPU = {5: 10.0, 10: 20.0, 15: 30.0, 20: 40.0, 25: 50.0, 30: 60.0}


def test_milestones_first_round_below_each_limit() -> None:
    limits = ttc.thresholds(35.4, 34.7)
    hits = ttc.milestones(TABLE, "oval", limits, CPU, cpu_total=99.0)
    assert hits["first_clean_lap"] == {"episode": 15, "env_steps": 15000, "lap_s": 35.8,
                                       "cpu_s": 30.0}  # fmt: skip
    assert hits["beat_centre_bot"]["episode"] == 20 and hits["beat_centre_bot"]["cpu_s"] == 40.0
    assert hits["beat_mincurv_bot"]["episode"] == 30
    assert hits["beat_mincurv_bot"]["lap_s"] == pytest.approx(34.5)
    assert ttc.best_clean_lap(TABLE, "oval") == pytest.approx(34.5)


def test_milestones_missed_and_other_tracks_ignored() -> None:
    early = TABLE[TABLE["episode"] <= 20]
    other = _tests([(5, [(30.0, 0.0)] * 3)], track="technical")
    hits = ttc.milestones(pd.concat([early, other]), "oval", ttc.thresholds(35.4, 34.7), CPU, 0.0)
    assert hits["beat_centre_bot"]["episode"] == 20 and hits["beat_mincurv_bot"] is None
    empty = ttc.milestones(TABLE.iloc[:0], "oval", ttc.thresholds(35.4, 34.7), {}, 0.0)
    assert empty == dict.fromkeys(ttc.MILESTONES)
    assert math.isnan(ttc.best_clean_lap(TABLE.iloc[:0], "oval"))


def test_round_without_cpu_reading_takes_the_total() -> None:
    hits = ttc.milestones(TABLE, "oval", ttc.thresholds(35.4, 34.7), {15: 30.0}, cpu_total=77.0)
    assert hits["first_clean_lap"]["cpu_s"] == 30.0
    assert hits["beat_mincurv_bot"]["cpu_s"] == 77.0


def test_demonstrator_lap_tightens_the_bot_milestones() -> None:
    limits = ttc.thresholds(35.4, 34.7, demo_lap_s=35.0)
    assert limits == {"first_clean_lap": math.inf, "beat_centre_bot": 35.0,
                      "beat_mincurv_bot": 34.7}  # fmt: skip
    hits = ttc.milestones(TABLE, "oval", limits, CPU, 0.0)
    assert hits["beat_centre_bot"]["episode"] == 25  # 35.1 at round 20 beats the bot, not the demo
    assert ttc.thresholds(35.4, 34.7, None) == ttc.thresholds(35.4, 34.7, NAN)


def test_a_run_stops_at_the_best_bot_unless_it_trains_to_the_budget() -> None:
    task = {"bots": {"centre_s": 35.4, "mincurv_s": 34.7}}
    assert ttc.stop_lap_s(task) == 34.7
    assert ttc.stop_lap_s(task, demo_lap_s=34.2) == 34.2  # with demos: past the demonstrator
    assert ttc.stop_lap_s({**task, "to_budget": True}) == -math.inf  # no lap ends it


def test_clean_start_rate_from_the_first_clean_lap_on() -> None:
    # rounds 15..30: >= 2 clean starts in 15, 20, 30; not in 25 -> 3/4
    assert ttc.clean_start_rate(TABLE, "oval", 15) == pytest.approx(0.75)
    assert ttc.clean_start_rate(TABLE, "oval", 30) == 1.0
    assert ttc.clean_start_rate(TABLE, "oval", None) is None
    assert ttc.clean_start_rate(TABLE, "oval", 35) is None


def test_medians_count_misses_as_infinite() -> None:
    assert ttc.median_inf([10.0, None, 30.0]) == 30.0
    assert ttc.median_inf([10.0, 20.0, None, None]) == math.inf
    assert ttc.median_inf([10.0, 20.0, 40.0, None]) == 30.0
    assert ttc.median_inf([NAN]) == math.inf and ttc.median_inf([]) == math.inf
    assert ttc.finite(math.inf) is None and ttc.finite(12.34) == 12.3
    assert ttc.ratio(30.0, 60.0) == 0.5
    assert ttc.ratio(30.0, math.inf) == 0.0 and ttc.ratio(math.inf, 60.0) is None


def _run(a: float | None, b: float | None, c: float | None, best: float | None,
         rate: float | None) -> dict:  # fmt: skip
    return {"cpu_s": dict(zip(ttc.MILESTONES, (a, b, c), strict=True)),
            "best_lap_to_limit": best, "clean_start_rate": rate}  # fmt: skip


def test_summary_and_goal_flags() -> None:
    runs = [_run(5.0, 40.0, 200.0, 1.01, 1.0), _run(8.0, 50.0, None, 1.03, 0.5),
            _run(9.0, 70.0, 250.0, 1.015, 1.0), _run(None, None, None, None, None)]  # fmt: skip
    s = ttc.summarise(runs)
    assert s["median_first_clean_lap_cpu_s"] == 8.5 and s["reached_first_clean_lap"] == 3
    assert s["median_beat_centre_bot_cpu_s"] == 60.0
    assert s["median_beat_mincurv_bot_cpu_s"] == math.inf and s["reached_beat_mincurv_bot"] == 2
    assert s["median_best_lap_to_limit"] == pytest.approx(1.0225)
    assert s["median_clean_start_rate"] == 0.75  # the seed without a clean lap counts 0
    ratios = {"first_clean_lap": 0.2, "beat_centre_bot": 0.6, "beat_mincurv_bot": None}
    oval = ttc.goal_flags("oval", s, ratios)
    assert oval == {"beat_centre_bot_cpu_s": True, "beat_mincurv_bot_cpu_s": False,
                    "best_lap_to_limit": False, "ratio_first_clean_lap": True,
                    "ratio_beat_centre_bot": False, "ratio_beat_mincurv_bot": False}  # fmt: skip
    tech = ttc.goal_flags("technical", s, None)
    assert tech == {"first_clean_lap_cpu_s": True, "beat_mincurv_bot_cpu_s": False,
                    "best_lap_to_limit": True}  # fmt: skip
    assert ttc.goal_flags("gen-5", s, None) is None


def test_parse_entrants() -> None:
    assert ttc.parse_entrants("WIN1:best, SAC:best,") == [("WIN1", "best"), ("SAC", "best")]
    for bad in ("WIN1", "WIN1:best,WIN1:best", "", ":best"):
        with pytest.raises(SystemExit):
            ttc.parse_entrants(bad)
    assert ttc.parse_overrides(["batch_size=32", "algorithm=sac"]) == {
        "batch_size": 32, "algorithm": "sac"}  # fmt: skip


def test_learning_curve_lists_every_round_with_its_clean_lap() -> None:
    curve = ttc.learning_curve(TABLE, "oval", CPU, cpu_total=99.0)
    assert [c["episode"] for c in curve] == [5, 10, 15, 20, 25, 30]
    assert [c["clean_lap_s"] for c in curve] == [None, None, 35.8, 35.1, 34.9, 34.5]
    assert [c["cpu_s"] for c in curve] == [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    late = ttc.learning_curve(TABLE, "oval", {5: 10.0}, cpu_total=99.0)
    assert [c["cpu_s"] for c in late] == [10.0, 99.0, 99.0, 99.0, 99.0, 99.0]


NO_LAP = {"episode": 5, "cpu_s": 1.0, "clean_lap_s": None}


def test_plot_curves_writes_a_png_and_a_pdf(tmp_path) -> None:
    curve = ttc.learning_curve(TABLE, "oval", CPU, cpu_total=99.0)
    result = {"track": "oval", "reference": "centre", "lac": False, "seeds": [0],
              "bots": {"centre_s": 35.4, "mincurv_s": 34.7, "reference_limit_s": 33.8},
              "entrants": [{"label": "WIN1:tuned", "runs": [{"curve": curve}]}],
              "sb3": {"label": "SB3 SAC", "runs": [{"curve": [NO_LAP]}]}}  # fmt: skip
    paths = ttc.plot_curves(result, tmp_path / "curves")
    assert sorted(p.name for p in paths) == ["curves.pdf", "curves.png"]
    assert (tmp_path / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_failed_run_is_summarised_and_plotted_as_a_run_that_reached_nothing(tmp_path) -> None:
    """A seed whose worker raised keeps the others: its record counts as misses in the medians
    and draws nothing (it once stopped the plot, and with it the benchmark's JSON line)."""
    failed = ttc.run_job({"kind": "ours", "label": "WIN1:tuned", "seed": 3, "spec": {}})
    assert failed["error"].startswith("UserInputError") and failed["curve"] == []
    assert ttc.summarise([failed])["reached_first_clean_lap"] == 0
    curve = ttc.learning_curve(TABLE, "oval", CPU, cpu_total=99.0)
    result = {"track": "oval", "reference": "centre", "lac": False, "seeds": [0, 3],
              "bots": {"centre_s": 35.4, "mincurv_s": 34.7, "reference_limit_s": 33.8},
              "entrants": [{"label": "WIN1:tuned", "runs": [{"curve": curve}, failed]}],
              "sb3": None}  # fmt: skip
    assert [p.name for p in ttc.plot_curves(result, tmp_path / "c")] == ["c.png", "c.pdf"]


class _Follower:
    """A line follower on the telemetry behind SB3's ``predict``: what the anchor's adapter
    hands the test drive."""

    def predict(self, obs, deterministic: bool = True):  # noqa: ANN001, ANN201
        assert deterministic
        angle = obs[K.OBS_ANGLE] * math.pi
        steer = np.clip(-2.0 * angle - 0.6 * obs[K.OBS_TRACKPOS], -1, 1)
        err = 24.0 - obs[K.OBS_VX] * K.SPEED_SCALE_MPS
        return np.array([steer, np.clip(0.3 * err, 0, 1), np.clip(-0.2 * err, 0, 1)],
                        np.float32), None


def test_the_sb3_adapter_drives_the_tests_as_our_agents_do() -> None:
    """The anchor is tested by the same ``run_test_episode`` as our agents, which drives
    ``act_eval``: the adapter must offer it (it did not, and every SB3 seed failed)."""
    env = FormulaRacingEnv(config={"track": stadium(), "max_steps": 400})
    drive = run_test_episode(ttc._Greedy(_Follower()), env, "stadium", 1250.0, seed=0)
    assert drive.laps >= 1 and drive.damage == 0.0
    assert 55.0 < drive.best_lap_s < 60.0  # 1 302.65 m at ~24 m/s
