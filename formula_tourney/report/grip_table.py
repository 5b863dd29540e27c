"""The grip table: lap time over the reference limit at each grip a study tested at.

A study can train on one grip and test on others (``schedule.test_grip_scales``). Lap
times at different grips only compare through the reference limit *at that grip*, which the
trainer computed once per job, track and grip and stored beside the tests
(``tests.parquet`` ``reference_limit_s``); this table reads that stored number, so a figure or
another table that shows the same limit shows the same value. Its lap metrics are those of
Table 1 (``paper_tables.entry_stats`` on ``results.metrics`` model and run tables), restricted
to the tests at one grip. The table exists only when some run tested at more than one grip.
"""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from formula_tourney.lines.kinds import line_label
from formula_tourney.report.paper_tables import (
    LIMIT_LABEL,
    Context,
    entry_stats,
    fill_entry,
    ordered_rows,
)
from formula_tourney.report.table_model import DASH, ReportTable, fmt_lap
from formula_tourney.results import metrics

GRIP_METRICS = ["bLT", "aLT", "lap/limit", "gap", "runs"]
"""Per grip: best and average best lap, bLT over the limit at that grip, the gap, runs."""


def grip_label(part: str, track: str, reference: str, lac: bool, grip: float) -> str:
    return (f"{part}: {track} {line_label(reference)}" + (" + LAC" if lac else "")
            + f" @ grip {grip:g}")


def _groups(ctx: Context) -> dict[str, dict[str, Any]]:
    """One group per (part, track, line, LAC, grip) of the jobs that tested at several grips."""
    tests = ctx.data.grip_tests
    groups: dict[str, dict[str, Any]] = {}
    if tests.empty:
        return groups
    jobs = ctx.jobs.set_index(ctx.jobs["job_id"].astype(str))
    for job_id, rows in tests.groupby(tests["job_id"].astype(str), sort=False):
        grips = pd.to_numeric(rows["grip_scale"], errors="coerce").dropna().unique()
        if len(grips) < 2 or job_id not in jobs.index:
            continue
        job = jobs.loc[job_id]
        part = str(job["part"])
        for track in dict.fromkeys(rows["track"].astype(str)):
            for grip in sorted(float(g) for g in grips):
                label = grip_label(part, track, job["reference"], bool(job["lac"]), grip)
                grp = groups.setdefault(label, {"part": part, "track": track, "grip": grip,
                                                "jobs": []})
                grp["jobs"].append(job_id)
    order = {p: i for i, p in enumerate(ctx.data.part_order())}
    return dict(sorted(groups.items(), key=lambda kv: (order.get(kv[1]["part"], len(order)),
                                                        kv[1]["track"], -kv[1]["grip"])))


def grip_table(ctx: Context) -> ReportTable:
    """Lap time / reference limit per grip: entrants by row, one column group per
    part, track, line and grip, and the limit at that grip as the last row."""
    table = ReportTable(
        key="grip", title="Lap time over the reference limit at each grip",
        caption=(
            "Runs tested at several grips (schedule.test_grip_scales): bLT and aLT (s, models "
            "with 0 damage at that grip), lap/limit: bLT over the reference limit recomputed "
            "at that grip (QSS lap on the minimum-curvature line with every friction times the "
            "grip), gap: the same in percent; runs: runs with a clean lap / runs."
        ),
        groups=[], metrics={},
    )
    groups = _groups(ctx)
    if not groups:
        return table
    table.groups = list(groups)
    table.metrics = {g: list(GRIP_METRICS) for g in table.groups}
    tests = ctx.data.grip_tests
    jobs = ctx.jobs.loc[ctx.jobs["job_id"].astype(str).isin(
        {j for g in groups.values() for j in g["jobs"]})]
    rows = {key: table.add_row(key, "entrant", fam) for key, fam in ordered_rows(jobs,
                                                                                  ctx.row_keys)}
    limits: dict[str, float] = {}
    for label, grp in groups.items():
        track, grip = grp["track"], grp["grip"]
        limit = metrics.stored_limit_s(tests, track, grip)
        limits[label] = limit
        sel = metrics.at_grip(tests, grip)
        sel = sel.loc[sel["job_id"].astype(str).isin(grp["jobs"])
                      & (sel["track"].astype(str) == track)]
        runs = metrics.run_table(metrics.model_table(sel))
        by_row: dict[str, list[str]] = {}
        for job_id in dict.fromkeys(grp["jobs"]):
            by_row.setdefault(ctx.row_keys[job_id], []).append(job_id)
        for key, row in rows.items():
            job_ids = by_row.get(key, [])
            if not job_ids:
                continue
            st = entry_stats(runs.loc[runs["job_id"].isin(job_ids)], len(job_ids), limit)
            fill_entry(row, label, st, GRIP_METRICS)
            ratio = metrics.limit_ratio(st["bLT"], limit)
            row["values"][(label, "lap/limit")] = ratio
            row["text"][(label, "lap/limit")] = f"{ratio:.3f}" if math.isfinite(ratio) else DASH
            table.records.append({"group": label, "row": key, "part": grp["part"],
                                  "track": track, "grip_scale": grip,
                                  "reference_limit_s": limit, "lap_over_limit": ratio, **st})
    row = table.add_row(LIMIT_LABEL, "limit")
    for label, limit in limits.items():
        row["values"][(label, "bLT")] = limit
        row["text"][(label, "bLT")] = fmt_lap(limit)
        row["values"][(label, "lap/limit")] = 1.0 if math.isfinite(limit) else math.nan
        row["text"][(label, "lap/limit")] = "1.000" if math.isfinite(limit) else DASH
    return table
