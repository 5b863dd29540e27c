"""The paper's three tables (plus probability-of-improvement) from any tournament's results.

Metrics follow the paper (formula_rl.tex, Study 1): a *model* is one checkpoint tested at one
point of training on one track (all its test starts together); only models with zero test damage
count. bLT is the best lap over all runs' models, aLT the mean over runs (seeds) of each run's
best zero-damage lap, DNF where no run produced one, and damage the cumulative test damage of a
run (averaged over runs). Every lap-time table adds the baseline bots, the track's reference limit
(quasi-steady-state lap on the minimum-curvature line) and the gap to it.

Tables are built once as ``ReportTable`` (numbers + display text) and rendered three ways: rich
terminal, Markdown and LaTeX (pandas Styler, booktabs, best per column in bold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.report import stats
from formula_tourney.report.load import TournamentData
from formula_tourney.safeio import atomic_write_text

REFERENCE_LABELS = {"centre": "MOT", "recorded": "RC", "mincurv": "MinCurv", "genetic": "GenLine"}
"""Paper names of reference lines: MOT = middle of track, RC = the racing line a bot drove."""
BOT_LABELS = {"follower": "Follower (Tita)", "genetic": "Genetic"}
LIMIT_LABEL = "Reference limit"
LAP_METRICS = ("bLT", "aLT")
"""Metrics whose best (lowest) value per column is bold."""
_DASH = "-"


def reference_label(reference: str) -> str:
    return REFERENCE_LABELS.get(str(reference), str(reference))


def config_label(variant: str, reference: str, lac: bool) -> str:
    """``PER1M RC + LAC``: how the paper names an entrant configuration."""
    return f"{variant} {reference_label(reference)}" + (" + LAC" if lac else "")


def bot_label(bot: str, reference: str | None = None) -> str:
    base = BOT_LABELS.get(str(bot), str(bot))
    return f"{base} {reference_label(reference)}" if reference else base


# --------------------------------------------------------------------------------------------
# metrics


def model_table(tests: pd.DataFrame) -> pd.DataFrame:
    """One row per model (job, test episode, track): its best lap over starts and its damage.

    ``clean_lap_s`` is the best lap when the model's damage over all its starts is zero, else nan:
    the paper's "models with 0 damage".
    """
    columns = ["job_id", "episode", "track", "best_lap_s", "damage", "finished", "starts",
               "part", "entrant", "variant", "family", "seed", "reference", "lac", "clean_lap_s"]
    if tests.empty:
        return pd.DataFrame(columns=columns)
    frame = tests.copy()
    frame["damage"] = pd.to_numeric(frame["damage"], errors="coerce").fillna(0.0)
    keys = ["job_id", "episode", "track"]
    grouped = frame.groupby(keys, sort=False, dropna=False)
    models = grouped.agg(
        best_lap_s=("best_lap_s", "min"), damage=("damage", "sum"),
        finished=("finished", "any"), starts=("best_lap_s", "size"),
    )
    info = grouped[["part", "entrant", "variant", "family", "seed", "reference", "lac"]].first()
    models = models.join(info).reset_index()
    models["clean_lap_s"] = models["best_lap_s"].where(models["damage"] <= 0.0)
    return models[columns]


def run_table(models: pd.DataFrame) -> pd.DataFrame:
    """One row per run and track: the run's best zero-damage lap and its cumulative test damage."""
    columns = ["job_id", "track", "run_best_s", "damage", "models", "best_episode"]
    if models.empty:
        return pd.DataFrame(columns=columns)
    rows = []
    for (job_id, track), grp in models.groupby(["job_id", "track"], sort=False):
        clean = grp["clean_lap_s"]
        best = float(clean.min()) if clean.notna().any() else float("nan")
        best_ep = float(grp.loc[clean.idxmin(), "episode"]) if clean.notna().any() else math.nan
        rows.append({"job_id": job_id, "track": track, "run_best_s": best,
                     "damage": float(grp["damage"].sum()), "models": len(grp),
                     "best_episode": best_ep})
    return pd.DataFrame(rows, columns=columns)


def entry_stats(runs: pd.DataFrame, planned: int, limit_s: float) -> dict[str, Any]:
    """bLT, aLT with its 95% CI, IQM, finished runs and mean damage for one table cell group.

    ``runs`` holds the run rows (``run_table``) of the jobs in this cell; ``planned`` counts the
    jobs the index lists for it (failed and pending included), so "2/3" says one run is missing.
    """
    laps = runs["run_best_s"].to_numpy(dtype=float) if not runs.empty else np.array([])
    finished = laps[np.isfinite(laps)]
    out: dict[str, Any] = {
        "runs": int(len(runs)), "planned": int(max(planned, len(runs))),
        "finished_runs": int(finished.size), "run_best_s": [float(v) for v in laps],
        "damage": float(runs["damage"].mean()) if not runs.empty else math.nan,
    }
    if runs.empty:
        out.update(status="missing", bLT=math.nan, aLT=math.nan, ci_low=math.nan,
                   ci_high=math.nan, iqm=math.nan, gap_pct=math.nan, best_job=None)
        return out
    if finished.size == 0:
        out.update(status="DNF", bLT=math.nan, aLT=math.nan, ci_low=math.nan,
                   ci_high=math.nan, iqm=math.nan, gap_pct=math.nan, best_job=None)
        return out
    ci = stats.mean_ci(finished)
    best = float(finished.min())
    best_row = runs.loc[runs["run_best_s"].idxmin()]
    out.update(
        status="ok", bLT=best, aLT=ci.value, ci_low=ci.low, ci_high=ci.high,
        iqm=stats.iqm(finished), gap_pct=gap_pct(best, limit_s),
        best_job=str(best_row["job_id"]), best_episode=float(best_row["best_episode"]),
    )
    return out


