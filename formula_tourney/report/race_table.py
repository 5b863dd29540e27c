"""Race parts in the report: each finished series' standings as a report table, and its figures.

Reads ``<part>/_races/`` of every race series the index knows (files only, through
``results.folder.RaceFolder``) and scores it with ``report.race_standings.standings``, the one
definition of the table, so the report, ``formula-tourney races`` and ``race --races`` print
the same numbers for the same files. A series that is not complete (running, failed, a race
file missing) is listed among the report's problems rather than shown half scored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from formula_tourney.report.race_figures import plot_race
from formula_tourney.report.race_standings import STANDINGS_COLUMNS, standings, standings_rows
from formula_tourney.report.table_model import DASH, ReportTable
from formula_tourney.results.folder import RaceFolder
from formula_tourney.results.index import read_index, rows_of_kind
from formula_tourney.tourney.kinds import RACE

STANDINGS_GROUP = "standings"
AHEAD_GROUP = "P(row finishes ahead of column)"


@dataclass
class RacePart:
    """One finished series: its ``series.json``, its race documents and their standings."""

    part: str
    series: dict[str, Any]
    races: list[dict[str, Any]]
    standings: dict[str, Any]


def load_race_parts(root: str | Path, part: str | None, problems: list[str]) -> list[RacePart]:
    """The finished series of the tournament in ``root`` (of ``part`` only when given), in
    part order; incomplete ones go to ``problems``."""
    root = Path(root)
    index = read_index(root)
    rows = rows_of_kind(index["jobs"], RACE.name, RACE.columns)
    if rows.empty:
        return []
    order = {str(p): i for i, p in zip(index["parts"]["position"], index["parts"]["part"],
                                       strict=True)}
    out = []
    for row in sorted(rows.to_dict("records"), key=lambda r: (order.get(r["part"], 1e9),
                                                              r["part"])):
        if part is not None and row["part"] != part:
            continue
        folder = RaceFolder(root / str(row["path"]))
        races = int(row["races"])
        if row["status"] != "done" or not folder.is_complete(races):
            have = len(folder.race_numbers())
            problems.append(f"race part {row['part']}: series {row['status']}, {have} of "
                            f"{races} races on disk" + (f" ({row['reason']})"
                                                        if row.get("reason") else ""))
            continue
        series = folder.series()
        docs = folder.races()[:races]
        out.append(RacePart(row["part"], series, docs, standings(docs, series["points"])))
    return out


def race_table(item: RacePart) -> ReportTable:
    """The standings of one series (every column of ``race_standings``) and the head-to-head
    matrix, as one report table; ``records`` carry the unrounded numbers."""
    table = item.standings
    names = [r["name"] for r in table["rows"]]
    points = "-".join(f"{p:g}" for p in table["points_table"])
    out = ReportTable(
        key=f"races-{item.part}",
        title=f"Race part {item.part}: {table['races']} races on {item.series['track']}",
        caption=(f"Points {points}; mean finishing position with its 95% bootstrap CI; clean = "
                 "finished with no contact and no damage; contacts and caused per race; "
                 "(blind) = a model trained without the opponent sensors."),
        groups=[STANDINGS_GROUP, AHEAD_GROUP],
        metrics={STANDINGS_GROUP: [c for c in STANDINGS_COLUMNS if c not in ("rank", "driver")],
                 AHEAD_GROUP: names},
        lap_metrics=set(),
    )
    keys = ("points", "wins", "mean_position", "clean_rate", "contacts_per_race",
            "caused_per_race", "dnf")
    for r, text in zip(table["rows"], standings_rows(table), strict=True):
        row = out.add_row(text[1], "bot" if r["kind"] == "bot" else "entrant")
        for metric, cell, key in zip(out.metrics[STANDINGS_GROUP], text[2:], keys, strict=True):
            row["text"][(STANDINGS_GROUP, metric)] = cell
            row["values"][(STANDINGS_GROUP, metric)] = float(r[key])
        for other in names:
            p = None if other == r["name"] else table["ahead"][r["name"]][other]
            row["text"][(AHEAD_GROUP, other)] = DASH if p is None else f"{p:.2f}"
            row["values"][(AHEAD_GROUP, other)] = math.nan if p is None else float(p)
    out.records = [{"group": STANDINGS_GROUP, **r} for r in table["rows"]]
    out.records += [{"group": AHEAD_GROUP, "name": a, "ahead": dict(b)}
                    for a, b in table["ahead"].items()]
    return out


def race_figures(items: list[RacePart], out_dir: Path) -> dict[str, list[Path]]:
    """Position and gap-to-leader by lap of every race, ``<part>-race-<k>-positions|gaps``."""
    figures: dict[str, list[Path]] = {}
    for item in items:
        for k, doc in enumerate(item.races):
            for path in plot_race(doc, Path(out_dir) / f"{item.part}-race-{k}"):
                figures.setdefault(path.stem, []).append(path)
    return figures
