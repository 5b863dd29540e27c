"""The report's figures on the fixture tournament: every text fits the canvas and no two overlap,
the learning curves mark every clean test and show the tables' bLT, a seed that stopped early is
drawn as stopped, and the HTML captions say what a figure shows."""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg", force=True)

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from matplotlib.text import Text  # noqa: E402
from report_fixtures import build_tournament  # noqa: E402

from formula_tourney.report import plots  # noqa: E402
from formula_tourney.report.build import build_report  # noqa: E402
from formula_tourney.report.claims.figures import make_claim_figures  # noqa: E402
from formula_tourney.report.html import figure_caption  # noqa: E402
from formula_tourney.report.load import load_tournament  # noqa: E402
from formula_tourney.report.paper_tables import Context, build_tables  # noqa: E402
from formula_tourney.report.race_figures import plot_race  # noqa: E402

# Entrant labels as long as the demo's, which is where labels used to run off the canvas.
LONG_A = "WIN1 (beyond paper: preset tuned-bc, demos (follower on mincurv)) (seed-0)"
LONG_B = "Follower (Tita) MinCurv"


def drawn_texts(fig: Any) -> list[Text]:
    """Every non-empty Text that drawing the figure actually draws (titles, axis and tick
    labels, legends, colorbars, annotations), found by watching ``Text.draw``: a tick that
    matplotlib made but leaves out (beyond the axis limits) is not on the page."""
    drawn: list[Text] = []
    original = Text.draw

    def record(self: Text, renderer: Any) -> None:
        if self.get_visible() and self.get_text().strip():
            drawn.append(self)
        original(self, renderer)

    Text.draw = record  # type: ignore[method-assign]
    try:
        fig.canvas.draw()
    finally:
        Text.draw = original  # type: ignore[method-assign]
    return list(dict.fromkeys(drawn))


def text_problems(fig: Any) -> list[str]:
    """Every drawn text of the figure whose window extent leaves the canvas or overlaps
    another's, as one line each."""
    texts = drawn_texts(fig)
    renderer = fig.canvas.get_renderer()
    canvas = fig.bbox
    boxes = [(t, t.get_window_extent(renderer)) for t in texts]
    problems = []
    tol = 0.5  # px: glyph boxes that only touch do not overlap
    for artist, box in boxes:
        if (box.x0 < canvas.x0 - tol or box.y0 < canvas.y0 - tol or box.x1 > canvas.x1 + tol
                or box.y1 > canvas.y1 + tol):
            problems.append(f"{artist.get_text()!r} leaves the canvas: {box.bounds} vs "
                            f"{canvas.bounds}")
    for i, (a, box_a) in enumerate(boxes):
        for b, box_b in boxes[i + 1:]:
            w = min(box_a.x1, box_b.x1) - max(box_a.x0, box_b.x0)
            h = min(box_a.y1, box_b.y1) - max(box_a.y0, box_b.y0)
            if w > tol and h > tol:
                problems.append(f"{a.get_text()!r} overlaps {b.get_text()!r}")
    return problems


@pytest.fixture()
def checked(monkeypatch: pytest.MonkeyPatch) -> dict[str, tuple[Any, list[str]]]:
    """Check every figure any report module saves, before it is written:
    name -> (figure, problems)."""
    found: dict[str, tuple[Any, list[str]]] = {}
    original = plots.save_figure

    def check_then_save(fig: Any, out_base: Path) -> list[Path]:
        found[Path(out_base).name] = (fig, text_problems(fig))
        return original(fig, out_base)

    for name, module in list(sys.modules.items()):
        if name.startswith("formula_tourney.report") and \
                getattr(module, "save_figure", None) is original:
            monkeypatch.setattr(module, "save_figure", check_then_save)
    return found


