"""The lines/bot CLI: JSON documents with real numbers, plots, and bad input -> exit 2."""

from __future__ import annotations

import json
import math

import pytest
from test_lines_support import stadium

from formula_tourney import cli
from formula_tourney.commands import lines as lines_cmd


@pytest.fixture
def fake_catalog(monkeypatch, tmp_path):
    """Serve a small synthetic track under any name (the CLI's only catalog use)."""
    monkeypatch.setenv("FORMULA_TOURNEY_CACHE_DIR", str(tmp_path / "cache"))
    track = stadium()
    monkeypatch.setattr(lines_cmd, "load_track", lambda name: track)
    return track


def _run(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_bot_json_reports_laps_damage_and_limit(fake_catalog, capsys):
    cli.main(["bot", "stadium", "--line", "mincurv", "--laps", "2", "--json"])
    data = json.loads(capsys.readouterr().out)
    assert len(data["laps"]) == 2 and data["damage"] == 0.0 and data["finished"]
    assert data["best_lap_s"] == pytest.approx(min(data["laps"]))
    assert 23.0 < data["reference_limit_s"] < 24.5
    assert data["best_lap_s"] > data["reference_limit_s"]
    assert data["gap_to_limit_pct"] == pytest.approx(
        100 * (data["best_lap_s"] / data["reference_limit_s"] - 1))
    assert data["gap_to_limit_pct"] < 15.0


def test_lines_show_json_and_plot(fake_catalog, capsys, tmp_path):
    plot = tmp_path / "map.png"
    cli.main(["lines", "show", "stadium", "--line", "centre", "--plot", str(plot), "--json"])
    centre = json.loads(capsys.readouterr().out)
    assert plot.stat().st_size > 10_000
    cli.main(["lines", "show", "stadium", "--line", "mincurv", "--json"])
    mincurv = json.loads(capsys.readouterr().out)
    assert mincurv["profile_lap_s"] == pytest.approx(mincurv["reference_limit_s"])
    assert centre["profile_lap_s"] > 1.03 * mincurv["profile_lap_s"]
    assert centre["sum_curvature_sq"] > mincurv["sum_curvature_sq"]
    assert centre["offset_min_m"] == 0.0 == centre["offset_max_m"]


def test_bad_line_and_plot_name_exit_2(fake_catalog, capsys):
    code, out, err = _run(capsys, ["bot", "stadium", "--line", "fastest"])
    assert code == 2 and "known lines" in err and out == ""
    code, _, err = _run(capsys, ["lines", "show", "stadium", "--plot", "map.gif"])
    assert code == 2 and ".png" in err


def test_table_rows_have_every_column(fake_catalog, capsys, monkeypatch):
    from formula_tourney.bots import baselines

    # The genetic search is exercised in test_lines; a cheap one keeps this test fast.
    real = baselines.reference_offsets

    def quick(track, kind, car=None, **kw):
        if kind == "genetic":
            from formula_tourney.lines.genetic import genetic_line

            seed = real(track, "mincurv", car)
            return genetic_line(track, car, population=8, generations=3,
                                seed_offsets_m=seed).offsets_m
        return real(track, kind, car, **kw)

    monkeypatch.setattr(baselines, "reference_offsets", quick)
    cli.main(["lines", "table", "--tracks", "stadium", "--json"])
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert row["track"] == "stadium"
    for key in ("follower_centre", "follower_mincurv", "genetic"):
        assert row[f"{key}_damage"] == 0.0
        assert math.isfinite(row[f"{key}_s"]) and row[f"{key}_s"] > row["reference_limit_s"]
    assert row["follower_mincurv_s"] < row["follower_centre_s"]
