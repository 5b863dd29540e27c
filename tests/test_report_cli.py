"""``formula-tourney report`` end to end: JSON, LaTeX (compiled where pdflatex exists), HTML and
figures, and ``replay``'s arguments and GIF on an untrained actor."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from report_fixtures import _bot_trace, _trace, build_tournament, template_lap

from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.report import plots
from formula_tourney.report.build import build_report
from formula_tourney.report.load import load_tournament
from formula_tourney.results.folder import BaselineFolder, JobFolder


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("results")
    build_tournament(base)
    return base


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_report_json_has_table1_with_cis(results: Path, capsys) -> None:
    code, out, _ = _run(["report", "--results", str(results), "--part", "part1", "--json"],
                        capsys)
    assert code == 0
    doc = json.loads(out)
    assert doc["tournament"] == "fixture-cup"
    rows = {r["label"]: r for r in doc["tables"]["table1"]["rows"]}
    assert rows["win1"]["cells"]["part1: oval MOT | bLT"] == pytest.approx(27.1)
    assert rows["win1"]["text"]["part1: oval MOT | 95% CI"] == "[27.10, 27.40]"
    # every number shown is a number too: the CI's bounds, the runs' counts
    assert rows["win1"]["cells"]["part1: oval MOT | 95% CI"] == pytest.approx([27.1, 27.4])
    assert all(isinstance(v, float) for v in rows["win1"]["cells"]["part1: oval MOT | 95% CI"])
    assert rows["win1"]["cells"]["part1: oval MOT | runs"] == {"clean": 3, "planned": 3}
    assert rows["ms3"]["cells"]["part1: oval MOT | bLT"] is None
    assert rows["ms3"]["text"]["part1: oval MOT | aLT"] == "DNF"
    # an empty cell says why, and the table's legend explains the mark
    table1 = doc["tables"]["table1"]
    assert rows["Follower (Tita)"]["text"]["part1: oval MOT | aLT"] == "n/a"
    assert table1["legend"]["DNF"].startswith("runs exist but none finished")
    assert "n/a" in table1["legend"]
    comparisons = {r["label"]: r for r in doc["tables"]["comparisons"]["rows"]}
    low, high = comparisons["win1"]["cells"]["part1: oval MOT | 95% CI"]
    shown = comparisons["win1"]["text"]["part1: oval MOT | 95% CI"]
    assert shown == f"[{low:.2f}, {high:.2f}]" and low < high
    assert 0.0 < comparisons["win1"]["cells"]["part1: oval MOT | p"] < 1.0
    assert comparisons["win4"]["text"]["part1: oval MOT | P(faster)"] == "leader"
    assert doc["files"] == {} and doc["figures"] == {}


def test_report_terminal_lists_problems_and_renders(results: Path, capsys) -> None:
    code, out, _ = _run(["report", "--results", str(results)], capsys)
    assert code == 0
    assert "part2/win4-rc/seed-2: failed" in out
    assert "Table 1" in out and "27.23" in out and "DNF" in out


def test_report_bad_input_exits_2(results: Path, capsys) -> None:
    code, out, err = _run(["report", "--results", str(results), "--tournament", "nope"], capsys)
    assert code == 2 and "no tournament 'nope'" in err and out == ""


def test_json_errors_are_json_objects_on_stdout(results: Path, tmp_path: Path, capsys) -> None:
    """With --json a script reads stdout: an error is a JSON object there too (and the usual
    line on stderr), for bad input and for a bad option alike."""
    code, out, err = _run(["report", "--results", str(results), "--tournament", "nope",
                           "--json"], capsys)
    doc = json.loads(out)
    assert code == 2 and doc["exit_code"] == 2 and "no tournament 'nope'" in doc["error"]
    assert err.startswith("error: ") and "no tournament 'nope'" in err
    code, out, _ = _run(["replay", str(tmp_path / "missing.pt"), "--track", "oval", "--gif",
                         str(tmp_path / "lap.gif"), "--json"], capsys)
    assert code == 2 and json.loads(out) == {"error": json.loads(out)["error"], "exit_code": 2}
    assert "does not exist" in json.loads(out)["error"]
    code, out, _ = _run(["report", "--results", str(results), "--no-such-option", "--json"],
                        capsys)
    assert code == 2 and "--no-such-option" in json.loads(out)["error"]


def test_report_garbage_index_exits_2_naming_the_file(tmp_path: Path, capsys) -> None:
    root = tmp_path / "broken-cup"
    root.mkdir()
    (root / "index.sqlite").write_bytes(b"this is not an SQLite database, just text\n" * 40)
    code, out, err = _run(["report", "--results", str(tmp_path)], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert str(root / "index.sqlite") in err and "not a results index" in err
    code, _, err = _run(["report", "--results", str(tmp_path), "--tournament",
                         str(tmp_path / "nowhere")], capsys)
    assert code == 2 and "no tournament" in err


def test_report_writes_several_formats_in_one_call(results: Path, tmp_path: Path,
                                                   capsys) -> None:
    code, out, err = _run(["report", "--results", str(results), "--part", "part1", "--out",
                           str(tmp_path), "--markdown", "--latex", "--html", "--no-figures"],
                          capsys)
    assert code == 0, err
    md = (tmp_path / "report.md").read_text()
    assert out.strip() == md.strip()  # stdout is the Markdown document alone
    assert "| win4 | **27.07** | **27.17** |" in md
    assert "\\textbf{27.07}" in (tmp_path / "report.tex").read_text()
    assert "<td class='best'>27.07</td>" in (tmp_path / "report.html").read_text()
    assert f"wrotereport.html:{tmp_path / 'report.html'}" in "".join(err.split())  # wrapped
    code, out, _ = _run(["report", "--results", str(results), "--part", "part1", "--out",
                         str(tmp_path / "two"), "--latex", "--html", "--no-figures", "--json"],
                        capsys)
    doc = json.loads(out)
    assert code == 0 and doc["formats"] == ["latex", "html"]
    assert {"report.tex", "table1.tex", "report.html"} <= set(doc["files"])
    assert "report.md" not in doc["files"]


def test_report_empty_part_does_not_crash(results: Path, capsys) -> None:
    code, out, _ = _run(["report", "--results", str(results), "--part", "part4", "--json"],
                        capsys)
    assert code == 0
    doc = json.loads(out)
    assert doc["tables"]["table1"]["rows"] == []
    assert any("part4" in p for p in doc["problems"])


def test_latex_is_standalone_and_compiles(results: Path, tmp_path: Path) -> None:
    rep = build_report("fixture-cup", results, out_dir=tmp_path, formats=["latex"],
                       figures=False)
    tex = rep.files["report.tex"].read_text()
    assert tex.startswith("\\documentclass")
    # Table 1's 4 parts + Tables 2, 3, comparisons + the claims and the cost
    assert tex.count("\\begin{table}") == tex.count("\\end{table}") == 9
    assert "\\textbf{27.07}" in tex and "\\usepackage{booktabs}" in tex
    assert (tmp_path / "table1.tex").is_file() and "\\documentclass" not in (
        tmp_path / "table1.tex").read_text()
    if shutil.which("pdflatex") is None:  # CI installs it (.ci/run)
        pytest.skip("pdflatex not found: install texlive-latex-base and "
                    "texlive-latex-recommended")
    proc = subprocess.run(
        ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "report.tex"],
        cwd=tmp_path, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert (tmp_path / "report.pdf").stat().st_size > 10_000


def test_html_and_figures_for_a_generalisation_part(results: Path, tmp_path: Path) -> None:
    rep = build_report("fixture-cup", results, part="part3", out_dir=tmp_path, formats="html")
    names = set(rep.figures)
    assert {"learning-part3", "generalisation-per1m-rc", "trace-part3-technical-rc-lac",
            "line-part3-technical-rc-lac", "delta-part3-technical-rc-lac"} <= names
    for paths in rep.figures.values():
        png, pdf = sorted(paths, key=lambda p: p.suffix, reverse=True)
        assert png.suffix == ".png" and pdf.suffix == ".pdf"
        with Image.open(png) as img:
            assert img.width > 300 and img.height > 200
            # not a blank canvas: many distinct colours
            assert len(img.convert("RGB").getcolors(1 << 20)) > 50
        assert pdf.read_bytes()[:4] == b"%PDF"
    page = rep.files["report.html"].read_text()
    assert page.count("data:image/png;base64,") == len(rep.figures)
    assert "part3/per1m-mot/seed-1: running" in page
    assert "<td class='best'>65.27</td>" in page
    assert not any("baseline trace" in p for p in rep.data.problems)


def _sampled(trace: pd.DataFrame, times: np.ndarray) -> pd.DataFrame:
    """``trace`` sampled at ``times`` (control steps), its ``lap`` count held between steps."""
    t = trace["time_s"].to_numpy()
    out = pd.DataFrame({c: np.interp(times, t, trace[c].to_numpy(dtype=float))
                        for c in trace.columns if c != "lap"})
    if "lap" in trace.columns:
        out["lap"] = trace["lap"].to_numpy()[np.searchsorted(t, times, side="right") - 1]
    return out


def test_racing_line_titles_show_the_tables_lap_times(tmp_path: Path, monkeypatch) -> None:
    """Traces are sampled every control step (200 ms), so the first sample of a lap comes up to
    a step after the line: a title measured from the trace said 35.80 s where Table 1 said 35.97.
    The titles must print the tables' numbers."""
    root = build_tournament(tmp_path)
    lap_s = template_lap("oval", "win4", 0, 300, 0)  # win4 seed-0: Table 1's bLT
    steps = lap_s - 0.2 * np.arange(int(lap_s / 0.2) + 1)[::-1]  # as training.evaluate cuts
    JobFolder(root / "part1/win4/seed-0").write_trace(
        "oval", _sampled(_trace("oval", lap_s), steps))
    bot = _bot_trace("oval", 28.57)
    BaselineFolder(root / "part1/_baselines/follower-recorded-oval").write_trace(
        _sampled(bot, np.arange(0.0, float(bot["time_s"].iloc[-1]), 0.2)))
    titles: dict[str, list[str]] = {}
    real_save = plots.save_figure

    def spy(fig, out_base: Path) -> list[Path]:
        titles[out_base.name] = [ax.get_title() for ax in fig.axes]
        return real_save(fig, out_base)

    monkeypatch.setattr(plots, "save_figure", spy)
    rep = build_report(str(root), tmp_path, part="part1", out_dir=tmp_path / "out")
    table1 = next(t for t in rep.tables if t.key == "table1")
    group = "part1: oval MOT"
    win4 = next(r for r in table1.records if r["group"] == group and r["row"] == "win4")
    text = {r["label"]: r["text"][(group, "bLT")] for r in table1.rows}
    assert win4["bLT"] == pytest.approx(lap_s)
    shown = [f"win4 (seed-0): {text['win4']} s", f"Follower (Tita): {text['Follower (Tita)']} s"]
    assert shown == ["win4 (seed-0): 27.07 s", "Follower (Tita): 28.57 s"]
    assert titles["line-part1-oval-mot"][:2] == shown


