"""The report's table model: a table as numbers (for bold and JSON) and display text.

Paper tables (``report.paper_tables``) fill ``ReportTable`` rows; renderers (``report.renderers``,
``report.html``) only read them, so every format shows the same text for the same cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

LAP_METRICS = ("bLT", "aLT")
"""Metrics whose best (lowest) value per column is bold."""
DASH = "-"
"""Text of an empty cell."""


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
        """Rows to show under one group alone: entrants that have a result there, every bot and
        the limit (so a per-group view is not padded with other parts' entrants)."""
        return [i for i, r in enumerate(self.rows)
                if r["kind"] != "entrant"
                or any(r["text"].get((group, m), DASH) != DASH for m in self.metrics[group])]

    def subset(self, groups: list[str], metrics: list[str] | None = None,
               suffix: str = "") -> ReportTable:
        """The same table restricted to some groups (and metrics), dropping entrant rows that
        have nothing in them; used to split the wide Table 1 into one LaTeX float per part."""
        keep = {g: [m for m in self.metrics[g] if metrics is None or m in metrics]
                for g in groups}
        sub = ReportTable(key=self.key + suffix, title=self.title, caption=self.caption,
                          groups=list(groups), metrics=keep, notes=list(self.notes),
                          records=[r for r in self.records if r.get("group") in groups],
                          lap_metrics=set(self.lap_metrics))
        shown = set().union(*(self.shown(g) for g in groups)) if groups else set()
        sub.rows = [r for i, r in enumerate(self.rows) if i in shown]
        return sub

    def text_frame(self) -> pd.DataFrame:
        cols = pd.MultiIndex.from_tuples(self.columns)
        data = [[r["text"].get(c, DASH) for c in self.columns] for r in self.rows]
        return pd.DataFrame(data, index=[r["label"] for r in self.rows], columns=cols)

    def to_json(self) -> dict[str, Any]:
        return {
            "key": self.key, "title": self.title, "caption": self.caption,
            "columns": [list(c) for c in self.columns],
            "rows": [
                {"label": r["label"], "kind": r["kind"], "family": r["family"],
                 "cells": {f"{g} | {m}": _num(r["values"].get((g, m), math.nan))
                           for g, m in self.columns},
                 "text": {f"{g} | {m}": r["text"].get((g, m), DASH) for g, m in self.columns}}
                for r in self.rows
            ],
            "notes": self.notes, "records": _jsonable(self.records),
        }


def _num(value: float) -> float | None:
    return float(value) if value is not None and np.isfinite(value) else None


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


def fmt_lap(value: float) -> str:
    return f"{value:.2f}" if np.isfinite(value) else DASH


def fmt_gap(value: float) -> str:
    return f"{value:+.1f}%" if np.isfinite(value) else DASH


def fmt_ci(low: float, high: float) -> str:
    return f"[{low:.2f}, {high:.2f}]" if np.isfinite(low) and np.isfinite(high) else DASH


def fmt_damage(value: float) -> str:
    return f"{value:.0f}" if np.isfinite(value) else DASH
