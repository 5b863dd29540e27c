"""report.load and the paper's tables on the fixture tournament: numbers computed by hand."""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path

import pytest
from report_fixtures import (
    LIMIT_S,
    build_empty_tournament,
    build_generated_tournament,
    build_tournament,
    template_lap,
)

from formula_tourney.errors import UserInputError
from formula_tourney.report import paper_tables, renderers
from formula_tourney.report.competence_table import competence_table
from formula_tourney.report.load import TournamentData, load_tournament, resolve_tournament
from formula_tourney.report.paper_tables import LIMIT_LABEL, Context, build_tables
from formula_tourney.report.table_model import ReportTable

E2 = 2.0 * math.exp(-2.0)  # the template's learning term at episode 300


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("results")
    build_tournament(base)
    build_empty_tournament(base)
    return base


@pytest.fixture(scope="module")
def data(results: Path) -> TournamentData:
    return load_tournament(results / "fixture-cup")


@pytest.fixture(scope="module")
def built(data: TournamentData) -> dict[str, ReportTable]:
    return {t.key: t for t in build_tables(Context.build(data))}


def _record(table: ReportTable, group: str, row: str) -> dict:
    return next(r for r in table.records if r.get("group") == group and r["row"] == row)


def _row(table: ReportTable, label: str) -> dict:
    return next(r for r in table.rows if r["label"] == label)


def test_load_reports_every_gap(data: TournamentData) -> None:
    problems = "\n".join(data.problems)
    assert "part2/win4-rc/seed-2: failed (DivergedError" in problems
    assert "part3/per1m-mot/seed-1: running" in problems
    assert "part part4: no jobs" in problems
    assert "baseline genetic on oval (part3): failed (TimeoutError" in problems
    assert len(data.jobs) == 34
    # 33 jobs wrote files; the failed one wrote episodes only, the running one nothing
    assert data.tests["job_id"].nunique() == 32
    assert data.episodes["job_id"].nunique() == 33
    assert data.part_order() == ["part1", "part2", "part3", "ablation", "part4"]


def test_resolve_tournament(results: Path) -> None:
    assert resolve_tournament("fixture-cup", results) == results / "fixture-cup"
    assert resolve_tournament(str(results / "empty-cup"), results) == results / "empty-cup"
    assert resolve_tournament(None, results) in (results / "fixture-cup", results / "empty-cup")
    with pytest.raises(UserInputError, match="known under .*empty-cup, fixture-cup"):
        resolve_tournament("nope", results)
    with pytest.raises(UserInputError, match="no part 'nope'"):
        load_tournament(results / "fixture-cup", part="nope")


def test_table1_hand_computed(built: dict[str, ReportTable]) -> None:
    t1 = built["table1"]
    assert t1.groups[:3] == ["part1: oval MOT", "part2: technical MOT", "part2: technical RC"]
    # win1 (WIN1_PART1): seed bests 27.1, 27.4, 27.2 (26.5 came with damage)
    win1 = _record(t1, "part1: oval MOT", "win1")
    assert win1["bLT"] == pytest.approx(27.1)
    assert win1["aLT"] == pytest.approx((27.1 + 27.4 + 27.2) / 3)
    assert win1["ci_low"] == pytest.approx(27.1) and win1["ci_high"] == pytest.approx(27.4)
    assert win1["damage"] == pytest.approx(40.0)
    assert win1["gap_pct"] == pytest.approx((27.1 / LIMIT_S["oval"] - 1) * 100)
    assert sorted(win1["run_best_s"]) == pytest.approx([27.1, 27.2, 27.4])
    # template runs: best at episode 300, start 0, + 0.1 per seed
    win4 = _record(t1, "part1: oval MOT", "win4")
    assert win4["bLT"] == pytest.approx(26.5 + 0.3 + E2)
    assert win4["aLT"] == pytest.approx(26.5 + 0.3 + E2 + 0.1)
    assert win4["bLT"] == pytest.approx(template_lap("oval", "win4", 0, 300, 0))
    # ms3 only lapped with damage: DNF with its mean cumulative damage (2 starts x 35)
    ms3 = _record(t1, "part1: oval MOT", "ms3")
    assert ms3["status"] == "DNF" and math.isnan(ms3["bLT"]) and ms3["damage"] == 70.0
    assert _row(t1, "ms3")["text"][("part1: oval MOT", "bLT")] == "DNF"
    # the failed seed counts as planned but not run: 2/3
    rc = _record(t1, "part2: technical RC", "win4")
    assert (rc["runs"], rc["planned"], rc["finished_runs"]) == (2, 3, 2)
    assert rc["aLT"] == pytest.approx(66.0 + 2.0 + E2 + 0.05)
    assert _row(t1, "win4")["text"][("part2: technical RC", "runs")] == "2/3"