def gap_pct(lap_s: float, limit_s: float) -> float:
    """How much slower than the reference limit, in percent (nan without a limit)."""
    if not (np.isfinite(lap_s) and np.isfinite(limit_s)) or limit_s <= 0:
        return math.nan
    return (lap_s / limit_s - 1.0) * 100.0


def reference_limits(baselines: pd.DataFrame) -> dict[str, float]:
    """Reference limit per track (the same for every bot row of a track; the first non-nan)."""
    limits: dict[str, float] = {}
    if baselines.empty:
        return limits
    for track, grp in baselines.groupby("track", sort=False):
        vals = pd.to_numeric(grp["reference_limit_s"], errors="coerce").dropna()
        if not vals.empty:
            limits[str(track)] = float(vals.iloc[0])
    return limits


def bot_rows(baselines: pd.DataFrame) -> list[tuple[str, str, str | None]]:
    """(label, bot, reference or None): one row per bot, split by line only where a bot drove
    several lines, so a single follower run stays one "Follower (Tita)" row as in the paper."""
    rows: list[tuple[str, str, str | None]] = []
    if baselines.empty:
        return rows
    for bot, grp in baselines.groupby("bot", sort=False):
        refs = list(dict.fromkeys(grp["reference"].dropna().astype(str)))
        if len(refs) <= 1:
            rows.append((bot_label(str(bot)), str(bot), None))
        else:
            rows.extend((bot_label(str(bot), r), str(bot), r) for r in refs)
    return rows


def bot_result(baselines: pd.DataFrame, bot: str, reference: str | None, track: str,
               part: str | None = None) -> dict[str, Any]:
    """A bot's best clean lap on a track (in one part, or over all), DNF when it never finished
    cleanly, missing when it was not run there."""
    sel = (baselines["bot"].astype(str) == bot) & (baselines["track"].astype(str) == track)
    if reference is not None:
        sel &= baselines["reference"].astype(str) == reference
    if part is not None:
        sel &= baselines["part"].astype(str) == part
    # a drive that failed or has not run is missing (and listed as a problem), not a DNF
    sel &= ~baselines["status"].astype(str).isin(["failed", "pending", "running"])
    rows = baselines.loc[sel]
    if rows.empty:
        return {"status": "missing", "bLT": math.nan, "damage": math.nan}
    ok = rows["finished"] & (rows["damage"].fillna(0) <= 0) & rows["best_lap_s"].notna()
    clean = rows.loc[ok]
    damage = float(rows["damage"].fillna(0).min())
    if clean.empty:
        return {"status": "DNF", "bLT": math.nan, "damage": damage}
    return {"status": "ok", "bLT": float(clean["best_lap_s"].min()),
            "damage": float(clean["damage"].fillna(0).min())}


