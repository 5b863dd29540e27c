"""The time-to-competence table: CPU-seconds of training until entrants lap cleanly and beat bots.

A part with a CPU budget (``budget_cpu_s``, docs/tourney.md) races the follower on the centre
and on the min-curvature line as baselines, and its runs record the CPU-seconds of each test
round. Each run's milestones come from ``results.competence`` (the one computation the
benchmark ``benchmarks/time_to_competence.py`` reads too); this table shows, per entrant, the
median over seeds with a miss counted as infinite and how many seeds reached each milestone,
the median best lap over the reference limit, and the clean-start rate. Only parts whose
finished runs have a budget, timed tests and both bots' laps get a column group: no other
table or tournament shows it.
"""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from formula_tourney.report.paper_tables import Context, group_label, ordered_rows
from formula_tourney.report.table_model import DASH, ReportTable
from formula_tourney.results import competence
from formula_tourney.results.folder import CorruptResultError, JobFolder

METRICS = {
    "first_clean_lap": "clean lap",
    "beat_centre_bot": "beat centre bot",
    "beat_mincurv_bot": "beat best bot",
}
"""Column of each milestone (``results.competence.MILESTONES``)."""
RATIO = "best/limit"
CLEAN_STARTS = "clean starts"
COMPETENCE_METRICS = [*METRICS.values(), RATIO, CLEAN_STARTS]


def part_bots(baselines: pd.DataFrame, part: str, track: str) -> competence.Bots | None:
    """The follower's laps on the two lines of ``track`` in ``part``, or None when one is
    missing (not driven yet, or no clean lap)."""
    if baselines.empty:
        return None
    rows = baselines.loc[(baselines["part"].astype(str) == part)
                         & (baselines["track"].astype(str) == track)
                         & (baselines["bot"].astype(str) == "follower")]
    laps = {str(r["reference"]): float(pd.to_numeric(r["best_lap_s"], errors="coerce"))
            for _, r in rows.iterrows()}  # fmt: skip
    limits = pd.to_numeric(rows["reference_limit_s"], errors="coerce").dropna()
    centre, mincurv = laps.get("centre", math.nan), laps.get("mincurv", math.nan)
    if not (math.isfinite(centre) and math.isfinite(mincurv)) or limits.empty:
        return None
    return competence.Bots(centre, mincurv, float(limits.iloc[0]))


def _budgeted_runs(ctx: Context) -> dict[str, dict[str, Any]]:
    """One group per (part, key track, line, LAC) of finished runs with a CPU budget, timed
    tests and both bots: its bots, budget and each run's milestones."""
    data = ctx.data
    groups: dict[str, dict[str, Any]] = {}
    for _, job in ctx.jobs.iterrows():
        job_id = str(job["job_id"])
        config = data.configs.get(job_id) or {}
        schedule = config.get("schedule") or {}
        if job["status"] != "done" or schedule.get("budget_cpu_s") is None:
            continue
        folder = JobFolder(data.job_dir(job_id))
        try:
            track = str(folder.summary()["track"])  # the key track, where milestones count
            bots = part_bots(data.baselines, str(job["part"]), track)
            if bots is None or not competence.timed(folder.tests()):
                continue
            run = competence.job_competence(folder, track, bots)
        except (CorruptResultError, KeyError) as err:
            data.problems.append(f"{job_id}: no time to competence: {err}")
            continue
        label = group_label(str(job["part"]), track, str(config.get("reference")),
                            bool(config.get("lac")))
        group = groups.setdefault(label, {"part": str(job["part"]), "track": track,
                                          "bots": bots, "budget_cpu_s": schedule["budget_cpu_s"],
                                          "stop_at": schedule.get("stop_at", "none"),
                                          "runs": {}})
        group["runs"][job_id] = {"job_id": job_id, "seed": int(job["seed"]), **run}
    order = {p: i for i, p in enumerate(data.part_order())}
    return dict(sorted(groups.items(), key=lambda kv: order.get(kv[1]["part"], len(order))))


def _cell(median: float, reached: int, seeds: int) -> str:
    return f"{'miss' if not math.isfinite(median) else f'{median:.1f}'} ({reached}/{seeds})"


def competence_table(ctx: Context) -> ReportTable:
    """Median CPU-s to each milestone per entrant (rows) and budgeted part (column groups)."""
    table = ReportTable(
        key="competence", title="Time to competence: CPU-seconds of training to each milestone",
        caption=(
            "Parts with a CPU budget (budget_cpu_s): per entrant, the median over seeds of the "
            "CPU-seconds of training (the run's process, from the start of training) until the "
            "first test round with a clean lap (0 damage over all starts), a clean lap faster "
            "than the follower on the centre line, and one faster than the follower on the "
            "min-curvature line (the best bot; with demonstrations also faster than the "
            "demonstrator). A miss counts as infinite (miss: the median missed); (n/N): seeds "
            "that reached it. best/limit: median best clean lap over the reference limit; clean "
            "starts: median share of test rounds from the first clean lap on in which two "
            "thirds of the starts lapped without damage."
        ),
        groups=[], metrics={}, lap_metrics={*METRICS.values(), RATIO},
    )
    groups = _budgeted_runs(ctx)
    if not groups:
        return table
    table.groups = list(groups)
    table.metrics = {g: list(COMPETENCE_METRICS) for g in table.groups}
    job_ids = {j for g in groups.values() for j in g["runs"]}
    jobs = ctx.jobs.loc[ctx.jobs["job_id"].astype(str).isin(job_ids)]
    rows = {key: table.add_row(key, "entrant", fam)
            for key, fam in ordered_rows(jobs, ctx.row_keys)}  # fmt: skip
    for label, grp in groups.items():
        bots = grp["bots"]
        stop = "" if grp["stop_at"] == "none" else f", stop_at {grp['stop_at']}"
        table.notes.append(
            f"{label}: follower {bots.centre_s:.3f} s on the centre line, {bots.mincurv_s:.3f} s "
            f"on the min-curvature line; reference limit {bots.reference_limit_s:.3f} s; budget "
            f"{grp['budget_cpu_s']:g} CPU-s{stop}")
        by_row: dict[str, list[dict[str, Any]]] = {}
        for job_id, run in grp["runs"].items():
            by_row.setdefault(ctx.row_keys[job_id], []).append(run)
        for key, runs in by_row.items():
            row = rows[key]
            summary = competence.summarise(runs)
            for name, metric in METRICS.items():
                median = summary[f"median_{name}_cpu_s"]
                row["values"][(label, metric)] = median
                row["text"][(label, metric)] = _cell(median, summary[f"reached_{name}"],
                                                     summary["seeds"])
            ratio = summary["median_best_lap_to_limit"]
            row["values"][(label, RATIO)] = ratio
            row["text"][(label, RATIO)] = f"{ratio:.3f}" if math.isfinite(ratio) else DASH
            rate = summary["median_clean_start_rate"]
            row["values"][(label, CLEAN_STARTS)] = rate
            row["text"][(label, CLEAN_STARTS)] = f"{rate:.2f}"
            table.records.append({
                "group": label, "row": key, "part": grp["part"], "track": grp["track"],
                "budget_cpu_s": grp["budget_cpu_s"], "stop_at": grp["stop_at"],
                "bots": {"centre_s": bots.centre_s, "mincurv_s": bots.mincurv_s,
                         "reference_limit_s": bots.reference_limit_s},
                "summary": summary, "runs": sorted(runs, key=lambda r: r["seed"]),
            })  # fmt: skip
    return table
