"""What the terminal shows: help text printed as written (never read as markup), race tables
that keep every car's name whole on an 80-column console, and messages that stay one line."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import typer.main
from rich.console import Console
from rich.text import Text

from formula_tourney.cli import app, main
from formula_tourney.commands.output import message
from formula_tourney.commands.race import RACE_COLUMNS, _render, _render_series, race_table_rows
from formula_tourney.report.race_standings import standings, standings_rows


def _commands(command: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[str, Any]]:
    yield " ".join(path), command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, (*path, name))


def test_no_help_text_is_read_as_markup() -> None:
    """typer prints help through rich: "[claims]" vanished and ``run FILE`` kept its quotes.
    Every command's and option's help must print as written."""
    bad = []
    for path, command in _commands(typer.main.get_command(app)):
        for name, text in [("help", command.help or ""),
                           *((p.name, getattr(p, "help", None) or "") for p in command.params)]:
            shown = Text.from_markup(text).plain
            if shown != text.replace("\\[", "[") or "``" in text:
                bad.append(f"{path or 'formula-tourney'} {name}: {text[:80]!r}")
    assert bad == []


def test_report_help_shows_claims_literally(capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    try:
        main(["report", "--help"])
    except SystemExit as exc:
        assert exc.code in (0, None)
    out = capsys.readouterr().out
    assert "the tournament file's [claims], else the paper's findings" in " ".join(out.split())


def _car(name: str, position: int, **extra: Any) -> dict[str, Any]:
    return {"name": name, "position": position, "grid": position, "status": "finished",
            "reason": None, "time_s": 110.0 + position, "laps_behind": 0,
            "gap_s": float(position), "sees_opponents": True, "kind": "model", "laps": 3,
            "best_lap_s": 35.0 + position / 10, "damage": 0.0, "contacts": 0, "caused": 0,
            "overtakes": 0, **extra}


def test_race_table_keeps_the_seeds_apart_at_80_columns() -> None:
    """A piped race table at 80 columns showed "WIN4…" and "(bli…" for every model."""
    doc = {"track": "oval", "laps": 3, "start": "standing", "seed": 0, "incidents": [],
           "overtakes": [], "results": [
               _car("WIN4-MOT/seed-0", 1),
               _car("WIN4-MOT/seed-1", 2, sees_opponents=False),
               _car("follower", 3, kind="bot"),
               _car("WIN1-RC-LAC/seed-0", 4, status="retired", reason="off_track"),
           ]}
    console = Console(width=80, record=True, color_system=None)
    _render(doc)(console)
    text = console.export_text()
    assert "…" not in text
    rows = race_table_rows(doc)
    for row in rows:  # every cell of every row whole, on one line
        line = next(line for line in text.splitlines() if f" {row[1]} " in line)
        for cell in row:
            assert cell in line, (cell, line)
    assert "WIN4-MOT/seed-1 (blind)" in text and "DNF (off_track)" in text
    assert all(col in text for col in RACE_COLUMNS)


def test_standings_keep_the_seeds_apart_at_80_columns() -> None:
    names = ["WIN4-MOT/seed-0", "WIN4-MOT/seed-1", "WIN1-RC-LAC/seed-0", "follower"]
    docs = [{"track": "oval", "laps": 1, "start": "standing", "seed": k, "incidents": [],
             "overtakes": [],
             "results": [_car(n, 1 + (i + k) % 4, kind="bot" if n == "follower" else "model")
                         for i, n in enumerate(names)]} for k in range(3)]
    table = standings(docs)
    console = Console(width=80, record=True, color_system=None)
    _render_series(table, docs)(console)
    text = console.export_text()
    assert "…" not in text
    for row in standings_rows(table):
        line = next(line for line in text.splitlines() if f" {row[1]} " in line
                    and row[2] in line)
        assert all(cell in line for cell in row), line


def test_a_long_message_stays_one_line(capsys) -> None:
    """A message naming a long path is one line on an 80-column console (not a terminal):
    rich used to break it at a space, so a path's message split and a grep for it failed."""
    path = "/tmp/pytest-of-someone/pytest-123/popen-gw0/test_import_a_tree_table_json_0/tracks"
    message(f"imported 0 of 3 track file(s) from {path}; 3 failed")
    err = capsys.readouterr().err
    assert err == f"imported 0 of 3 track file(s) from {path}; 3 failed\n"
