"""Time to competence: the milestones of a hand-made tests table, the part keys that ask for it,
and one tiny tournament part with a CPU budget whose report shows the table."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.report.build import build_report
from formula_tourney.results import competence as C
from formula_tourney.results.folder import JobFolder
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.spec import parse_spec
from formula_tourney.training.budget import StopRule

NAN = math.nan
BOTS = C.Bots(centre_s=35.4, mincurv_s=34.7, reference_limit_s=33.8)


def _tests(rounds: list[tuple[int, float, list[tuple[float, float]]]],
           track: str = "oval") -> pd.DataFrame:  # fmt: skip
    """A tests table: per round (episode, cpu_s, [(best_lap_s, damage) per start])."""
    rows = []
    for episode, cpu_s, drives in rounds:
        for k, (lap, damage) in enumerate(drives):
            rows.append({"episode": episode, "env_steps": episode * 1000, "track": track,
                         "start_s_m": 100.0 * k, "finished": math.isfinite(lap),
                         "best_lap_s": lap, "laps": int(math.isfinite(lap)), "damage": damage,
                         "reward": 0.0, "steps": 10, "termination": "max_steps",
                         "checkpoint": "", "distance_m": 1.0, "grip_scale": 1.0,
                         "reference_limit_s": NAN, "cpu_s": cpu_s})  # fmt: skip
    return pd.DataFrame(rows)


TABLE = _tests([
    (5, 10.0, [(NAN, 0.0), (NAN, 1.0), (NAN, 0.0)]),       # nothing
    (10, 20.0, [(36.0, 0.0), (NAN, 2.0), (NAN, 0.0)]),     # a lap, damage elsewhere: not clean
    (15, 30.0, [(36.0, 0.0), (35.8, 0.0), (NAN, 0.0)]),    # (a): clean 35.8
    (20, 40.0, [(35.2, 0.0), (35.3, 0.0), (35.1, 0.0)]),   # (b): 35.1 < 35.4
    (25, 50.0, [(34.9, 0.0), (NAN, 0.0), (NAN, 0.0)]),     # clean 34.9, not < 34.7
    (30, 60.5, [(34.6, 0.0), (34.65, 0.0), (34.5, 0.0)]),  # (c): 34.5
])  # fmt: skip


def test_milestones_are_the_first_rounds_below_each_bot_timed_by_their_cpu_s() -> None:
    run = C.run_competence(TABLE, "oval", BOTS)
    assert run["cpu_s"] == {"first_clean_lap": 30.0, "beat_centre_bot": 40.0,
                            "beat_mincurv_bot": 60.5}  # fmt: skip
    assert run["milestones"]["first_clean_lap"] == {"episode": 15, "env_steps": 15000,
                                                    "lap_s": 35.8, "cpu_s": 30.0}  # fmt: skip
    assert run["milestones"]["beat_centre_bot"]["lap_s"] == 35.1
    assert run["best_lap_s"] == 34.5
    assert run["best_lap_to_limit"] == pytest.approx(34.5 / 33.8)
    # rounds 15..30: two of three starts lapped cleanly in 15, 20 and 30, not in 25
    assert run["clean_start_rate"] == 0.75
    assert [c["clean_lap_s"] for c in run["curve"]] == [None, None, 35.8, 35.1, 34.9, 34.5]
    assert [c["cpu_s"] for c in run["curve"]] == [10.0, 20.0, 30.0, 40.0, 50.0, 60.5]


def test_misses_other_tracks_demonstrators_and_untimed_tables() -> None:
    early = TABLE[TABLE["episode"] <= 20]
    other = _tests([(5, 1.0, [(30.0, 0.0)] * 3)], track="technical")
    run = C.run_competence(pd.concat([early, other]), "oval", BOTS)
    assert run["cpu_s"] == {"first_clean_lap": 30.0, "beat_centre_bot": 40.0,
                            "beat_mincurv_bot": None}  # fmt: skip
    # a run with demonstrations must also beat its demonstrator (35.0): 35.1 no longer does
    demo = C.run_competence(TABLE, "oval", BOTS, demo_lap_s=35.0)
    assert demo["cpu_s"]["beat_centre_bot"] == 50.0 and demo["limits_s"]["beat_centre_bot"] == 35.0
    empty = C.run_competence(TABLE.iloc[:0], "oval", BOTS)
    assert empty["cpu_s"] == dict.fromkeys(C.MILESTONES) and empty["clean_start_rate"] is None
    assert C.timed(TABLE) and not C.timed(TABLE.assign(cpu_s=NAN))
    assert not C.timed(TABLE.drop(columns="cpu_s")) and not C.timed(TABLE.iloc[:0])


def test_medians_over_seeds_count_a_miss_as_infinite() -> None:
    runs = [{"cpu_s": dict(zip(C.MILESTONES, cpu, strict=True)), "best_lap_to_limit": ratio,
             "clean_start_rate": rate}
            for cpu, ratio, rate in (((5.0, 40.0, 200.0), 1.01, 1.0),
                                     ((8.0, 50.0, None), 1.03, 0.5),
                                     ((9.0, 70.0, 250.0), 1.015, 1.0),
                                     ((None, None, None), None, None))]  # fmt: skip
    s = C.summarise(runs)
    assert s["seeds"] == 4 and s["reached_first_clean_lap"] == 3
    assert s["median_first_clean_lap_cpu_s"] == 8.5 and s["median_beat_centre_bot_cpu_s"] == 60.0
    assert s["median_beat_mincurv_bot_cpu_s"] == math.inf and s["reached_beat_mincurv_bot"] == 2
    assert s["median_best_lap_to_limit"] == pytest.approx(1.0225)
    assert s["median_clean_start_rate"] == 0.75  # the seed without a clean lap counts 0
    assert C.median_inf([NAN]) == math.inf and C.median_inf([]) == math.inf
    assert s["median_first_clean_lap_env_steps"] == math.inf  # these runs record no steps
    assert s["median_env_steps_per_cpu_s"] is None


def test_medians_of_env_steps_to_each_milestone_and_of_steps_per_cpu_s() -> None:
    """Two machines (or hours of one) buy different steps per CPU-s: the steps to a milestone
    compare runs across them, and the steps per CPU-s say how fast each machine was."""
    run = C.run_competence(TABLE, "oval", BOTS)  # first clean lap at 15 000 env steps
    slow = {**run, "env_steps": 60_000, "cpu_s_total": 60.0}
    fast = {**run, "env_steps": 60_000, "cpu_s_total": 30.0, "milestones": {
        **run["milestones"], "first_clean_lap": {**run["milestones"]["first_clean_lap"],
                                                 "env_steps": 25_000}}}  # fmt: skip
    missed = {**run, "env_steps": 45_000, "cpu_s_total": 45.0,
              "milestones": dict.fromkeys(C.MILESTONES)}  # fmt: skip
    s = C.summarise([slow, fast, missed])
    assert s["median_first_clean_lap_env_steps"] == 25_000.0  # 15k, 25k, inf
    assert s["median_beat_mincurv_bot_env_steps"] == 30_000.0  # 30k, 30k and a miss
    assert s["median_env_steps_per_cpu_s"] == 1000.0  # 1 000, 2 000 and 1 000 steps per CPU-s


def test_the_stop_rule_ends_a_run_at_the_bot_or_the_budget() -> None:
    rule = StopRule(budget_cpu_s=20.0, stop_lap_s=34.7)
    assert rule.reason(34.8, 19.9) is None
    assert rule.reason(34.6, 5.0) == "stop_at" and rule.reason(math.inf, 20.0) == "budget_cpu_s"
    assert rule.with_demonstrator(34.2).stop_lap_s == 34.2
    assert rule.with_demonstrator(35.0).stop_lap_s == 34.7
    assert StopRule().active is False and StopRule().reason(1.0, 1e9) is None


SPEC = """\
name = "tiny"