@pytest.fixture(scope="module")
def cup(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_tournament(tmp_path_factory.mktemp("results"))


def _race_doc() -> dict[str, Any]:
    names = [LONG_A, "WIN4 (seed-1)", LONG_B]
    results = [{"name": n, "grid": k + 1} for k, n in enumerate(names)]
    chart = [{"name": n, "lap": lap, "position": (k + lap) % 3 + 1, "gap_s": 0.0 if k == 0
              else 1.5 * k * lap} for lap in (1, 2, 3) for k, n in enumerate(names)]
    return {"track": "technical", "laps": 3, "seed": 0, "results": results,
            "lap_chart": chart}


def test_every_figure_keeps_its_text_on_the_canvas_and_apart(
        cup: Path, tmp_path: Path, checked: dict[str, tuple[Any, list[str]]]) -> None:
    report = build_report(str(cup), out_dir=tmp_path / "report", formats=("html",),
                          figures=True)
    trace = pd.read_parquet(next((cup / "part1").glob("win4/seed-0/traces/oval.parquet")))
    slower = trace.assign(time_s=trace["time_s"] * 1.03, speed_kmh=trace["speed_kmh"] / 1.03)
    plots.plot_lap_delta(trace, slower, LONG_A, LONG_B, "p2-technical: lap vs lap",
                         tmp_path / "delta-long")
    plots.plot_racing_line({LONG_A: trace, LONG_B: slower}, "p2-technical", tmp_path / "line",
                           lap_times_s={LONG_A: 78.82, LONG_B: 80.14})
    plot_race(_race_doc(), tmp_path / "race")
    kinds = {name.split("-")[0] for name in checked}
    assert {"learning", "generalisation", "trace", "line", "delta", "ablation", "claim",
            "profile", "race"} <= kinds, kinds
    assert set(report.figures) <= set(checked)
    bad = {name: p for name, (_, p) in checked.items() if p}
    assert not bad, "\n".join(f"{name}: {p}" for name, ps in bad.items() for p in ps)


def _legend_texts(ax: Any) -> list[str]:
    legend = ax.get_legend()
    return [t.get_text().replace("\n", " ") for t in legend.get_texts()] if legend else []


def test_learning_curves_mark_every_clean_test_and_the_tables_blt(
        cup: Path, tmp_path: Path, checked: dict[str, tuple[Any, list[str]]]) -> None:
    ctx = Context.build(load_tournament(cup))
    table1 = next(t for t in build_tables(ctx) if t.key == "table1")
    plots.make_figures(ctx, [table1], tmp_path)
    fig, _ = checked["learning-part1"]
    _, ax_laps = fig.axes
    own = ctx.models.loc[(ctx.models["part"] == "part1") & ctx.models["clean_lap_s"].notna()]
    # every clean test of every seed is a marker (win1 seed-2's lone clean pair included)
    points = [(float(x), float(y)) for line in ax_laps.get_lines() if line.get_marker() == "o"
              for x, y in zip(line.get_xdata(), line.get_ydata(), strict=True)
              if np.isfinite(y)]
    assert sorted(points) == sorted(zip(own["episode"].astype(float), own["clean_lap_s"],
                                        strict=True))
    # the star and its legend show the table's bLT: win1's clean best is 27.1, not 26.5
    labels = " | ".join(_legend_texts(ax_laps))
    for rec in (r for r in table1.records if r["group"] == "part1: oval MOT"):
        if math.isfinite(rec["bLT"]):
            assert f"bLT {rec['bLT']:.2f} s" in labels
    assert "win1: bLT 27.10 s (n=3)" in labels
    stars = [float(line.get_ydata()[0]) for line in ax_laps.get_lines()
             if line.get_marker() == "*"]
    assert min(stars) == pytest.approx(min(r["bLT"] for r in table1.records
                                           if r["group"] == "part1: oval MOT"
                                           and math.isfinite(r["bLT"])), abs=1e-9)


def test_a_seed_that_stopped_early_is_drawn_as_stopped(
        tmp_path: Path, checked: dict[str, tuple[Any, list[str]]]) -> None:
    episodes = pd.DataFrame({
        "job_id": ["p/e/seed-0"] * 300 + ["p/e/seed-1"] * 190, "entrant": "e",
        "episode": [*range(1, 301), *range(1, 191)],
        "reward": [*np.full(300, 100.0), *np.full(190, 300.0)],
    })
    plots.plot_learning_curves(episodes, pd.DataFrame(columns=["entrant", "job_id", "episode",
                                                                "clean_lap_s"]),
                               "stopped", tmp_path / "learning-stopped", smooth=1)
    fig, problems = checked["learning-stopped"]
    assert not problems
    ax_reward = fig.axes[0]
    mean = next(line for line in ax_reward.get_lines() if line.get_label().startswith("e ("))
    y = np.asarray(mean.get_ydata(), dtype=float)
    assert y[0] == pytest.approx(200.0) and y[189] == pytest.approx(200.0)
    assert np.isnan(y[190:]).all()  # the mean over both seeds ends with seed-1
    # after seed-1's last episode the mean is seed-0's alone, dashed: never 0, never a gap
    dashed = next(line for line in ax_reward.get_lines() if line.get_linestyle() == "--")
    tail = np.asarray(dashed.get_ydata(), dtype=float)
    assert np.all(tail[190:] == pytest.approx(100.0)) and np.isnan(tail[:189]).all()
    assert "n=2, n=1 from ep 191" in mean.get_label().replace("\n", " ")
    stops = [line for line in ax_reward.get_lines() if line.get_marker() == "x"
             and len(line.get_xdata())]
    assert [(float(s.get_xdata()[0]), float(s.get_ydata()[0])) for s in stops] == [(190.0,
                                                                                   300.0)]
    assert "a seed's last episode" in _legend_texts(ax_reward)


def test_html_captions_say_what_a_figure_shows(cup: Path, tmp_path: Path) -> None:
    build_report(str(cup), out_dir=tmp_path, formats=("html",), figures=True, part="part1")
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", page)
    assert "<figcaption>learning-part1</figcaption>" not in page
    assert any(c.startswith("Learning curves, part1. Training reward") for c in captions)
    delta = next(c for c in captions if "lap vs lap" in c)
    assert delta.startswith("part1: oval MOT: lap vs lap. Both laps") and "A \u2212 B" in delta
    assert figure_caption("p3-race-race-0-gaps", "Gap to the leader: oval, 3 laps, seed 0") == (
        "Gap to the leader: oval, 3 laps, seed 0. Each car's gap to the leader at the end of "
        "every lap.")
    assert figure_caption("odd-figure") == "odd-figure"


def test_profile_legend_names_its_bands(
        cup: Path, tmp_path: Path, checked: dict[str, tuple[Any, list[str]]]) -> None:
    ctx = Context.build(load_tournament(cup))
    make_claim_figures(ctx, [], tmp_path)
    fig, problems = checked["profile"]
    assert not problems
    assert "95% bootstrap CI (shaded)" in _legend_texts(fig.axes[0])
