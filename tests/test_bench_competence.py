"""benchmarks/time_to_competence.py: its tournament (validated by the product, the anchors as
outside entrants), the stop rule, the goal flags, the goals table and ratios, the plot and a
failed seed. No training; the milestones themselves are the product's (tests/test_competence.py)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

from formula_tourney.results.competence import Bots, run_competence, summarise
from formula_tourney.tourney.plan import Planner
from formula_tourney.tourney.spec import parse_spec

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "time_to_competence.py"
_SPEC = importlib.util.spec_from_file_location("time_to_competence", _PATH)
ttc = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(ttc)

NAN = math.nan
BOTS = Bots(centre_s=35.4, mincurv_s=34.7, reference_limit_s=33.8)


def _curve_run() -> dict:
    """A run of the product's competence record, as the benchmark shows it."""
    import pandas as pd

    rows = [{"episode": e, "env_steps": e * 100, "track": "oval", "best_lap_s": lap,
             "damage": 0.0, "finished": True, "cpu_s": cpu}
            for e, lap, cpu in ((5, NAN, 10.0), (10, 35.8, 20.0), (15, 34.5, 30.0))]
    run = run_competence(pd.DataFrame(rows), "oval", BOTS)
    return ttc._run_record("WIN1:tuned", {**run, "seed": 0, "cpu_s_total": 31.0})


def test_the_tournament_has_one_part_per_entrant_and_the_product_accepts_it(
    tmp_path: Path,
) -> None:
    defaults = {"episodes": 10**7, "max_steps": 1000, "test_every_episodes": 5,
                "test_starts": 3, "test_max_steps": 631, "budget_cpu_s": 20.0,
                "stop_at": "best-bot", "device": "cpu", "threads": 1,
                "env_overrides": {"track_pos_weight": 0}, "variant_overrides": {"batch_size": 32}}
    text = ttc.tournament_toml(track="oval", reference="centre", lac=False,
                               entrants=[("WIN1", "fast-small"), ("SAC", "best")],
                               seeds=[3, 4], defaults=defaults,
                               demos={("SAC", "best"): {"laps": 2}},
                               anchors=[("sb3", "SAC")])  # fmt: skip
    path = tmp_path / "t.toml"
    spec = parse_spec(text, path)
    assert [p.name for p in spec.parts] == ["WIN1-fast-small", "SAC-best", "SB3-SAC-fast-small"]
    assert spec.variants["SB3-SAC"].sb3 == "SAC"  # an outside entrant at its defaults
    assert spec.seed_base == 3 and spec.defaults.seeds == 2
    planner = Planner(spec, path, text, tmp_path / "res")
    jobs = planner.jobs(0, ["WIN1"])
    run = planner.run_spec(0, "WIN1", 0, seed=1)
    assert [j.job_id for j in jobs] == ["WIN1-fast-small/WIN1-MOT/seed-0",
                                        "WIN1-fast-small/WIN1-MOT/seed-1"]  # fmt: skip
    assert run.seed == 4 and run.preset == "fast-small" and run.agent.batch_size == 32
    assert run.schedule.budget_cpu_s == 20.0 and run.schedule.stop_at == "best-bot"
    assert run.env.track_pos_weight == 0 and run.demos is None
    assert planner.run_spec(1, "SAC", 0).demos.laps == 2
    assert [b.spec["reference"] for b in planner.baselines(0)] == ["centre", "mincurv"]


def test_seeds_are_consecutive_and_entrants_are_pairs() -> None:
    assert ttc.parse_seeds("2,0,1") == [0, 1, 2]
    for bad in ("", "0,2"):
        with pytest.raises(SystemExit):
            ttc.parse_seeds(bad)
    assert ttc.parse_entrants("WIN1:best, SAC:best,") == [("WIN1", "best"), ("SAC", "best")]
    for bad in ("WIN1", "WIN1:best,WIN1:best", "", ":best"):
        with pytest.raises(SystemExit):
            ttc.parse_entrants(bad)
    assert ttc.parse_overrides(["batch_size=32", "algorithm=sac"]) == {
        "batch_size": 32, "algorithm": "sac"}  # fmt: skip


def test_the_anchor_stops_at_the_best_bot_unless_it_trains_to_the_budget() -> None:
    assert ttc.stop_lap_s(BOTS, to_budget=False) == 34.7
    assert ttc.stop_lap_s(BOTS, to_budget=True) == -math.inf  # no lap ends it


