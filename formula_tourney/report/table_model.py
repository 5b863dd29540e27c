"""The report's table model: a table as numbers (for bold and JSON) and display text.

Paper tables (``report.paper_tables``) fill ``ReportTable`` rows; renderers (``report.renderers``,
``report.html``) only read them, so every format shows the same text for the same cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

LAP_METRICS = ("bLT", "aLT")
"""Metrics whose best (lowest) value per column is bold."""
DASH = "-"
"""Text of an empty cell of a table that does not say why it is empty."""

# Marks of empty cells: a cell without a number says why it has none, and every table that
# shows a mark explains it in a legend (``ReportTable.legend``), in every format.
DNF = "DNF"
NOT_APPLICABLE = "n/a"
NOT_DRIVEN = "not driven"
NOT_RUN = "not run"
NO_RESULT = "no result"
NOT_TESTED = "not tested"
NO_GENERAL = "none"
NO_LIMIT = "no limit"
LEADER = "leader"
CELL_MARKS: dict[str, str] = {
    DNF: "runs exist but none finished a lap without damage",
    NO_RESULT: "no run of this entrant here has written results (pending, running or failed: "
               "see the problems list)",
    NOT_RUN: "the tournament did not enter this entrant here",
    NOT_DRIVEN: "no baseline drive of this bot on this track and line in this part (the "
                "tournament did not ask for one; the reference limit comes with a track's "
                "baseline drives)",
    NOT_TESTED: "not tested on this track",
    NO_LIMIT: "no reference limit for this track (it comes with the track's baseline drives)",
    NO_GENERAL: "no checkpoint qualifies as a general model",
    LEADER: "the entrant with the best aLT here, which every other row is compared with",
    NOT_APPLICABLE: "no such number for this row (a bot or the limit has one lap and no runs; "
                    "a CI needs two runs with a clean lap)",
}
"""Each mark an empty cell may show, and what it means."""


@dataclass
class ReportTable:
    """A table as numbers (for bold and JSON) and display text, with two-level columns."""

    key: str
    title: str
    caption: str
    groups: list[str]
    metrics: dict[str, list[str]]
    rows: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    records: list[dict[str, Any]] = field(default_factory=list)
    lap_metrics: set[str] = field(default_factory=lambda: set(LAP_METRICS))
    """Metrics holding lap times: the lowest per column is bold."""
    glossary: dict[str, str] = field(default_factory=dict)
    """What each metric means; the caption defines the metrics a view shows, and only those."""

    def add_row(self, label: str, kind: str, family: str = "") -> dict[str, Any]:
        row = {"label": label, "kind": kind, "family": family, "values": {}, "text": {}}
        self.rows.append(row)
        return row

    @property
    def columns(self) -> list[tuple[str, str]]:
        return [(g, m) for g in self.groups for m in self.metrics[g]]

    @property
    def empty(self) -> bool:
        return not self.rows or not self.groups

    def best_cells(self) -> set[tuple[int, str, str]]:
        """(row index, group, metric) of the lowest bLT/aLT per column among entrants and bots.

        The reference limit is excluded: it is a bound, not a competitor.
        """
        best: set[tuple[int, str, str]] = set()
        for group, metric in self.columns:
            if metric not in self.lap_metrics:
                continue
            vals = [(i, r["values"].get((group, metric), math.nan)) for i, r in
                    enumerate(self.rows) if r["kind"] != "limit"]
            finite = [(i, v) for i, v in vals if np.isfinite(v)]
            if not finite:
                continue
            low = min(v for _, v in finite)
            best.update((i, group, metric) for i, v in finite if math.isclose(v, low))
        return best

    def shown(self, group: str) -> list[int]:
        """Rows to show under one group alone: entrants entered there, every bot and the limit
        (so a per-group view is not padded with other parts' entrants)."""
        return [i for i, r in enumerate(self.rows)
                if r["kind"] != "entrant"
                or any(r["text"].get((group, m), DASH) not in (DASH, NOT_RUN)
                       for m in self.metrics[group])]

    @property
    def full_caption(self) -> str:
        """The caption and the meaning of each metric this table shows (a LaTeX float that
        leaves some metrics out does not describe them)."""
        shown = dict.fromkeys(m for g in self.groups for m in self.metrics[g])
        terms = [f"{m}: {self.glossary[m]}" for m in shown if m in self.glossary]
        return " ".join([self.caption, *(["; ".join(terms) + "."] if terms else [])])

    def legend(self, by_group: bool = False) -> dict[str, str]:
        """The empty-cell marks this table shows, with what each means: in every cell, or
        (``by_group``) in the per-group views, which show only the rows ``shown`` there."""
        used = {self.rows[i]["text"].get((g, m), DASH)
                for g in self.groups
                for i in (self.shown(g) if by_group else range(len(self.rows)))
                for m in self.metrics[g]}
        return {mark: meaning for mark, meaning in CELL_MARKS.items() if mark in used}

    def footnotes(self, by_group: bool = False) -> list[str]:
        """The notes, then one line explaining the empty-cell marks shown (``legend``)."""
        legend = self.legend(by_group)
        line = "; ".join(f"{mark}: {meaning}" for mark, meaning in legend.items())
        return [*self.notes, *([f"Cells without a number: {line}."] if legend else [])]

    def subset(self, groups: list[str], metrics: list[str] | None = None,
               suffix: str = "") -> ReportTable:
        """The same table restricted to some groups (and metrics), dropping entrant rows that
        have nothing in them; used to split the wide Table 1 into one LaTeX float per part."""
        keep = {g: [m for m in self.metrics[g] if metrics is None or m in metrics]
                for g in groups}
        sub = ReportTable(key=self.key + suffix, title=self.title, caption=self.caption,
                          groups=list(groups), metrics=keep, notes=list(self.notes),
                          records=[r for r in self.records if r.get("group") in groups],
                          lap_metrics=set(self.lap_metrics), glossary=dict(self.glossary))
        shown = set().union(*(self.shown(g) for g in groups)) if groups else set()
        sub.rows = [r for i, r in enumerate(self.rows) if i in shown]
        return sub

    def to_json(self) -> dict[str, Any]:
        """Every cell as a number (a float; a CI as ``[low, high]``; runs as
        ``{"clean": k, "planned": n}``) or null, beside the text shown; ``legend`` explains
        the marks of the empty cells."""
        return {
            "key": self.key, "title": self.title, "caption": self.full_caption,
            "columns": [list(c) for c in self.columns],
            "rows": [
                {"label": r["label"], "kind": r["kind"], "family": r["family"],
                 "cells": {f"{g} | {m}": _jsonable(r["values"].get((g, m), math.nan))
                           for g, m in self.columns},
                 "text": {f"{g} | {m}": r["text"].get((g, m), DASH) for g, m in self.columns}}
                for r in self.rows
            ],
            "notes": self.notes, "legend": self.legend(), "records": _jsonable(self.records),
        }


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def fmt_lap(value: float, empty: str = DASH) -> str:
    return f"{value:.2f}" if np.isfinite(value) else empty


def fmt_gap(value: float, empty: str = DASH) -> str:
    return f"{value:+.1f}%" if np.isfinite(value) else empty


def fmt_ci(low: float, high: float, empty: str = DASH) -> str:
    return f"[{low:.2f}, {high:.2f}]" if np.isfinite(low) and np.isfinite(high) else empty


def ci_value(low: float, high: float) -> list[float] | float:
    """A CI cell's number: ``[low, high]``, or nan (null in JSON) where there is none."""
    return [float(low), float(high)] if np.isfinite(low) and np.isfinite(high) else math.nan


def fmt_damage(value: float, empty: str = DASH) -> str:
    return f"{value:.0f}" if np.isfinite(value) else empty
