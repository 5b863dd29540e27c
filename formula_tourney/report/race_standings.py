"""Standings of a series of races: points, wins, mean finishing position with its CI, head to head.

The one definition of a race part's table (the CLI's ``race --races``, the race part's
``standings.json`` and the report all call :func:`standings`):

- **points**: ``points[p - 1]`` for finishing position ``p`` (default 25-18-15-12-10-8-6-4-2-1,
  nothing beyond); a retired car scores nothing, a lapped finisher scores its position.
- **mean position**: over the races, with a 95% percentile-bootstrap interval
  (``report.stats.mean_ci``, fixed seed: the same races always print the same table).
- **P(A ahead of B)**: the share of the races with both in which A finished ahead of B.
- **clean-race rate**: the share of races an entrant finished with no contact and zero damage.
- **contacts per race**: incidents it was in (``caused``: those blamed on it).
- Order: points, then wins, then mean position, then name.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from formula_tourney.errors import UserInputError
from formula_tourney.report.stats import mean_ci

DEFAULT_POINTS: tuple[float, ...] = (25, 18, 15, 12, 10, 8, 6, 4, 2, 1)


def race_points(row: dict[str, Any], points: Sequence[float]) -> float:
    """Points of one result row."""
    pos = int(row["position"])
    if row["status"] == "retired" or pos > len(points):
        return 0.0
    return float(points[pos - 1])


def standings(races: Sequence[dict[str, Any]],
              points: Sequence[float] = DEFAULT_POINTS) -> dict[str, Any]:
    """The table of ``races`` (``RaceResult.to_json()`` documents)."""
    if not races:
        raise UserInputError("standings: no races")
    if any(p < 0 or not math.isfinite(p) for p in points):
        raise UserInputError(f"points: expected finite values >= 0, got {list(points)}")
    names: list[str] = []
    for race in races:
        for row in race["results"]:
            if row["name"] not in names:
                names.append(row["name"])
    per: dict[str, dict[str, Any]] = {n: {"positions": [], "points": 0.0, "wins": 0, "clean": 0,
                                          "contacts": 0, "caused": 0, "dnf": 0, "races": 0,
                                          "sees_opponents": None, "kind": None} for n in names}
    position_in: list[dict[str, int]] = []
    for race in races:
        pos_here = {}
        for row in race["results"]:
            e = per[row["name"]]
            e["races"] += 1
            e["positions"].append(int(row["position"]))
            e["points"] += race_points(row, points)
            e["wins"] += int(row["position"] == 1 and row["status"] != "retired")
            e["clean"] += int(row["status"] == "finished" and row["contacts"] == 0
                              and row["damage"] == 0)
            e["contacts"] += int(row["contacts"])
            e["caused"] += int(row["caused"])
            e["dnf"] += int(row["status"] == "retired")
            e["sees_opponents"] = bool(row["sees_opponents"])
            e["kind"] = row["kind"]
            pos_here[row["name"]] = int(row["position"])
        position_in.append(pos_here)
    ahead: dict[str, dict[str, float | None]] = {}
    for a in names:
        ahead[a] = {}
        for b in names:
            if a == b:
                continue
            both = [r for r in position_in if a in r and b in r]
            ahead[a][b] = (sum(r[a] < r[b] for r in both) / len(both)) if both else None
    rows = []
    for name in names:
        e = per[name]
        ci = mean_ci(e["positions"])
        rows.append({
            "name": name, "kind": e["kind"], "sees_opponents": e["sees_opponents"],
            "races": e["races"], "points": e["points"], "wins": e["wins"],
            "mean_position": ci.value, "position_low": _num(ci.low), "position_high": _num(ci.high),
            "clean_rate": e["clean"] / e["races"], "contacts_per_race": e["contacts"] / e["races"],
            "caused_per_race": e["caused"] / e["races"], "dnf": e["dnf"],
        })
    rows.sort(key=lambda r: (-r["points"], -r["wins"], r["mean_position"], r["name"]))
    for rank, row in enumerate(rows, start=1):
        row["rank"] = rank
    return {"races": len(races), "points_table": [float(p) for p in points], "rows": rows,
            "ahead": ahead}


def _num(x: float) -> float | None:
    return x if math.isfinite(x) else None


STANDINGS_COLUMNS = ["rank", "driver", "points", "wins", "mean pos (95% CI)", "clean",
                     "contacts/race", "caused/race", "DNF"]


def standings_rows(table: dict[str, Any]) -> list[list[str]]:
    """The standings as text rows (terminal and Markdown): a blind model is marked."""
    out = []
    for r in table["rows"]:
        ci = ("" if r["position_low"] is None else
              f" [{r['position_low']:.2f}, {r['position_high']:.2f}]")
        blind = " (blind)" if r["kind"] == "model" and not r["sees_opponents"] else ""
        out.append([str(r["rank"]), r["name"] + blind, f"{r['points']:g}", str(r["wins"]),
                    f"{r['mean_position']:.2f}{ci}", f"{r['clean_rate']:.0%}",
                    f"{r['contacts_per_race']:.2f}", f"{r['caused_per_race']:.2f}", str(r["dnf"])])
    return out


def markdown(table: dict[str, Any]) -> str:
    """The standings and the head-to-head matrix as Markdown."""
    lines = ["| " + " | ".join(STANDINGS_COLUMNS) + " |",
             "|" + "|".join("---" for _ in STANDINGS_COLUMNS) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in standings_rows(table)]
    names = [r["name"] for r in table["rows"]]
    lines += ["", "P(row finishes ahead of column):", "",
              "| | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for a in names:
        cells = ["-" if a == b else ("-" if table["ahead"][a][b] is None
                                     else f"{table['ahead'][a][b]:.2f}") for b in names]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
