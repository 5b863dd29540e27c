"""Figures of a race: position by lap and gap to the leader by lap, one line per car.

Both read the race document's ``lap_chart`` (position and gap of each car as it crossed the
line), the numbers the race table was made from; lap 0 is the grid.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from formula_tourney.report.plots import save_figure, subplots, wrap


def _series(doc: dict[str, Any]) -> dict[str, tuple[list[int], list[int], list[float | None]]]:
    grid = {r["name"]: r["grid"] for r in doc["results"]}
    out: dict[str, tuple[list[int], list[int], list[float | None]]] = {
        name: ([0], [g], [None]) for name, g in sorted(grid.items(), key=lambda kv: kv[1])}
    for row in doc["lap_chart"]:
        laps, pos, gaps = out[row["name"]]
        laps.append(row["lap"])
        pos.append(row["position"])
        gaps.append(row["gap_s"])
    return out


def plot_race(doc: dict[str, Any], out_base: Path) -> list[Path]:
    """``<out_base>-positions`` and ``<out_base>-gaps`` (.png and .pdf)."""
    series = _series(doc)
    title = f"{doc['track']}, {doc['laps']} laps, seed {doc['seed']}"
    paths = []
    fig, ax = subplots(figsize=(9, 4.5))
    for name, (laps, pos, _) in series.items():
        ax.plot(laps, pos, marker="o", label=wrap(name, 2.2, 7))
    ax.invert_yaxis()
    ax.set_xlabel("lap")
    ax.set_ylabel("position")
    ax.set_yticks(range(1, len(series) + 1))
    ax.set_title(wrap(f"Position by lap: {title}", 6.0, 12))
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    paths += save_figure(fig, out_base.with_name(out_base.name + "-positions"))
    fig, ax = subplots(figsize=(9, 4.5))
    for name, (laps, _, gaps) in series.items():
        pts = [(lap, g) for lap, g in zip(laps, gaps, strict=True) if g is not None]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o",
                    label=wrap(name, 2.2, 7))
    ax.set_xlabel("lap")
    ax.set_ylabel("gap to the leader (s)")
    ax.set_title(wrap(f"Gap to the leader: {title}", 6.0, 12))
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    paths += save_figure(fig, out_base.with_name(out_base.name + "-gaps"))
    return paths