# --------------------------------------------------------------------------------------------
# table model


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
                or any(r["text"].get((group, m), _DASH) != _DASH for m in self.metrics[group])]

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
        data = [[r["text"].get(c, _DASH) for c in self.columns] for r in self.rows]
        return pd.DataFrame(data, index=[r["label"] for r in self.rows], columns=cols)

    def to_json(self) -> dict[str, Any]:
        return {
            "key": self.key, "title": self.title, "caption": self.caption,
            "columns": [list(c) for c in self.columns],
            "rows": [
                {"label": r["label"], "kind": r["kind"], "family": r["family"],
                 "cells": {f"{g} | {m}": _num(r["values"].get((g, m), math.nan))
                           for g, m in self.columns},
                 "text": {f"{g} | {m}": r["text"].get((g, m), _DASH) for g, m in self.columns}}
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


def _fmt_lap(value: float) -> str:
    return f"{value:.2f}" if np.isfinite(value) else _DASH


def _fmt_gap(value: float) -> str:
    return f"{value:+.1f}%" if np.isfinite(value) else _DASH


def _fmt_ci(low: float, high: float) -> str:
    return f"[{low:.2f}, {high:.2f}]" if np.isfinite(low) and np.isfinite(high) else _DASH


def _fmt_damage(value: float) -> str:
    return f"{value:.0f}" if np.isfinite(value) else _DASH


def _fill_entry(row: dict[str, Any], group: str, st: dict[str, Any], metrics: list[str]) -> None:
    """Write one entrant cell group; DNF replaces lap times when no run finished cleanly."""
    status = st["status"]
    values = {"bLT": st["bLT"], "aLT": st["aLT"], "gap": st["gap_pct"], "IQM": st["iqm"],
              "dmg": st["damage"]}
    for metric in metrics:
        if metric in values:
            row["values"][(group, metric)] = values[metric]
        if metric == "runs" and st["planned"] > 0:
            # shown even when no run wrote results, so failed entrants keep their row
            text = f"{st['finished_runs']}/{st['planned']}"
        elif status == "missing":
            text = _DASH
        elif metric in ("bLT", "aLT", "IQM"):
            text = "DNF" if status == "DNF" else _fmt_lap(values[metric])
        elif metric == "95% CI":
            text = _fmt_ci(st["ci_low"], st["ci_high"])
        elif metric == "gap":
            text = _fmt_gap(st["gap_pct"])
        elif metric == "dmg":
            text = _fmt_damage(st["damage"])
        else:
            text = _DASH
        row["text"][(group, metric)] = text


def _fill_single(row: dict[str, Any], group: str, lap_s: float, status: str, limit_s: float,
                 metrics: list[str], damage: float = math.nan) -> None:
    """A bot or limit cell group: one lap time, shown under bLT (aLT has no meaning for it)."""
    for metric in metrics:
        text = _DASH
        if metric == "bLT":
            row["values"][(group, metric)] = lap_s
            text = "DNF" if status == "DNF" else _fmt_lap(lap_s)
        elif metric == "gap" and status == "ok":
            gap = gap_pct(lap_s, limit_s)
            row["values"][(group, metric)] = gap
            text = _fmt_gap(gap)
        elif metric == "dmg" and np.isfinite(damage):
            text = _fmt_damage(damage)
        row["text"][(group, metric)] = text


# --------------------------------------------------------------------------------------------
# job bookkeeping shared by the tables


def _jobs_with_tracks(data: TournamentData) -> pd.DataFrame:
    """Jobs with explicit train tracks (index, else config.json, else the tracks tested on) and
    the tracks each job was tested on."""
    jobs = data.jobs.copy()
    tested = (data.tests.groupby("job_id", sort=False)["track"]
              .apply(lambda s: list(dict.fromkeys(s.astype(str)))).to_dict()
              if not data.tests.empty else {})
    train_lists, test_lists = [], []
    for _, job in jobs.iterrows():
        train = [str(t) for t in job["train_tracks"]]
        if not train:
            train = [str(t) for t in data.configs.get(str(job["job_id"]), {})
                     .get("train_tracks", [])]
        cfg = data.configs.get(str(job["job_id"]), {})
        planned_tests = [str(t) for t in cfg.get("test_tracks") or []]
        tested_here = list(dict.fromkeys([*tested.get(job["job_id"], []), *planned_tests]))
        if not train:
            train = tested_here[:1]
        train_lists.append(train)
        test_lists.append(tested_here)
    jobs["train_tracks"] = train_lists
    jobs["tested_tracks"] = test_lists
    return jobs


def _row_keys(jobs: pd.DataFrame) -> dict[str, str]:
    """Row label per job: the variant (as in the paper), or the entrant name for jobs whose part
    holds several entrants of one variant with the same line and LAC (e.g. an ablation pair)."""
    keys: dict[str, str] = {}
    for _, grp in jobs.groupby(["part", "reference", "lac", "variant"], sort=False):
        col = "entrant" if grp["entrant"].nunique() > 1 else "variant"
        keys.update({str(j): str(v) for j, v in zip(grp["job_id"], grp[col], strict=True)})
    return keys


def _ordered_rows(jobs: pd.DataFrame, keys: dict[str, str]) -> list[tuple[str, str]]:
    """(row key, family), families in order of first appearance (the spec's order)."""
    fam_order = list(dict.fromkeys(jobs["family"].astype(str)))
    seen: dict[str, str] = {}
    for _, job in jobs.iterrows():
        seen.setdefault(keys[str(job["job_id"])], str(job["family"]))
    return sorted(seen.items(), key=lambda kv: fam_order.index(kv[1]))


@dataclass
class Context:
    """Frames every table needs, computed once per report."""

    data: TournamentData
    jobs: pd.DataFrame
    runs: pd.DataFrame
    models: pd.DataFrame
    limits: dict[str, float]
    row_keys: dict[str, str]

    @classmethod
    def build(cls, data: TournamentData) -> Context:
        jobs = _jobs_with_tracks(data)
        models = model_table(data.tests)
        return cls(data=data, jobs=jobs, runs=run_table(models), models=models,
                   limits=reference_limits(data.baselines), row_keys=_row_keys(jobs))

    def runs_of(self, job_ids: list[str], track: str) -> pd.DataFrame:
        sel = self.runs["job_id"].isin(job_ids) & (self.runs["track"].astype(str) == track)
        return self.runs.loc[sel]


# --------------------------------------------------------------------------------------------
# Table 1


TABLE1_METRICS = ["bLT", "aLT", "95% CI", "IQM", "gap", "runs", "dmg"]


def _group_label(part: str, track: str, reference: str, lac: bool) -> str:
    return f"{part}: {track} {reference_label(reference)}" + (" + LAC" if lac else "")


def table1(ctx: Context) -> ReportTable:
    """Best and average best lap per part, track and reference line (paper, Table 1).

    Columns are one group per (part, train track, reference line, LAC); rows are variants grouped
    by family, then the bots, then the reference limit. Only tests on a job's own train tracks
    count here; unseen tracks belong to Table 3.
    """
    data = ctx.data
    table = ReportTable(
        key="table1", title="Table 1: best (bLT) and average best (aLT) lap time per part",
        caption=(
            "Testing results per part, track and reference line (MOT: middle of track; RC: a "
            "bot's racing line). bLT: best lap; aLT: mean over runs of each run's best lap, with "
            "95% bootstrap CI and interquartile mean (IQM), in seconds, for models with 0 damage; "
            "gap: bLT above the track's reference limit; runs: runs with a clean lap / runs "
            "planned; dmg: mean cumulative test damage per run. DNF: no run finished cleanly."
        ),
        groups=[], metrics={},
    )
    groups: dict[str, dict[str, Any]] = {}
    for part in data.part_order():
        part_jobs = ctx.jobs.loc[ctx.jobs["part"] == part]
        for _, job in part_jobs.iterrows():
            for track in job["train_tracks"]:
                label = _group_label(part, track, job["reference"], bool(job["lac"]))
                grp = groups.setdefault(label, {"part": part, "track": track,
                                                "reference": job["reference"],
                                                "lac": bool(job["lac"]), "jobs": []})
                grp["jobs"].append(str(job["job_id"]))
    if not groups:
        table.notes.append("no jobs to report yet")
        return table
    table.groups = list(groups)
    table.metrics = {g: list(TABLE1_METRICS) for g in table.groups}
    rows = {key: table.add_row(key, "entrant", fam)
            for key, fam in _ordered_rows(ctx.jobs, ctx.row_keys)}
    for label, grp in groups.items():
        limit = ctx.limits.get(grp["track"], math.nan)
        by_row: dict[str, list[str]] = {}
        for job_id in grp["jobs"]:
            by_row.setdefault(ctx.row_keys[job_id], []).append(job_id)
        for key, row in rows.items():
            job_ids = by_row.get(key, [])
            st = entry_stats(ctx.runs_of(job_ids, grp["track"]), len(job_ids), limit)
            _fill_entry(row, label, st, TABLE1_METRICS)
            if job_ids:
                table.records.append({
                    "group": label, "row": key, "part": grp["part"], "track": grp["track"],
                    "reference": grp["reference"], "lac": grp["lac"], **st,
                })
    for blabel, bot, ref in bot_rows(data.baselines):
        row = table.add_row(blabel, "bot")
        for label, grp in groups.items():
            res = bot_result(data.baselines, bot, ref, grp["track"], grp["part"])
            _fill_single(row, label, res["bLT"], res["status"],
                         ctx.limits.get(grp["track"], math.nan), TABLE1_METRICS, res["damage"])
    if any(g["track"] in ctx.limits for g in groups.values()):
        row = table.add_row(LIMIT_LABEL, "limit")
        for label, grp in groups.items():
            limit = ctx.limits.get(grp["track"], math.nan)
            _fill_single(row, label, limit, "ok" if np.isfinite(limit) else "missing",
                         limit, TABLE1_METRICS)
    return table


# --------------------------------------------------------------------------------------------
# Table 2


def table2(ctx: Context) -> ReportTable:
    """LAC comparison with the follower bot (paper, Table 2): best lap of each configuration of
    the variants that were run with LAC, on every track they were trained and tested on."""
    table = ReportTable(
        key="table2", title="Table 2: look-ahead curvature (LAC) vs the follower bot",
        caption=(
            "Best lap (bLT, s, zero damage) of each configuration trained and tested on the same "
            "track: middle of track (MOT) vs a racing line (RC) vs racing line + look-ahead "
            "curvature (LAC), against the follower bot (our Tita) and the reference limit; gap "
            "to the limit in percent."
        ),
        groups=[], metrics={},
    )
    jobs = ctx.jobs
    lac_variants = list(dict.fromkeys(jobs.loc[jobs["lac"], "variant"].astype(str)))
    if not lac_variants:
        table.notes.append("no entrant was run with LAC: Table 2 needs a LAC entrant")
        return table
    cfg_jobs: dict[str, list[str]] = {}
    for _, job in jobs.loc[jobs["variant"].isin(lac_variants)].iterrows():
        label = config_label(job["variant"], job["reference"], bool(job["lac"]))
        cfg_jobs.setdefault(label, []).append(str(job["job_id"]))
    tracks = list(dict.fromkeys(t for tl in jobs.loc[jobs["variant"].isin(lac_variants),
                                                    "train_tracks"] for t in tl))
    metrics = ["bLT", "gap"]
    table.groups = tracks
    table.metrics = {t: list(metrics) for t in tracks}
    train_of = dict(zip(jobs["job_id"].astype(str), jobs["train_tracks"], strict=True))
    for blabel, bot, ref in bot_rows(ctx.data.baselines):
        if bot != "follower":
            continue
        row = table.add_row(blabel, "bot")
        for track in tracks:
            res = bot_result(ctx.data.baselines, bot, ref, track)
            _fill_single(row, track, res["bLT"], res["status"],
                         ctx.limits.get(track, math.nan), metrics)
    for label, job_ids in cfg_jobs.items():
        row = table.add_row(label, "entrant")
        for track in tracks:
            trained = [j for j in job_ids if track in train_of[j]]
            st = entry_stats(ctx.runs_of(trained, track), len(trained),
                             ctx.limits.get(track, math.nan))
            _fill_entry(row, track, st, metrics)
            if trained:
                table.records.append({"row": label, "track": track, **st})
    if any(t in ctx.limits for t in tracks):
        row = table.add_row(LIMIT_LABEL, "limit")
        for track in tracks:
            limit = ctx.limits.get(track, math.nan)
            _fill_single(row, track, limit, "ok" if np.isfinite(limit) else "missing", limit,
                         metrics)
    return table


# --------------------------------------------------------------------------------------------
# Table 3


def general_model(models: pd.DataFrame, train_track: str,
                  tracks: list[str]) -> tuple[dict[str, Any] | None, dict[str, float]]:
    """The paper's *general model*: among all tested checkpoints of a configuration, the one
    with the best zero-damage lap on the train track that also finishes every other track.

    Where none finishes all tracks, the model finishing the most tracks wins (ties: the faster
    train-track lap), and the tracks it did not finish read DNF. Returns (which model, lap per
    track).
    """
    if models.empty:
        return None, {t: math.nan for t in tracks}
    pivot = models.pivot_table(index=["job_id", "episode"], columns="track",
                               values="clean_lap_s", aggfunc="min", dropna=False)
    pivot = pivot.reindex(columns=tracks)
    finished = pivot.notna().sum(axis=1)
    train = pivot[train_track] if train_track in pivot else pd.Series(np.nan, index=pivot.index)
    order = pd.DataFrame({"finished": -finished, "train": train.fillna(np.inf)})
    order = order.sort_values(["finished", "train"], kind="stable")
    if order.empty or finished.max() == 0:
        return None, {t: math.nan for t in tracks}
    job_id, episode = order.index[0]
    laps = {t: float(pivot.loc[(job_id, episode), t]) for t in tracks}
    return ({"job_id": str(job_id), "episode": float(episode),
             "finished_all": bool(finished.loc[(job_id, episode)] == len(tracks))}, laps)


def stored_general_model(general: pd.DataFrame, models: pd.DataFrame, job_ids: list[str],
                         tracks: list[str]) -> tuple[dict[str, Any] | None, dict[str, float]]:
    """The general model the tournament chose (``general_models`` with ``chosen``) among
    ``job_ids``, with its zero-damage laps from the tests; (None, {}) where it chose none, so the
    report and the promotion step never disagree on which model is general."""
    if general.empty:
        return None, {}
    chosen = general.loc[general["chosen"] & general["job_id"].astype(str).isin(job_ids)]
    if chosen.empty:
        return None, {}
    pick = chosen.sort_values("train_lap_s", kind="stable").iloc[0]
    job_id, episode = str(pick["job_id"]), float(pick["episode"])
    mine = models.loc[(models["job_id"] == job_id) & (models["episode"] == episode)]
    laps = {t: float(mine.loc[mine["track"] == t, "clean_lap_s"].min()) for t in tracks}
    finished_all = all(np.isfinite(v) for v in laps.values())
    return {"job_id": job_id, "episode": episode, "finished_all": finished_all,
            "chosen_by": "tournament"}, laps


def table3(ctx: Context) -> ReportTable:
    """Best vs general models on every track (paper, Table 3), for configurations tested on
    tracks they were not trained on."""
    table = ReportTable(
        key="table3", title="Table 3: fastest vs general models on every track",
        caption=(
            "Fastest models (bLT, aLT on the train track) compared with the general model (the "
            "best train-track lap among checkpoints that also finish every unseen track) on "
            "every test track, s. DNF: no model finished."
        ),
        groups=[], metrics={},
    )
    jobs = ctx.jobs
    general_jobs = jobs.loc[[any(t not in job["train_tracks"] for t in job["tested_tracks"])
                             for _, job in jobs.iterrows()]]
    if general_jobs.empty:
        table.notes.append("no entrant was tested on a track it was not trained on")
        return table
    cfgs: dict[str, dict[str, Any]] = {}
    for _, job in general_jobs.iterrows():
        train = job["train_tracks"][0] if job["train_tracks"] else ""
        label = config_label(job["variant"], job["reference"], bool(job["lac"]))
        if general_jobs["train_tracks"].map(lambda t: tuple(t)).nunique() > 1:
            label += f" ({train})"
        cfg = cfgs.setdefault(label, {"train": train, "jobs": [], "tracks": []})
        cfg["jobs"].append(str(job["job_id"]))
        cfg["tracks"].extend(t for t in job["tested_tracks"] if t not in cfg["tracks"])
    trains = list(dict.fromkeys(c["train"] for c in cfgs.values()))
    all_tracks = list(dict.fromkeys([*trains, *(t for c in cfgs.values() for t in c["tracks"])]))
    best_group = "Best" if len(trains) == 1 else "Best (train track)"
    table.groups = [best_group, "General"]
    table.metrics = {best_group: ["bLT", "aLT", "gap"], "General": list(all_tracks)}
    table.lap_metrics = {"bLT", "aLT", *all_tracks}
    for label, cfg in cfgs.items():
        row = table.add_row(label, "entrant")
        limit = ctx.limits.get(cfg["train"], math.nan)
        st = entry_stats(ctx.runs_of(cfg["jobs"], cfg["train"]), len(cfg["jobs"]), limit)
        _fill_entry(row, best_group, st, ["bLT", "aLT", "gap"])
        models = ctx.models.loc[ctx.models["job_id"].isin(cfg["jobs"])]
        which, laps = stored_general_model(ctx.data.general_models, models, cfg["jobs"],
                                           cfg["tracks"])
        if which is None:
            which, laps = general_model(models, cfg["train"], cfg["tracks"])
        for track in all_tracks:
            lap = laps.get(track, math.nan)
            row["values"][("General", track)] = lap
            if track not in cfg["tracks"] or models.empty:
                row["text"][("General", track)] = _DASH
            else:
                row["text"][("General", track)] = _fmt_lap(lap) if np.isfinite(lap) else "DNF"
        if which is not None:
            table.notes.append(
                f"general model of {label}: {which['job_id']} after {which['episode']:.0f} "
                "episodes" + ("" if which["finished_all"] else " (finishes not every track)")
            )
        table.records.append({"row": label, "train_track": cfg["train"], "jobs": cfg["jobs"],
                              "best": st,
                              "general": which, "general_laps": laps})
    for blabel, bot, ref in bot_rows(ctx.data.baselines):
        row = table.add_row(blabel, "bot")
        if len(trains) == 1:
            res = bot_result(ctx.data.baselines, bot, ref, trains[0])
            _fill_single(row, best_group, res["bLT"], res["status"],
                         ctx.limits.get(trains[0], math.nan), ["bLT", "aLT", "gap"])
        for track in all_tracks:
            res = bot_result(ctx.data.baselines, bot, ref, track)
            row["values"][("General", track)] = res["bLT"]
            row["text"][("General", track)] = (
                _DASH if res["status"] == "missing"
                else "DNF" if res["status"] == "DNF" else _fmt_lap(res["bLT"]))
    if any(t in ctx.limits for t in all_tracks):
        row = table.add_row(LIMIT_LABEL, "limit")
        if len(trains) == 1:
            limit = ctx.limits.get(trains[0], math.nan)
            _fill_single(row, best_group, limit, "ok" if np.isfinite(limit) else "missing",
                         limit, ["bLT", "aLT", "gap"])
        for track in all_tracks:
            limit = ctx.limits.get(track, math.nan)
            row["values"][("General", track)] = limit
            row["text"][("General", track)] = _fmt_lap(limit)
    return table


# --------------------------------------------------------------------------------------------
# probability of improvement


def comparisons(ctx: Context, table_1: ReportTable) -> ReportTable:
    """For every Table 1 column: P(the leader by aLT beats each other entrant in one run)."""
    table = ReportTable(
        key="comparisons", title="Probability of improvement: P(leader faster than row)",
        caption=(
            "For each part, track and line: probability that a run of the entrant with the best "
            "aLT has a faster best lap than a run of the row's entrant (Mann-Whitney U / "
            "(n_a n_b), 95% bootstrap CI, two-sided U test p-value). Runs without a clean lap "
            "are left out."
        ),
        groups=[], metrics={},
    )
    by_group: dict[str, list[dict[str, Any]]] = {}
    for rec in table_1.records:
        if rec["status"] == "ok":
            by_group.setdefault(rec["group"], []).append(rec)
    rows: dict[str, dict[str, Any]] = {}
    for group, recs in by_group.items():
        if len(recs) < 2:
            continue
        leader = min(recs, key=lambda r: r["aLT"])
        title = f"{group} (leader {leader['row']})"
        table.groups.append(title)
        table.metrics[title] = ["P(faster)", "95% CI", "p"]
        for rec in recs:
            if rec is leader:
                continue
            row = rows.get(rec["row"]) or table.add_row(rec["row"], "entrant")
            rows[rec["row"]] = row
            cmp_ = stats.compare(leader["run_best_s"], rec["run_best_s"])
            row["values"][(title, "P(faster)")] = cmp_.prob
            row["text"][(title, "P(faster)")] = f"{cmp_.prob:.2f}"
            row["text"][(title, "95% CI")] = _fmt_ci(cmp_.low, cmp_.high)
            row["text"][(title, "p")] = f"{cmp_.p_value:.3f}" if np.isfinite(cmp_.p_value) \
                else _DASH
            table.records.append({"group": group, "leader": leader["row"], "row": rec["row"],
                                  **cmp_.as_dict()})
    if not table.groups:
        table.notes.append("no column has two entrants with clean laps to compare")
    return table


def build_tables(data: TournamentData) -> list[ReportTable]:
    """All report tables for one tournament, in the paper's order."""
    ctx = Context.build(data)
    t1 = table1(ctx)
    return [t1, table2(ctx), table3(ctx), comparisons(ctx, t1)]


# --------------------------------------------------------------------------------------------
# renderers


def render_rich(table: ReportTable, console: Any) -> None:
    """One rich table per column group: the paper's wide layout does not fit a terminal."""
    from rich.table import Table

    console.print(f"[bold]{table.title}[/bold]")
    if table.empty:
        console.print("  (empty) " + "; ".join(table.notes))
        return
    best = table.best_cells()
    for group in table.groups:
        metrics = table.metrics[group]
        rt = Table(title=group, title_justify="left", show_lines=False)
        shown = table.shown(group)
        label_width = max([len(table.rows[i]["label"]) for i in shown] + [1])
        rt.add_column("", no_wrap=True, min_width=label_width)
        for m in metrics:
            width = max([len(table.rows[i]["text"].get((group, m), _DASH)) for i in shown]
                        + [len(m)])
            rt.add_column(m, justify="right", no_wrap=True, min_width=width)
        for k, i in enumerate(shown):
            row = table.rows[i]
            cells = []
            for m in metrics:
                text = row["text"].get((group, m), _DASH)
                cells.append(f"[bold green]{text}[/]" if (i, group, m) in best else text)
            nxt = table.rows[shown[k + 1]] if k + 1 < len(shown) else None
            end = nxt is not None and (nxt["kind"] != row["kind"] or nxt["family"] != row["family"])
            rt.add_row(row["label"], *cells, end_section=end)
        # Never cut a lap time to an ellipsis: a narrow (or piped, 80-column) console gets the
        # table at its natural width instead.
        natural = sum(c.min_width or 0 for c in rt.columns) + 3 * len(rt.columns) + 1
        console.print(rt, width=max(console.width, natural), crop=False)
    for note in table.notes:
        console.print(f"  {note}")


def render_markdown(table: ReportTable) -> str:
    """GitHub Markdown: one pipe table per column group, best per column in bold."""
    lines = [f"### {table.title}", ""]
    if table.empty:
        lines.append("_(empty)_ " + "; ".join(table.notes))
        return "\n".join(lines) + "\n"
    best = table.best_cells()
    for group in table.groups:
        metrics = table.metrics[group]
        lines.append(f"**{_md_escape(group)}**")
        lines.append("")
        lines.append("| | " + " | ".join(_md_escape(m) for m in metrics) + " |")
        lines.append("|---|" + "---:|" * len(metrics))
        for i in table.shown(group):
            row = table.rows[i]
            cells = []
            for m in metrics:
                text = _md_escape(row["text"].get((group, m), _DASH))
                cells.append(f"**{text}**" if (i, group, m) in best else text)
            lines.append(f"| {_md_escape(row['label'])} | " + " | ".join(cells) + " |")
        lines.append("")
    lines.append(f"_{table.caption}_")
    lines.extend(f"- {n}" for n in table.notes)
    return "\n".join(lines) + "\n"


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|")


def render_latex_tabular(table: ReportTable) -> str:
    """The table as a booktabs ``tabular`` (pandas Styler), best per column in ``\\textbf``.

    A ``\\midrule`` separates families, then the bots, then the reference limit, as in the
    paper's Table 1; ``\\cmidrule`` underlines each column group.
    """
    if table.empty:
        return "% " + table.title + ": empty (" + "; ".join(table.notes) + ")\n"
    frame = table.text_frame()
    best = table.best_cells()
    col_pos = {c: j for j, c in enumerate(table.columns)}
    bold = np.full(frame.shape, "", dtype=object)
    for i, group, metric in best:
        bold[i, col_pos[(group, metric)]] = "textbf:--rwrap;"
    styler = (frame.style.format(escape="latex")
              .format_index(escape="latex", axis=0).format_index(escape="latex", axis=1)
              .apply(lambda d: pd.DataFrame(bold, index=d.index, columns=d.columns), axis=None))
    latex = styler.to_latex(hrules=True, multicol_align="c",
                            column_format="l" + "r" * len(table.columns))
    lines = latex.splitlines()
    # \cmidrule under the group header row (the first row after \toprule).
    start = 2
    rules = []
    for group in table.groups:
        width = len(table.metrics[group])
        rules.append(f"\\cmidrule(lr){{{start}-{start + width - 1}}}")
        start += width
    top = lines.index("\\toprule")
    lines.insert(top + 2, " ".join(rules))
    mid = lines.index("\\midrule")
    out = lines[: mid + 1]
    for i, line in enumerate(lines[mid + 1:]):
        if i < len(table.rows) and i > 0:
            prev, row = table.rows[i - 1], table.rows[i]
            if row["kind"] != prev["kind"] or row["family"] != prev["family"]:
                out.append("\\midrule")
        out.append(line)
    return "\n".join(out) + "\n"


def render_latex_table(table: ReportTable) -> str:
    """A ``table`` float with caption, label and notes, for \\input into a paper."""
    tabular = render_latex_tabular(table)
    wide = len(table.columns) > 12
    body = f"\\resizebox{{\\linewidth}}{{!}}{{%\n{tabular}}}\n" if wide else tabular
    notes = "".join(f"\\par\\smallskip{{\\scriptsize {_latex_text(n)}}}\n" for n in table.notes)
    return (
        "\\begin{table}[ht]\n\\centering\n\\footnotesize\n" + body
        + f"\\caption{{{_latex_text(table.title)}. {_latex_text(table.caption)}}}\n"
        + f"\\label{{table:{table.key}}}\n" + notes + "\\end{table}\n"
    )


def _latex_text(text: str) -> str:
    repl = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
            "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
            "^": r"\textasciicircum{}"}
    return "".join(repl.get(ch, ch) for ch in str(text))


def latex_document(tables: list[ReportTable], title: str, problems: list[str],
                   figures: dict[str, Path] | None = None) -> str:
    """A standalone article (booktabs, geometry, graphicx: all in texlive-latex-base/recommended)
    holding every table and, given ``figures`` (name -> PDF path relative to the .tex), every
    figure; compiles with a bare ``pdflatex`` run in the .tex's folder."""
    parts = [
        "\\documentclass[10pt]{article}",
        "\\usepackage{booktabs}",
        "\\usepackage{graphicx}",
        "\\usepackage[a4paper,landscape,margin=1.5cm]{geometry}",
        "\\pagestyle{empty}",
        "\\begin{document}",
        f"\\section*{{{_latex_text(title)}}}",
    ]
    if problems:
        parts.append("\\paragraph{Missing or failed jobs.}")
        parts.append("\\begin{itemize}")
        parts.extend(f"\\item {_latex_text(p)}" for p in problems[:40])
        if len(problems) > 40:
            parts.append(f"\\item \\dots{{}} and {len(problems) - 40} more")
        parts.append("\\end{itemize}")
    for table in tables:
        parts.extend(render_latex_table(t) for t in latex_split(table))
    for name, path in (figures or {}).items():
        parts.append("\\begin{figure}[ht]\\centering")
        parts.append(f"\\includegraphics[width=0.9\\linewidth,height=0.8\\textheight,"
                     f"keepaspectratio]{{{Path(path).as_posix()}}}")
        parts.append(f"\\caption{{{_latex_text(name)}}}\\end{{figure}}")
        parts.append("\\clearpage")
    parts.append("\\end{document}")
    return "\n".join(parts) + "\n"


LATEX_TABLE1_METRICS = ["bLT", "aLT", "95% CI", "gap", "runs"]
"""Table 1 in LaTeX keeps the paper's columns plus the CI, gap and runs: IQM and damage stay in
the terminal/JSON so that a part fits a page."""


def latex_split(table: ReportTable) -> list[ReportTable]:
    """Table 1 as one float per part (the paper's width: a part holds 1-2 lines), else as is."""
    if table.key != "table1" or table.empty:
        return [table]
    by_part: dict[str, list[str]] = {}
    for group in table.groups:
        by_part.setdefault(group.split(":", 1)[0], []).append(group)
    out = []
    for part, groups in by_part.items():
        sub = table.subset(groups, LATEX_TABLE1_METRICS, suffix=f"-{part}")
        sub.title = f"{table.title} ({part})"
        out.append(sub)
    return out


def write_latex(tables: list[ReportTable], out_dir: Path, title: str, problems: list[str],
                figures: dict[str, Path] | None = None) -> dict[str, Path]:
    """``tables.tex`` (standalone) plus one ``<key>.tex`` float per table for \\input."""
    out_dir = Path(out_dir)
    paths = {"tables.tex": atomic_write_text(
        out_dir / "tables.tex", latex_document(tables, title, problems, figures))}
    for table in tables:
        body = "".join(render_latex_table(t) for t in latex_split(table))
        paths[f"{table.key}.tex"] = atomic_write_text(out_dir / f"{table.key}.tex", body)
    return paths