def test_ratios_and_finite_numbers() -> None:
    assert ttc.finite(math.inf) is None and ttc.finite(12.34) == 12.3
    assert ttc.ratio(30.0, 60.0) == 0.5
    assert ttc.ratio(30.0, math.inf) == 0.0 and ttc.ratio(math.inf, 60.0) is None


def _run(a: float | None, b: float | None, c: float | None, best: float | None,
         rate: float | None) -> dict:  # fmt: skip
    return {"cpu_s": dict(zip(ttc.MILESTONES, (a, b, c), strict=True)),
            "best_lap_to_limit": best, "clean_start_rate": rate}  # fmt: skip


def test_goal_flags() -> None:
    runs = [_run(5.0, 40.0, 20.0, 1.01, 1.0), _run(8.0, 50.0, None, 1.03, 0.5),
            _run(9.0, 70.0, 25.0, 1.012, 1.0), _run(None, None, None, None, None)]  # fmt: skip
    s = summarise(runs)  # medians: (a) 8.5, (c) inf (2 of 4 reached), best/limit 1.03
    ratios = {"SB3-SAC": {"first_clean_lap": 0.2, "beat_centre_bot": 0.6,
                          "beat_mincurv_bot": None}}  # fmt: skip
    oval = ttc.goal_flags("oval", s, ratios)
    assert oval == {"beat_mincurv_bot_cpu_s": False, "best_lap_to_limit": False,
                    "ratio_first_clean_lap_vs_SB3-SAC": True,
                    "ratio_beat_centre_bot_vs_SB3-SAC": False,
                    "ratio_beat_mincurv_bot_vs_SB3-SAC": False}  # fmt: skip
    tech = ttc.goal_flags("technical", s, None)
    # (a)'s median 8.5 <= 60 but one seed in four missed: "4 of 4" is not met
    assert tech == {"first_clean_lap_cpu_s": False, "clean_start_rate": True,
                    "beat_mincurv_bot_cpu_s": False, "best_lap_to_limit": True}  # fmt: skip
    all_reached = summarise(runs[:1] * 4)
    assert ttc.goal_flags("technical", all_reached, None)["first_clean_lap_cpu_s"] is True
    assert ttc.goal_flags("technical", all_reached, None, demos=True) == {
        "beat_mincurv_bot_cpu_s": True, "best_lap_to_limit": True}
    assert ttc.goal_flags("gen-5", s, None) is None


def test_the_goals_table_names_each_figure_its_value_and_whether_it_is_met() -> None:
    s = summarise([_run(5.0, 40.0, 20.0, 1.01, 1.0)] * 4)
    result = {"track": "oval", "entrants": [{
        "label": "WIN1:best", "demos": None, "summary": s,
        "goal_met": ttc.goal_flags("oval", s, {"SB3-SAC": {"first_clean_lap": 0.1,
                                                           "beat_centre_bot": 0.0,
                                                           "beat_mincurv_bot": 0.0}})}]}
    lines = ttc.goals_table(result)
    assert lines[0] == "goals of WIN1:best (from scratch):"
    assert lines[1] == ("  CPU-s until it beats the best bot: 20.0 (4 of 4); goal <= 30: met")
    assert lines[2].endswith("1.0100; goal <= 1.015: met")
    assert lines[3].endswith(": 3 of 3 <= 0.25")


def test_the_table_shows_env_steps_under_each_milestone_and_the_json_keeps_them() -> None:
    """CPU-s to a milestone depends on how many steps the machine buys per CPU-s, which varies
    (on one machine, from hour to hour); the env steps to it do not, so the table shows both."""
    run = {**_curve_run(), "env_steps": 3100}  # (a) at episode 10: 1 000 env steps
    s = summarise([run] * 4)
    result = {"track": "oval", "reference": "centre", "lac": False, "budget_cpu_s": 300.0,
              "seeds": [0, 1, 2, 3], "bots": vars(BOTS),
              "entrants": [{"label": "WIN1:tuned", "demos": None, "summary": s, "goal_met": {},
                            "runs": [run] * 4}], "anchors": []}  # fmt: skip
    table = ttc.render(result).splitlines()
    steps_row = next(line for line in table if line.startswith("  env steps (k)"))
    assert steps_row.split()[3:8] == ["1.0", "1.5", "1.5", "100", "steps/CPU-s"]
    js = ttc._json_summary(s)
    assert js["median_first_clean_lap_env_steps"] == 1000.0
    assert js["median_env_steps_per_cpu_s"] == 100.0  # 3 100 env steps in 31 CPU-s


