"""What the tournament cost, next to what ``run --estimate`` said it would cost.

Measured: per job the index's ``wall_s`` (the job in its one-thread worker, from start to its
summary: its CPU time on a core of its own; the worker's imports count in its first job) and
``train_seconds`` (the training loop alone, ``summary.json``'s ``seconds``); per part and in
total the wall time from the first job's start to the last one's end (``started_at``,
``finished_at``, to the second). Estimated: ``estimate.json`` (``results.layout.ESTIMATE_FILE``),
written by the first ``run --estimate``.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any

import pandas as pd

from formula_tourney.report.load import TournamentData
from formula_tourney.report.table_model import DASH, ReportTable
from formula_tourney.results.folder import CorruptResultError, read_json_file
from formula_tourney.results.layout import ESTIMATE_FILE

GROUP = "cost"
METRICS = ["jobs", "CPU est.", "CPU ~95%", "CPU measured", "train s", "wall est.",
           "wall measured"]


def _s(value: float) -> str:
    return f"{value:.1f} s" if math.isfinite(value) else DASH


def _span_s(jobs: pd.DataFrame) -> float:
    """Seconds from the first job's start to the last job's end (nan if unknown)."""
    try:
        starts = [datetime.fromisoformat(str(v).replace("Z", "+00:00"))
                  for v in jobs["started_at"].dropna()]
        ends = [datetime.fromisoformat(str(v).replace("Z", "+00:00"))
                for v in jobs["finished_at"].dropna()]
    except ValueError:
        return math.nan
    if not starts or not ends:
        return math.nan
    return (max(ends) - min(starts)).total_seconds()


def read_estimate(data: TournamentData) -> dict[str, Any] | None:
    """The stored estimate, None when the tournament was run without ``--estimate`` (an
    unreadable one is a problem line)."""
    path = data.root / ESTIMATE_FILE
    if not path.is_file():
        return None
    try:
        est = read_json_file(path, "the cost estimate")
    except CorruptResultError as err:
        data.problems.append(str(err))
        return None
    return est if isinstance(est, dict) else None


def measured(jobs: pd.DataFrame) -> dict[str, float]:
    """Jobs, summed job seconds, summed training-loop seconds and wall span of ``jobs``."""
    wall = pd.to_numeric(jobs.get("wall_s"), errors="coerce")
    train = pd.to_numeric(jobs.get("train_seconds"), errors="coerce")
    return {"jobs": float(len(jobs)), "cpu_s": float(wall.sum(min_count=1)),
            "train_s": float(train.sum(min_count=1)), "wall_s": _span_s(jobs)}


def cost_table(data: TournamentData) -> ReportTable:
    """One row per part and a total: the estimate (if stored) and the measured cost."""
    est = read_estimate(data)
    table = ReportTable(
        key="cost", title="Cost: estimated before the run vs measured",
        caption=(
            "CPU est.: run --estimate's CPU time (s, ~95% range from the spread of the rates "
            "measured; the total adds each worker's start); CPU measured: summed job seconds of "
            "one-thread workers (wall_s in the index); train s: the training loops alone; wall: "
            "first job start to last job end."
        ),
        groups=[GROUP], metrics={GROUP: list(METRICS)},
    )
    table.lap_metrics = set()
    jobs = data.jobs
    parts = {str(p["part"]): p for p in (est or {}).get("parts", [])}
    names = list(dict.fromkeys([*data.part_order(), *parts]))
    rows: list[tuple[str, dict[str, Any] | None, pd.DataFrame]] = [
        (name, parts.get(name), jobs.loc[jobs["part"] == name]) for name in names]
    total = (est or {}).get("total")
    rows.append(("total", total, jobs))
    for name, e, sub in rows:
        m = measured(sub)
        row = table.add_row(name, "entrant" if name != "total" else "limit")
        e = e or {}
        cpu_e = float(e.get("cpu_s", math.nan))
        text = {
            "jobs": f"{int(m['jobs'])}" + (f" (est. {e['jobs']})" if "jobs" in e else ""),
            "CPU est.": _s(cpu_e),
            "CPU ~95%": (f"{e['cpu_s_low']:.1f}-{e['cpu_s_high']:.1f} s"
                         if "cpu_s_low" in e else DASH),
            "CPU measured": _s(m["cpu_s"]) + (
                f" ({100 * (m['cpu_s'] / cpu_e - 1):+.0f}%)"
                if math.isfinite(cpu_e) and cpu_e > 0 and math.isfinite(m["cpu_s"]) else ""),
            "train s": _s(m["train_s"]),
            "wall est.": _s(float(e.get("wall_s", math.nan))),
            "wall measured": _s(m["wall_s"]),
        }
        for metric in METRICS:
            row["text"][(GROUP, metric)] = text[metric]
        table.records.append({"part": name, "estimate": e or None, "measured": m})
    if est is None:
        table.notes.append(f"no {ESTIMATE_FILE}: run the tournament with --estimate to keep an "
                           "estimate to compare with")
    return table