def test_figures_compare_with_the_followers_stored_lap(results: Path) -> None:
    data = load_tournament(results / "fixture-cup", part="part2")
    label, trace = plots.bot_trace(data, "part2", "technical")
    assert label == "Follower (Tita)"
    # the faster of its two timed laps (68.11 s, the second is 69.11 s), rebased to 0
    assert trace["time_s"].iloc[0] == 0.0
    assert trace["time_s"].iloc[-1] == pytest.approx(68.11)
    assert plots.bot_trace(data, "part2", "flowing") is None


def test_ablation_pairs_and_plot(results: Path, tmp_path: Path) -> None:
    data = load_tournament(results / "fixture-cup")
    pairs = plots.ablation_pairs(data)
    assert pairs == [{"part": "ablation", "flag": "adopted_target", "off": "win1-noat",
                      "on": "win1"}]
    ep = data.episodes.loc[data.episodes["part"] == "ablation"]
    paths = plots.plot_ablation(ep, {"win1-noat": "off", "win1": "on"}, "AT", tmp_path / "at")
    assert [p.name for p in paths] == ["at.png", "at.pdf"]
    assert all(p.stat().st_size > 5_000 for p in paths)


def test_one_lap_picks_the_fastest_complete_lap() -> None:
    trace = pd.DataFrame({
        "time_s": [0.0, 1.0, 2.0, 4.0, 6.0, 7.0, 8.0, 9.0, 9.5],
        "distance_m": [0.0, 10.0, 20.0, 40.0, 60.0, 70.0, 80.0, 100.0, 105.0],
        "speed_kmh": 36.0, "x_m": 0.0, "y_m": 0.0,
        "lap": [0, 0, 1, 1, 1, 2, 2, 2, 3],  # lap 1 takes 4 s, lap 2 takes 2 s, 3 unfinished
    })
    lap = plots.one_lap(trace)
    assert lap["time_s"].tolist() == [0.0, 1.0, 2.0]
    assert lap["distance_m"].tolist() == [0.0, 10.0, 30.0]
    no_time = plots.one_lap(trace.drop(columns=["time_s", "lap"]))
    assert no_time["time_s"].iloc[-1] == pytest.approx(105.0 / 10.0)  # 36 km/h = 10 m/s