[defaults]
max_steps = 30
test_every_episodes = 2
device = "cpu"

[variants.WIN1]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}

[[parts]]
name = "cpu"
seeds = 1
entrants = ["WIN1"]
train_tracks = ["oval"]
episodes = 1000000
test_starts = 2
test_max_steps = 250
{keys}
"""
BASELINES = ('baselines = [{bot = "follower", reference = "centre"}, '
             '{bot = "follower", reference = "mincurv"}]')


@pytest.mark.parametrize(("keys", "message"), [
    ('budget_cpu_s = 9\nstop_at = "best"\n' + BASELINES,
     r"t\.toml:\d+: parts\[0\]\.stop_at: Input should be 'none' or 'best-bot'"),
    ("budget_cpu_s = 0\n" + BASELINES,
     r"t\.toml:\d+: parts\[0\]\.budget_cpu_s: Input should be greater than 0 \(CPU-second "
     r"budget"),
    ('stop_at = "best-bot"\n' + BASELINES,
     r"t\.toml:\d+: parts\[0\]\.stop_at: stop_at = 'best-bot' needs budget_cpu_s"),
    ('budget_cpu_s = 9\nbaselines = [{bot = "follower", reference = "centre"}]',
     r"t\.toml:\d+: parts\[0\]\.budget_cpu_s: a CPU budget times the runs until they beat the "
     r"follower on the centre and mincurv lines: add baselines = \[\{bot = \"follower\", "
     r"reference = \"mincurv\"\}\] to part 'cpu'"),
])  # fmt: skip
def test_competence_part_keys_are_checked_with_their_line(keys: str, message: str) -> None:
    with pytest.raises(UserInputError, match=message):
        parse_spec(SPEC.format(keys=keys), Path("t.toml"))


def test_a_part_with_a_cpu_budget_runs_to_it_and_reports_its_time_to_competence(
    tmp_path: Path,
) -> None:
    """One tiny run with a 3 CPU-s budget: the loop stops it there (no lap ends it: a 30-step
    episode never laps), every test round is timed, and the report's table shows the misses,
    with the bots the part's baselines drove."""
    path = tmp_path / "t.toml"
    path.write_text(SPEC.format(keys='budget_cpu_s = 3\nstop_at = "best-bot"\n' + BASELINES),
                    encoding="utf-8")
    run_tournament(path, workers=1, results_dir=tmp_path / "res")
    root = tmp_path / "res" / "tiny"
    folder = JobFolder(root / "cpu" / "WIN1-MOT" / "seed-0")
    summary = folder.summary()
    assert summary["stopped_by"] == "budget_cpu_s" and 3.0 <= summary["cpu_s"] < 10.0
    cpu = folder.tests().groupby("episode")["cpu_s"].max()
    assert cpu.is_monotonic_increasing and cpu.notna().all() and cpu.iloc[-1] <= summary["cpu_s"]

    report = build_report("tiny", tmp_path / "res")
    tables = {t.key: t for t in report.tables}
    table = tables["competence"]
    record = table.records[0]
    assert table.groups == ["cpu: oval MOT"] and record["row"] == "WIN1"
    assert record["summary"]["seeds"] == 1 and record["budget_cpu_s"] == 3.0
    baselines = report.data.baselines.set_index("reference")["best_lap_s"]
    assert record["bots"]["centre_s"] == baselines["centre"]
    assert record["bots"]["mincurv_s"] == baselines["mincurv"]
    assert record["runs"][0]["cpu_s_total"] == summary["cpu_s"]
    row = table.rows[0]
    assert row["text"][("cpu: oval MOT", "clean lap")] == "miss (0/1)"
    assert row["text"][("cpu: oval MOT", "best/limit")] == "-"
    assert any("budget 3 CPU-s, stop_at best-bot" in n for n in table.notes)