def test_table1_baselines_limit_and_bold(built: dict[str, ReportTable]) -> None:
    t1 = built["table1"]
    group = "part1: oval MOT"
    assert _row(t1, "Follower (Tita)")["values"][(group, "bLT")] == pytest.approx(28.57)
    assert _row(t1, "Genetic")["values"][(group, "bLT")] == pytest.approx(33.86)
    limit = _row(t1, LIMIT_LABEL)
    assert limit["values"][(group, "bLT")] == pytest.approx(25.80)
    assert limit["text"][(group, "gap")] == "+0.0%"
    assert _row(t1, "Follower (Tita)")["text"][(group, "gap")] == "+10.7%"
    best = t1.best_cells()
    labels = {(t1.rows[i]["label"], g, m) for i, g, m in best}
    assert ("win4", group, "bLT") in labels and ("win4", group, "aLT") in labels
    assert not any(lab == LIMIT_LABEL for lab, _, _ in labels)
    # on the technical track with MOT the bot is fastest, and it is bold there
    assert ("Follower (Tita)", "part2: technical MOT", "bLT") in labels
    # the ablation pair shares a variant: its rows are named by entrant
    assert {"win1", "win1-noat"} <= {r["label"] for r in t1.rows}


def test_comparisons(built: dict[str, ReportTable]) -> None:
    comp = built["comparisons"]
    rec = next(r for r in comp.records if r["group"] == "part1: oval MOT" and r["row"] == "win1")
    assert rec["leader"] == "win4"
    # win4 runs 27.07/27.17/27.27 vs win1 27.1/27.4/27.2: 3 + 2 + 1 of 9 pairs faster
    assert rec["prob_faster"] == pytest.approx(6 / 9)
    assert 0.0 <= rec["low"] <= rec["prob_faster"] <= rec["high"] <= 1.0


def test_table2_lac(built: dict[str, ReportTable]) -> None:
    t2 = built["table2"]
    assert t2.groups == ["oval", "technical"]
    assert [r["label"] for r in t2.rows] == [
        "Follower (Tita)", "per1m MOT", "per1m RC", "per1m RC + LAC", LIMIT_LABEL]
    lac = _row(t2, "per1m RC + LAC")
    assert lac["values"][("technical", "bLT")] == pytest.approx(66.0 - 1.0 + E2)
    assert lac["text"][("oval", "bLT")] == "not run"  # never trained on the oval
    # per1m RC pools part2 and part3 runs on the technical track: best is seed 0 of either
    assert _row(t2, "per1m RC")["values"][("technical", "bLT")] == pytest.approx(67.5 + E2)
    assert _row(t2, "Follower (Tita)")["values"][("technical", "bLT")] == pytest.approx(68.11)