def test_laps_at_env_steps_compare_earlier_runs_step_for_step(tmp_path: Path) -> None:
    """``--replot ... --at-env-steps N``: each run's best clean lap after at most N env steps,
    read from its tests (here hand-made: clean 35.8 s after 1 000 env steps, 34.5 s after
    1 500), and the median with a miss counted as infinite."""
    import pandas as pd

    rows = [{"episode": e, "env_steps": e * 100, "track": "oval", "best_lap_s": lap,
             "damage": 0.0, "finished": True, "cpu_s": cpu}
            for e, lap, cpu in ((5, NAN, 10.0), (10, 35.8, 20.0), (15, 34.5, 30.0))]
    tests = pd.DataFrame(rows)
    runs = [{**_curve_run(), "seed": 0}, {**_curve_run(), "seed": 1},
            ttc._failed("WIN1:tuned", 2, "EntrantError: NaN action")]  # fmt: skip
    result = {"track": "oval", "entrants": [{"label": "WIN1:tuned", "runs": runs}],
              "anchors": []}  # fmt: skip
    (row,) = ttc.laps_at_env_steps(result, [999, 1000, 1500], lambda run: tests)
    assert row["seeds"] == [0, 1, 2]
    assert row["laps_s"] == {"999": [None, None, None], "1000": [35.8, 35.8, None],
                             "1500": [34.5, 34.5, None]}  # fmt: skip
    assert row["median_s"] == {"999": None, "1000": 35.8, "1500": 34.5}
    text = ttc.render_laps_at_env_steps([row], "oval")
    assert "WIN1:tuned at 1,500 env steps: 34.500, 34.500, miss; median 34.500 s" in text
    with pytest.raises(SystemExit, match=r"gone: not a job folder \(no config\.json\)"):
        ttc._job_tests({"seed": 0, "job": str(tmp_path / "gone")})
    assert ttc.parse_env_steps("100000, 135000") == [100000, 135000]
    for bad in ("", "1e5", "0"):
        with pytest.raises(SystemExit, match="--at-env-steps"):
            ttc.parse_env_steps(bad)


def test_settled_laps_are_the_median_of_the_late_tests() -> None:
    """``--replot ... --settled-from-cpu-s S``: each run's median clean test lap over its tests
    at S CPU-s or later (a dirty test is no lap), its fastest and slowest, and the median over
    runs with a run that has none there (or failed) counted as a miss."""
    def run(seed: int, laps: list[tuple[float, float | None]]) -> dict:
        return {"seed": seed, "curve": [{"episode": 5 * (k + 1), "cpu_s": cpu,
                                         "clean_lap_s": lap}
                                        for k, (cpu, lap) in enumerate(laps)]}  # fmt: skip

    runs = [run(0, [(10.0, 34.0), (20.0, 36.0), (25.0, None), (30.0, 35.0), (40.0, 35.5)]),
            run(1, [(10.0, 35.2), (20.0, 36.4), (30.0, 36.0)]),
            run(2, [(10.0, 34.9), (15.0, None)]),
            ttc._failed("WIN1:best", 3, "EntrantError: NaN action")]  # fmt: skip
    result = {"track": "oval", "entrants": [{"label": "WIN1:best", "runs": runs}],
              "anchors": []}  # fmt: skip
    (row,) = ttc.settled_laps(result, 20.0)
    assert row["seeds"] == [0, 1, 2, 3]
    assert row["median_lap_s"] == [35.5, 36.2, None, None]  # 35.0, 35.5, 36.0 / 36.0, 36.4
    assert row["span_s"] == [[35.0, 36.0], [36.0, 36.4], None, None]
    assert row["median_s"] is None  # two misses of four: the median is a miss
    (early,) = ttc.settled_laps(result, 0.0)
    assert early["median_lap_s"][:3] == [35.25, 36.0, 34.9]
    assert early["median_s"] == pytest.approx((35.25 + 36.0) / 2)  # 34.9, 35.25, 36.0, miss
    text = ttc.render_settled_laps([row], 20.0)
    assert "WIN1:best: 35.500 [35.000, 36.000], 36.200 [36.000, 36.400], miss, miss" in text


def test_anchors_are_parsed_and_named() -> None:
    assert ttc.parse_anchors("sb3:SAC, sb3_contrib:CrossQ") == [("sb3", "SAC"),
                                                                 ("sb3_contrib", "CrossQ")]
    assert ttc.anchor_variant("sb3_contrib", "CrossQ") == "SB3C-CrossQ"
    for bad in ("SAC", "torch:SAC", "sb3:"):
        with pytest.raises(SystemExit):
            ttc.parse_anchors(bad)