def test_one_lap_chooses_by_the_drives_lap_times_and_skips_damaged_laps() -> None:
    trace = pd.DataFrame({
        "time_s": [0.0, 1.0, 2.0, 4.0, 6.0, 7.0, 8.0, 9.0, 9.5, 12.0, 13.0],
        "distance_m": [0.0, 10.0, 20.0, 40.0, 60.0, 70.0, 80.0, 100.0, 105.0, 130.0, 140.0],
        "speed_kmh": 36.0, "x_m": 0.0, "y_m": 0.0,
        "lap": [0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 4],
    })
    # the rows say lap 2 is fastest (2 s); the drive's exact times say lap 1 (3.9 s against 4.1)
    lap = plots.one_lap(trace, [3.9, 4.1, 4.5], [0.0, 0.0, 0.0])
    assert lap["time_s"].tolist() == [0.0, 2.0, 4.0]
    # lap 1 cut a corner: of the clean laps 2 (4.1 s) and 3 (4.5 s), lap 2
    lap = plots.one_lap(trace, [3.9, 4.1, 4.5], [1.5, 0.0, 0.0])
    assert lap["distance_m"].tolist() == [0.0, 10.0, 30.0]
    with pytest.raises(UserInputError, match="no complete clean lap"):
        plots.one_lap(trace, [3.9, 4.1, 4.5], [1.0, 1.0, 1.0])