def test_table3_general_models(built: dict[str, ReportTable]) -> None:
    t3 = built["table3"]
    assert t3.metrics["General"] == ["technical", "oval", "flowing"]
    rc = _row(t3, "per1m RC")
    # the store chose seed-1's episode-300 checkpoint: its laps, not seed-0's faster ones
    assert rc["values"][("General", "technical")] == pytest.approx(66.0 + 1.5 + E2 + 0.1)
    assert rc["values"][("General", "oval")] == pytest.approx(26.5 + 1.5 + E2 + 0.1 + 7.0)
    assert rc["values"][("General", "flowing")] == pytest.approx(74.0 + 1.5 + E2 + 0.1 + 7.0)
    assert rc["values"][("Best", "bLT")] == pytest.approx(66.0 + 1.5 + E2)
    # computed by the report: best train lap among checkpoints finishing every track
    lac = _row(t3, "per1m RC + LAC")
    assert lac["values"][("General", "oval")] == pytest.approx(26.5 - 1.0 + E2 + 7.0)
    # per1m MOT never finishes the unseen flowing track: no checkpoint is a general model, and
    # the row says so instead of showing the model finishing the most tracks
    mot = _row(t3, "per1m MOT")
    assert [mot["text"][("General", t)] for t in ("technical", "oval", "flowing")] == [
        paper_tables.NO_GENERAL] * 3
    assert math.isnan(mot["values"][("General", "technical")])
    assert mot["values"][("Best", "bLT")] == pytest.approx(66.0 + 6.0 + E2)
    assert any(n.startswith("per1m MOT: no general model") for n in t3.notes)
    assert next(r for r in t3.records if r["row"] == "per1m MOT")["general"] is None
    # the genetic bot drove the flowing track without finishing (DNF); its oval drive failed,
    # so part 3 has no genetic oval lap and the best over parts (part 1's) is shown
    assert _row(t3, "Genetic")["text"][("General", "flowing")] == "DNF"
    assert _row(t3, "Genetic")["values"][("General", "oval")] == pytest.approx(33.86)
    assert any("part3/per1m-rc/seed-1 after 300" in n for n in t3.notes)
    # bold per General column too: the LAC model on the technical track, the bot elsewhere
    best = {(t3.rows[i]["label"], g, m) for i, g, m in t3.best_cells()}
    assert ("per1m RC + LAC", "General", "technical") in best
    assert ("Follower (Tita)", "General", "flowing") in best


def test_empty_part_and_empty_tournament_render(results: Path) -> None:
    for root, part in ((results / "fixture-cup", "part4"), (results / "empty-cup", None)):
        data = load_tournament(root, part=part)
        built = build_tables(Context.build(data))
        assert all(t.empty for t in built)
        assert "no jobs" in renderers.render_markdown(built[0])
        doc = renderers.latex_document(built, "x", data.problems)
        assert doc.rstrip().endswith("\\end{document}")


def test_no_time_to_competence_table_without_a_cpu_budget(data: TournamentData) -> None:
    """The fixture's runs have no budget_cpu_s and their tests no cpu_s: the table stays off
    (tests/test_competence.py builds one from a part with a budget)."""
    assert competence_table(Context.build(data)).empty


def test_unreadable_files_become_problems(tmp_path: Path) -> None:
    root = build_tournament(tmp_path)
    (root / "part1" / "win4" / "seed-0" / "tests.parquet").write_bytes(b"not parquet")
    (root / "part1" / "per1m" / "seed-2" / "tests.parquet").unlink()
    with sqlite3.connect(root / "index.sqlite") as con:
        con.execute("DELETE FROM jobs WHERE kind='baseline'")  # no bot drove
    data = load_tournament(root, part="part1")
    problems = "\n".join(data.problems)
    bad = root / "part1" / "win4" / "seed-0" / "tests.parquet"
    assert f"part1/win4/seed-0: {bad}: cannot read the job's tests table" in problems
    assert "part1/per1m/seed-2: marked done but" in problems and "(missing)" in problems
    t1 = build_tables(Context.build(data))[0]
    win4 = _record(t1, "part1: oval MOT", "win4")
    assert win4["runs"] == 2 and win4["planned"] == 3
    assert [r["kind"] for r in t1.rows].count("bot") == 0


def test_markdown_and_latex_render(built: dict[str, ReportTable]) -> None:
    md = renderers.render_markdown(built["table1"])
    assert "| win4 | **27.07** | **27.17** | [27.07, 27.27] |" in md
    assert "| ms3 | DNF | DNF |" in md
    tex = renderers.render_latex_tabular(built["table1"].subset(["part1: oval MOT"]))
    assert "\\toprule" in tex and "\\bottomrule" in tex and "\\cmidrule(lr){2-8}" in tex
    assert "win4 & \\textbf{27.07} & \\textbf{27.17} & [27.07, 27.27]" in tex
    assert "27.10 & 27.23" in tex and "+5.0\\%" in tex
    # families are separated: win rows, midrule, ms3
    lines = tex.splitlines()
    assert lines[lines.index(next(x for x in lines if x.startswith("ms3 "))) - 1] == "\\midrule"


def test_terminal_table_never_cuts_numbers_on_a_narrow_console(
    built: dict[str, ReportTable],
) -> None:
    """A piped or 80-column console used to shrink cells to '27.…'; the numbers must stay whole."""
    from rich.console import Console

    console = Console(width=40, record=True, color_system=None)
    renderers.render_rich(built["table1"], console)
    text = console.export_text()
    assert "…" not in text
    assert "27.10" in text  # win1's bLT on the oval, computed by hand above