NO_LAP = {"episode": 5, "cpu_s": 1.0, "clean_lap_s": None}


def test_plot_curves_writes_a_png_and_a_pdf(tmp_path) -> None:
    run = _curve_run()
    assert run["cpu_s"] == {"first_clean_lap": 20.0, "beat_centre_bot": 30.0,
                            "beat_mincurv_bot": 30.0}  # fmt: skip
    result = {"track": "oval", "reference": "centre", "lac": False, "seeds": [0],
              "bots": vars(BOTS), "entrants": [{"label": "WIN1:tuned", "runs": [run]}],
              "anchors": [{"label": "SB3-SAC", "runs": [{"curve": [NO_LAP]}]}]}  # fmt: skip
    paths = ttc.plot_curves(result, tmp_path / "curves")
    assert sorted(p.name for p in paths) == ["curves.pdf", "curves.png"]
    assert (tmp_path / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_failed_run_is_summarised_and_plotted_as_a_run_that_reached_nothing(tmp_path) -> None:
    """A seed whose job failed keeps the others: its record counts as misses in the medians
    and draws nothing (it once stopped the plot, and with it the benchmark's JSON line)."""
    failed = ttc._failed("SB3-SAC", 3, "EntrantError: NaN action")
    assert failed["curve"] == [] and summarise([failed])["reached_first_clean_lap"] == 0
    result = {"track": "oval", "reference": "centre", "lac": False, "seeds": [0, 3],
              "bots": vars(BOTS),
              "entrants": [{"label": "WIN1:tuned", "runs": [_curve_run(), failed]}],
              "anchors": []}  # fmt: skip
    assert [p.name for p in ttc.plot_curves(result, tmp_path / "c")] == ["c.png", "c.pdf"]


def test_replot_pools_runs_of_one_label_and_refuses_another_setup(tmp_path) -> None:
    """``--replot`` reads each file's last result line (a log with progress lines above it
    counts), pools the runs of entrants that share a label (a file's ``=LABEL`` renames its
    entrants) and draws them; runs of another track or reference are refused by name."""
    import json

    def result(seed: int, label: str, track: str = "oval") -> dict:
        run = {**_curve_run(), "seed": seed}
        return {"benchmark": "time_to_competence", "track": track, "reference": "centre",
                "lac": False, "seeds": [seed], "bots": vars(BOTS),
                "entrants": [{"label": label, "runs": [run]}], "anchors": []}  # fmt: skip

    first, second, other = tmp_path / "a.log", tmp_path / "b.json", tmp_path / "c.json"
    first.write_text("WIN1-best/seed-0: cpu 1 s\n" + json.dumps(result(0, "WIN1:best")) + "\n")
    second.write_text(json.dumps(result(1, "WIN1:best")) + "\n")
    other.write_text(json.dumps(result(2, "WIN1:best", track="technical")) + "\n")
    pooled = ttc.load_results([str(first), str(second)])
    assert [e["label"] for e in pooled["entrants"]] == ["WIN1:best"]
    assert [r["seed"] for r in pooled["entrants"][0]["runs"]] == [0, 1]
    assert pooled["seeds"] == [0, 1] and pooled["bots"] == vars(BOTS)
    apart = ttc.load_results([f"{first}=former best", str(second)])
    assert [(e["label"], len(e["runs"])) for e in apart["entrants"]] == [
        ("former best", 1), ("WIN1:best", 1)]  # fmt: skip
    assert [p.name for p in ttc.plot_curves(apart, tmp_path / "r")] == ["r.png", "r.pdf"]
    with pytest.raises(SystemExit, match=r"c\.json has track technical.*first file track oval"):
        ttc.load_results([str(first), str(other)])
    (tmp_path / "empty.log").write_text("no result here\n")
    with pytest.raises(SystemExit, match=r"empty\.log: no time_to_competence result line"):
        ttc.load_results([str(tmp_path / "empty.log")])
    with pytest.raises(SystemExit, match=r"missing\.json: No such file"):
        ttc.load_results([str(tmp_path / "missing.json")])
    (tmp_path / "cut.json").write_text('{"benchmark": "time_to_competence", "track": "oval"}\n')
    with pytest.raises(SystemExit, match=r"cut\.json: its result line lacks 'reference'"):
        ttc.load_results([str(tmp_path / "cut.json")])