def test_delta_time_by_hand() -> None:
    d = np.linspace(0.0, 100.0, 11)
    a = pd.DataFrame({"distance_m": d, "time_s": d / 10.0})  # 10 m/s
    b = pd.DataFrame({"distance_m": d, "time_s": d / 20.0})  # 20 m/s
    grid, delta = plots.delta_time(a, b, points=5)
    np.testing.assert_allclose(grid, [0, 25, 50, 75, 100])
    np.testing.assert_allclose(delta, grid / 10.0 - grid / 20.0)


def test_replay_rejects_bad_arguments(tmp_path: Path, capsys) -> None:
    code, _, err = _run(["replay", str(tmp_path / "missing.pt"), "--track", "oval", "--gif",
                         str(tmp_path / "lap.gif")], capsys)
    assert code == 2 and "does not exist" in err
    code, _, err = _run(["replay", str(tmp_path / "missing.pt"), "--track", "oval", "--gif",
                         str(tmp_path / "lap.png")], capsys)
    assert code == 2 and "must end in .gif" in err


def test_replay_end_to_end(tmp_path: Path, capsys) -> None:
    """A freshly initialised actor on the real env: the GIF is written whatever the lap."""
    pytest.importorskip("formula_tourney.sim.catalog")
    import gymnasium as gym

    import formula_tourney  # noqa: F401 (registers the env)
    from formula_tourney.agents.checkpoints import save_checkpoint
    from formula_tourney.agents.ddpg import DDPGAgent
    from formula_tourney.training.run_spec import build_run_spec

    env = gym.make("FormulaRacing-v0", config={"track": "oval"})
    obs_dim = int(np.prod(env.observation_space.shape))
    env.close()
    # a checkpoint carries its run spec (training.checkpoint), as the trainer writes it
    spec = build_run_spec(variant="WIN1", overrides={"hidden": (16, 16)}, train_tracks=["oval"])
    agent = DDPGAgent(spec.agent, obs_dim)
    ckpt = save_checkpoint(agent, tmp_path / "job" / "checkpoints" / "best.pt",
                           extra={"run_spec": spec.to_json()})
    code, out, _ = _run(["replay", str(ckpt), "--track", "oval", "--gif",
                         str(tmp_path / "lap.gif"), "--max-steps", "12", "--frame-every", "3",
                         "--json"], capsys)
    assert code == 0, out
    summary = json.loads(out)
    assert summary["steps"] <= 12 and summary["frames"] >= 2
    with Image.open(tmp_path / "lap.gif") as img:
        assert img.n_frames == summary["frames"] and img.width > 100