def test_terminal_table_keeps_every_column_beside_a_long_label(
    built: dict[str, ReportTable],
) -> None:
    """A run's "beyond paper" label can be 65 characters (`make demo`'s technical part): on a
    piped, 80-column console its lap columns were squeezed to zero width, numbers and all."""
    import copy

    from rich.console import Console

    table = copy.deepcopy(built["table1"])
    for row in table.rows:
        if row["label"] == "win4":
            row["label"] = "WIN4 (beyond paper: preset tuned-bc, demos (follower on mincurv))"
    console = Console(width=80, record=True, color_system=None)
    renderers.render_rich(table, console)
    lines = console.export_text().splitlines()
    rows = [line for line in lines if "WIN4 (beyond paper" in line]
    assert any("27.07" in r and "27.17" in r and "[27.07, 27.27]" in r for r in rows)  # oval
    assert any("74.27" in r and "74.37" in r and "[74.27, 74.47]" in r for r in rows)  # technical
    for line in lines:  # a column squeezed to nothing shows as two borders side by side
        assert "││" not in line and "┃┃" not in line, line


def test_runs_beyond_the_paper_are_labelled_in_every_table(tmp_path: Path) -> None:
    """A run's config.json says what it adds to the paper (another family, demos, cars); its
    row carries that label, so a replication is never mistaken for an improvement."""
    import json

    from formula_tourney.results.folder import JobFolder

    root = build_tournament(tmp_path)
    data = load_tournament(root)
    sac_jobs = data.jobs.loc[data.jobs["variant"] == "win1", "job_id"].tolist()
    for job_id in sac_jobs:
        folder = JobFolder(data.job_dir(job_id))
        doc = json.loads(folder.config_path.read_text())
        doc["beyond_paper"] = ["demos (follower on mincurv)"]
        folder.config_path.write_text(json.dumps(doc))
    relabelled = load_tournament(root)
    assert relabelled.beyond_paper[sac_jobs[0]] == ["demos (follower on mincurv)"]
    tables = {t.key: t for t in build_tables(Context.build(relabelled))}
    label = "win1 (beyond paper: demos (follower on mincurv))"
    assert label in [r["label"] for r in tables["table1"].rows]
    assert "win1" not in [r["label"] for r in tables["table1"].rows]
    assert _record(tables["table1"], "part1: oval MOT", label)["bLT"] == pytest.approx(27.1)


def test_runs_trained_on_tracks_they_are_never_tested_on(tmp_path: Path) -> None:
    """A general driver (trained on generated tracks, tested only on unseen ones): Tables 1 and
    2 have no group for the generated tracks, and Table 3's general model is the checkpoint
    with clean laps on the most unseen tracks, the least sum of laps breaking the tie (seed 0's
    episode 300: oval 28.0, flowing 79.0; technical never)."""
    data = load_tournament(build_generated_tournament(tmp_path))
    tables = {t.key: t for t in build_tables(Context.build(data))}
    assert tables["table1"].groups == []
    assert tables["table1"].notes == [
        "no job is tested on a track it trains on (unseen tracks: Table 3)"]
    assert tables["table2"].groups == []
    t3 = tables["table3"]
    assert t3.metrics["General"] == ["oval", "technical", "flowing"]
    win1 = _row(t3, "win1 MOT + LAC")
    assert win1["values"][("General", "oval")] == 28.0
    assert win1["values"][("General", "flowing")] == 79.0
    assert win1["text"][("General", "technical")] == "DNF"
    assert win1["text"][("Best", "bLT")] == paper_tables.NOT_TESTED
    assert ("general model of win1 MOT + LAC: general/win1/seed-0 after 300 episodes, clean "
            "laps on 2 of 3 unseen tracks") in t3.notes
    assert ("win1 MOT + LAC, per run: 2 and 0 of 3 unseen tracks lapped cleanly by one "
            "checkpoint") in t3.notes


def test_table3_says_no_general_model_only_where_there_is_none(
        built: dict[str, ReportTable]) -> None:
    """Rows with a general model get its note alone; only per1m MOT, which has none, is noted
    as having none."""
    t3 = built["table3"]
    assert [n.split(":")[0] for n in t3.notes if "no general model" in n] == ["per1m MOT"]
