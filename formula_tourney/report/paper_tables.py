"""The paper's three tables (plus probability of improvement) from any tournament's results.

Metrics follow the paper (formula_rl.tex, Study 1) and are computed by ``results.metrics``, the
one definition that promotion and the figures read too: a *model* is one checkpoint tested at one
point of training on one track (all its test starts together); only models with zero test damage
count. bLT is the best lap over all runs' models, aLT the mean over runs (seeds) of each run's
best zero-damage lap, DNF where no run produced one, and damage the cumulative test damage of a
run (averaged over runs). Every lap-time table adds the baseline bots, the track's reference limit
(quasi-steady-state lap on the minimum-curvature line) and the gap to it.

Tables are built once as ``report.table_model.ReportTable`` and rendered by ``report.renderers`` and
``report.html``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.lines.kinds import line_label
from formula_tourney.report import stats
from formula_tourney.report.load import TournamentData
from formula_tourney.report.table_model import (
    DNF,
    LEADER,
    NO_GENERAL,
    NO_LIMIT,
    NO_RESULT,
    NOT_APPLICABLE,
    NOT_DRIVEN,
    NOT_RUN,
    NOT_TESTED,
    ReportTable,
    ci_value,
    fmt_ci,
    fmt_damage,
    fmt_gap,
    fmt_lap,
)
from formula_tourney.results import metrics

BOT_LABELS = {"follower": "Follower (Tita)", "genetic": "Genetic"}
LIMIT_LABEL = "Reference limit"


def config_label(variant: str, reference: str, lac: bool) -> str:
    """``PER1M RC + LAC``: how the paper names an entrant configuration."""
    return f"{variant} {line_label(reference)}" + (" + LAC" if lac else "")


def with_setup(label: str, beyond: list[str]) -> str:
    """``label`` with what its runs add to the paper's setup (``RunSpec.beyond_paper``: preset,
    demonstrations, ...), so runs of two setups never share a row: ``WIN1 (beyond paper: preset
    fast-small)``; the bare label for the paper's own setup."""
    return f"{label} (beyond paper: {', '.join(beyond)})" if beyond else label


def entrant_label(name: str, reference: str, lac: bool, beyond: list[str]) -> str:
    """``WIN1 RC + LAC (beyond paper: preset tuned-bc)``: a configuration and its setup."""
    return with_setup(config_label(name, reference, lac), beyond)


def bot_label(bot: str, reference: str | None = None) -> str:
    base = BOT_LABELS.get(str(bot), str(bot))
    return f"{base} {line_label(reference)}" if reference else base


# --------------------------------------------------------------------------------------------
# cell groups


def entry_stats(runs: pd.DataFrame, planned: int, limit_s: float) -> dict[str, Any]:
    """bLT, aLT with its 95% CI, IQM, finished runs and mean damage for one table cell group.

    ``runs`` holds the run rows (``results.metrics.run_table``) of the jobs in this cell;
    ``planned`` counts the jobs the index lists for it (failed and pending included), so "2/3"
    says one run is missing.
    """
    laps = runs["run_best_s"].to_numpy(dtype=float) if not runs.empty else np.array([])
    finished = laps[np.isfinite(laps)]
    out: dict[str, Any] = {
        "runs": int(len(runs)), "planned": int(max(planned, len(runs))),
        "finished_runs": int(finished.size), "run_best_s": [float(v) for v in laps],
        "damage": float(runs["damage"].mean()) if not runs.empty else math.nan,
    }
    if runs.empty or finished.size == 0:
        out.update(status="missing" if runs.empty else "DNF", bLT=math.nan, aLT=math.nan,
                   ci_low=math.nan, ci_high=math.nan, iqm=math.nan, gap_pct=math.nan,
                   best_job=None)
        return out
    blt, alt = metrics.blt_alt(laps)
    ci = stats.mean_ci(finished)
    best_row = runs.loc[runs["run_best_s"].idxmin()]
    out.update(
        status="ok", bLT=blt, aLT=alt, ci_low=ci.low, ci_high=ci.high,
        iqm=stats.iqm(finished), gap_pct=metrics.gap_pct(blt, limit_s),
        best_job=str(best_row["job_id"]), best_episode=float(best_row["best_episode"]),
    )
    return out


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


def bot_row_label(baselines: pd.DataFrame, bot: str, reference: str) -> tuple[str, str | None]:
    """The (label, reference or None) of the table row that shows ``bot`` driving ``reference``
    (as ``bot_rows`` names it)."""
    for label, b, ref in bot_rows(baselines):
        if b == bot and ref in (None, reference):
            return label, ref
    return bot_label(bot), None


def bot_result(baselines: pd.DataFrame, bot: str, reference: str | None, track: str,
               part: str | None = None) -> dict[str, Any]:
    """A bot's best clean lap on a track (in one part, or over all) and the line it drove it
    on, DNF when it never finished cleanly, missing when it was not run there."""
    if baselines.empty:
        return {"status": "missing", "bLT": math.nan, "damage": math.nan}
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
    best = clean.loc[clean["best_lap_s"].idxmin()]
    return {"status": "ok", "bLT": float(best["best_lap_s"]),
            "damage": float(clean["damage"].fillna(0).min()), "reference": str(best["reference"])}


def fill_entry(row: dict[str, Any], group: str, st: dict[str, Any], metrics_: list[str]) -> None:
    """Write one entrant cell group: every number also as a number (a CI as [low, high], runs
    as clean and planned counts); a cell without one says why (``table_model.CELL_MARKS``):
    DNF when no run finished cleanly, "no result" when none wrote results, "not run" when the
    entrant was not entered here."""
    status = st["status"]
    if status == "missing":
        empty = NO_RESULT if st["planned"] > 0 else NOT_RUN
    else:
        empty = DNF if status == "DNF" else NOT_APPLICABLE
    values = {"bLT": st["bLT"], "aLT": st["aLT"], "gap": st["gap_pct"], "IQM": st["iqm"],
              "dmg": st["damage"], "95% CI": ci_value(st["ci_low"], st["ci_high"])}
    for metric in metrics_:
        if metric in values:
            row["values"][(group, metric)] = values[metric]
        if metric == "runs" and st["planned"] > 0:
            # shown even when no run wrote results, so failed entrants keep their row
            row["values"][(group, metric)] = {"clean": st["finished_runs"],
                                              "planned": st["planned"]}
            text = f"{st['finished_runs']}/{st['planned']}"
        elif metric in ("bLT", "aLT", "IQM"):
            text = fmt_lap(values[metric], empty)
        elif metric == "95% CI":
            text = fmt_ci(st["ci_low"], st["ci_high"], empty)
        elif metric == "gap":
            text = fmt_gap(st["gap_pct"], NO_LIMIT if status == "ok" else empty)
        elif metric == "dmg":
            text = fmt_damage(st["damage"], empty)
        else:
            text = empty
        row["text"][(group, metric)] = text


def _fill_single(row: dict[str, Any], group: str, lap_s: float, status: str, limit_s: float,
                 metrics_: list[str], damage: float = math.nan) -> None:
    """A bot or limit cell group: one lap time, shown under bLT; aLT, CI, IQM and runs do not
    apply to one lap (n/a); a bot not driven here says so."""
    empty = {"missing": NOT_DRIVEN, "DNF": DNF}.get(status, NOT_APPLICABLE)
    for metric in metrics_:
        text = NOT_APPLICABLE
        if metric == "bLT":
            row["values"][(group, metric)] = lap_s
            text = fmt_lap(lap_s, empty)
        elif metric == "gap" and status == "ok":
            gap = metrics.gap_pct(lap_s, limit_s)
            row["values"][(group, metric)] = gap
            text = fmt_gap(gap, NO_LIMIT)
        elif metric in ("gap", "dmg"):
            text = fmt_damage(damage, empty) if metric == "dmg" else empty
            if metric == "dmg" and np.isfinite(damage):
                row["values"][(group, metric)] = damage
        row["text"][(group, metric)] = text


# --------------------------------------------------------------------------------------------
# job bookkeeping shared by the tables


def _jobs_with_tracks(data: TournamentData) -> pd.DataFrame:
    """Jobs with explicit train tracks (index, else the run spec in config.json, else the tracks
    tested on) and the tracks each job was tested on (or is planned to be)."""
    jobs = data.jobs.copy()
    tested = (data.tests.groupby("job_id", sort=False)["track"]
              .apply(lambda s: list(dict.fromkeys(s.astype(str)))).to_dict()
              if not data.tests.empty else {})
    train_lists, test_lists = [], []
    for _, job in jobs.iterrows():
        spec = data.configs.get(str(job["job_id"]), {})
        train = [str(t) for t in job["train_tracks"]] or [
            str(t) for t in spec.get("train_tracks") or []]
        planned_tests = [str(t) for t in spec.get("test_tracks") or []]
        tested_here = list(dict.fromkeys([*tested.get(job["job_id"], []), *planned_tests]))
        if not train:
            train = tested_here[:1]
        train_lists.append(train)
        test_lists.append(tested_here)
    jobs["train_tracks"] = train_lists
    jobs["tested_tracks"] = test_lists
    return jobs


def row_names(jobs: pd.DataFrame) -> dict[str, str]:
    """Row name per job: the variant (as in the paper), or the entrant name for jobs whose part
    holds several entrants of one variant with the same line and LAC (e.g. an ablation pair)."""
    names: dict[str, str] = {}
    for _, grp in jobs.groupby(["part", "reference", "lac", "variant"], sort=False):
        col = "entrant" if grp["entrant"].nunique() > 1 else "variant"
        names.update(zip(grp["job_id"].astype(str), grp[col].astype(str), strict=True))
    return names


def _row_keys(jobs: pd.DataFrame, beyond_paper: dict[str, list[str]]) -> dict[str, str]:
    """Row label per job: its ``row_names`` name; a run that goes beyond the paper (a preset,
    another family, demonstrations, several cars) carries "(beyond paper: ...)" so a
    replication is never mistaken for an improvement."""
    return {job_id: with_setup(name, beyond_paper.get(job_id) or [])
            for job_id, name in row_names(jobs).items()}


def ordered_rows(jobs: pd.DataFrame, keys: dict[str, str]) -> list[tuple[str, str]]:
    """(row key, family), families in order of first appearance (the spec's order)."""
    fam_order = list(dict.fromkeys(jobs["family"].astype(str)))
    seen: dict[str, str] = {}
    for _, job in jobs.iterrows():
        seen.setdefault(keys[str(job["job_id"])], str(job["family"]))
    return sorted(seen.items(), key=lambda kv: fam_order.index(kv[1]))


@dataclass
class Context:
    """Frames every table (and figure) needs, computed once per report."""

    data: TournamentData
    jobs: pd.DataFrame
    runs: pd.DataFrame
    models: pd.DataFrame
    limits: dict[str, float]
    row_keys: dict[str, str]

    @classmethod
    def build(cls, data: TournamentData) -> Context:
        jobs = _jobs_with_tracks(data)
        models = metrics.model_table(data.tests)
        return cls(data=data, jobs=jobs, runs=metrics.run_table(models), models=models,
                   limits=reference_limits(data.baselines),
                   row_keys=_row_keys(jobs, data.beyond_paper))

    def runs_of(self, job_ids: list[str], track: str) -> pd.DataFrame:
        sel = self.runs["job_id"].isin(job_ids) & (self.runs["track"].astype(str) == track)
        return self.runs.loc[sel]


# --------------------------------------------------------------------------------------------
# Table 1


TABLE1_METRICS = ["bLT", "aLT", "95% CI", "IQM", "gap", "runs", "dmg"]
TABLE1_GLOSSARY = {
    "bLT": "best lap",
    "aLT": "mean over runs of each run's best lap",
    "95% CI": "percentile bootstrap interval of aLT",
    "IQM": "interquartile mean of the runs' best laps",
    "gap": "bLT above the track's reference limit",
    "runs": "runs with a clean lap / runs planned",
    "dmg": "mean cumulative test damage per run",
}
"""What Table 1's metrics mean; a view that leaves some out (LaTeX) describes only the rest."""


def group_label(part: str, track: str, reference: str, lac: bool) -> str:
    """``p1-oval: oval MOT + LAC``: the heading of one part x track x line group of runs."""
    return f"{part}: {track} {line_label(reference)}" + (" + LAC" if lac else "")


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
            "bot's racing line; MC: minimum curvature), lap times in seconds, for models with 0 "
            "damage."
        ),
        groups=[], metrics={}, glossary=dict(TABLE1_GLOSSARY),
    )
    groups: dict[str, dict[str, Any]] = {}
    for part in data.part_order():
        part_jobs = ctx.jobs.loc[ctx.jobs["part"] == part]
        for _, job in part_jobs.iterrows():
            for track in job["train_tracks"]:
                if track not in job["tested_tracks"]:
                    continue  # trained on it, never tested on it (generated tracks): Table 3
                label = group_label(part, track, job["reference"], bool(job["lac"]))
                grp = groups.setdefault(label, {"part": part, "track": track,
                                                "reference": job["reference"],
                                                "lac": bool(job["lac"]), "jobs": []})
                grp["jobs"].append(str(job["job_id"]))
    if not groups:
        table.notes.append("no jobs to report yet" if ctx.jobs.empty else
                           "no job is tested on a track it trains on (unseen tracks: Table 3)")
        return table
    table.groups = list(groups)
    table.metrics = {g: list(TABLE1_METRICS) for g in table.groups}
    rows = {key: table.add_row(key, "entrant", fam)
            for key, fam in ordered_rows(ctx.jobs, ctx.row_keys)}
    for label, grp in groups.items():
        limit = ctx.limits.get(grp["track"], math.nan)
        by_row: dict[str, list[str]] = {}
        for job_id in grp["jobs"]:
            by_row.setdefault(ctx.row_keys[job_id], []).append(job_id)
        for key, row in rows.items():
            job_ids = by_row.get(key, [])
            st = entry_stats(ctx.runs_of(job_ids, grp["track"]), len(job_ids), limit)
            fill_entry(row, label, st, TABLE1_METRICS)
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
        # one row per configuration and setup: a preset's runs never share another's row
        label = entrant_label(job["variant"], job["reference"], bool(job["lac"]),
                              ctx.data.beyond_paper.get(str(job["job_id"])) or [])
        cfg_jobs.setdefault(label, []).append(str(job["job_id"]))
    lac_jobs = jobs.loc[jobs["variant"].isin(lac_variants)]
    tracks = list(dict.fromkeys(t for train, tested in zip(lac_jobs["train_tracks"],
                                                           lac_jobs["tested_tracks"], strict=True)
                                for t in train if t in tested))  # fmt: skip
    if not tracks:
        table.notes.append("no LAC entrant is tested on a track it trains on (unseen tracks: "
                           "Table 3)")
        return table
    shown = ["bLT", "gap"]
    table.groups = tracks
    table.metrics = {t: list(shown) for t in tracks}
    train_of = dict(zip(jobs["job_id"].astype(str), jobs["train_tracks"], strict=True))
    for blabel, bot, ref in bot_rows(ctx.data.baselines):
        if bot != "follower":
            continue
        row = table.add_row(blabel, "bot")
        for track in tracks:
            res = bot_result(ctx.data.baselines, bot, ref, track)
            _fill_single(row, track, res["bLT"], res["status"],
                         ctx.limits.get(track, math.nan), shown)
    for label, job_ids in cfg_jobs.items():
        row = table.add_row(label, "entrant")
        for track in tracks:
            trained = [j for j in job_ids if track in train_of[j]]
            st = entry_stats(ctx.runs_of(trained, track), len(trained),
                             ctx.limits.get(track, math.nan))
            fill_entry(row, track, st, shown)
            if trained:
                table.records.append({"row": label, "track": track, **st})
    if any(t in ctx.limits for t in tracks):
        row = table.add_row(LIMIT_LABEL, "limit")
        for track in tracks:
            limit = ctx.limits.get(track, math.nan)
            _fill_single(row, track, limit, "ok" if np.isfinite(limit) else "missing", limit,
                         shown)
    return table


# --------------------------------------------------------------------------------------------
# Table 3


def stored_general_model(general: pd.DataFrame, models: pd.DataFrame,
                         job_ids: list[str], tracks: list[str]) -> dict[str, Any] | None:
    """The general model the tournament chose (``general_models`` with ``chosen``) among
    ``job_ids``, with its zero-damage lap per track from the tests; None where it chose none, so
    the report and the promotion step never disagree on which model is general."""
    if general.empty:
        return None
    chosen = general.loc[general["chosen"] & general["job_id"].astype(str).isin(job_ids)]
    if chosen.empty:
        return None
    ranks = [metrics.general_rank(_lap_or_nan(r["train_lap_s"]), r["laps"] or {},
                                  str(r["train_track"])) for _, r in chosen.iterrows()]  # fmt: skip
    pick = chosen.iloc[min(range(len(ranks)), key=ranks.__getitem__)]
    job_id, episode = str(pick["job_id"]), float(pick["episode"])
    mine = models.loc[(models["job_id"] == job_id) & (models["episode"] == episode)]
    laps = {t: float(mine.loc[mine["track"] == t, "clean_lap_s"].min()) for t in tracks}
    train = str(pick["train_track"])
    return {"job_id": job_id, "episode": episode, "laps": laps, "chosen_by": "tournament",
            "unseen_lapped": len(metrics.unseen_clean_laps(laps, train)),
            "unseen": len([t for t in tracks if t != train])}


def _unseen_lapped_per_run(ctx: Context, cfg: dict[str, Any]) -> str:
    """For runs never tested on their train tracks: the most unseen tracks one checkpoint of
    each run lapped cleanly (its general model's), e.g. "2, 3, 4 and 0 of 6 unseen tracks"."""
    counts = []
    for job_id in cfg["jobs"]:
        models = ctx.models.loc[ctx.models["job_id"] == job_id]
        pick = metrics.general_model(models, cfg["train"], cfg["tracks"], 0.0)
        counts.append(str(pick["unseen_lapped"] if pick is not None else 0))
    listed = counts[0] if len(counts) == 1 else f"{', '.join(counts[:-1])} and {counts[-1]}"
    return (f"{listed} of {len([t for t in cfg['tracks'] if t != cfg['train']])} unseen tracks "
            "lapped cleanly by one checkpoint")


def _lap_or_nan(value: Any) -> float:
    """A stored lap (None where SQLite held NULL for NaN) as a float."""
    return math.nan if value is None or pd.isna(value) else float(value)


def general_model_of(ctx: Context, job_ids: list[str], train_track: str, tracks: list[str],
                     min_unseen_finish_rate: float) -> dict[str, Any] | None:
    """The general model of one configuration: the tournament's stored choice where it made one,
    else ``results.metrics.general_model`` under the part's selection rule; None when no
    checkpoint qualifies."""
    models = ctx.models.loc[ctx.models["job_id"].isin(job_ids)]
    stored = stored_general_model(ctx.data.general_models, models, job_ids, tracks)
    if stored is not None:
        return stored
    pick = metrics.general_model(models, train_track, tracks, min_unseen_finish_rate)
    return None if pick is None else {**pick, "chosen_by": "report"}


def table3(ctx: Context) -> ReportTable:
    """Best vs general models on every track (paper, Table 3), for configurations tested on
    tracks they were not trained on."""
    table = ReportTable(
        key="table3", title="Table 3: fastest vs general models on every track",
        caption=(
            "Fastest models (bLT, aLT on the train track) compared with the general model (the "
            "best clean train-track lap among checkpoints that also finish a lap from the part's "
            "share of starts on every unseen track; for a run never tested on its train tracks, "
            "the checkpoint with clean laps on the most unseen tracks) on every test track, s. "
            "DNF: the general model has no clean lap there."
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
    several_trains = general_jobs["train_tracks"].map(lambda t: tuple(t)).nunique() > 1
    for _, job in general_jobs.iterrows():
        train = job["train_tracks"][0] if job["train_tracks"] else ""
        label = config_label(job["variant"], job["reference"], bool(job["lac"]))
        if several_trains:
            label += f" ({train})"
        cfg = cfgs.setdefault(label, {"train": train, "jobs": [], "tracks": []})
        cfg["jobs"].append(str(job["job_id"]))
        cfg["tracks"].extend(t for t in job["tested_tracks"] if t not in cfg["tracks"])
    trains = list(dict.fromkeys(c["train"] for c in cfgs.values()))
    # a train track no job was tested on (generated tracks) has no column: nothing to show
    tested = {t for c in cfgs.values() for t in c["tracks"]}
    all_tracks = list(dict.fromkeys([*(t for t in trains if t in tested),
                                     *(t for c in cfgs.values() for t in c["tracks"])]))
    best_group = "Best" if len(trains) == 1 else "Best (train track)"
    table.groups = [best_group, "General"]
    table.metrics = {best_group: ["bLT", "aLT", "gap"], "General": list(all_tracks)}
    table.lap_metrics = {"bLT", "aLT", *all_tracks}
    for label, cfg in cfgs.items():
        row = table.add_row(label, "entrant")
        limit = ctx.limits.get(cfg["train"], math.nan)
        st = entry_stats(ctx.runs_of(cfg["jobs"], cfg["train"]), len(cfg["jobs"]), limit)
        fill_entry(row, best_group, st, ["bLT", "aLT", "gap"])
        if cfg["train"] not in cfg["tracks"]:  # trained on tracks it is never tested on
            row["text"].update({(best_group, m): NOT_TESTED for m in ("bLT", "aLT", "gap")})
        tested = not ctx.models.loc[ctx.models["job_id"].isin(cfg["jobs"])].empty
        rate = ctx.data.unseen_finish_rate(
            ctx.jobs.loc[ctx.jobs["job_id"].isin(cfg["jobs"]), "part"].astype(str))
        which = general_model_of(ctx, cfg["jobs"], cfg["train"], cfg["tracks"], rate)
        laps = which["laps"] if which is not None else {}
        for track in all_tracks:
            lap = float(laps.get(track, math.nan))
            row["values"][("General", track)] = lap
            if track not in cfg["tracks"]:
                text = NOT_TESTED
            elif not tested:
                text = NO_RESULT
            elif which is None:
                text = NO_GENERAL
            else:
                text = fmt_lap(lap, DNF)
            row["text"][("General", track)] = text
        if which is not None:
            table.notes.append(
                f"general model of {label}: {which['job_id']} after {which['episode']:.0f} "
                f"episodes, clean laps on {which['unseen_lapped']} of {which['unseen']} unseen "
                "tracks" + (" (the tournament's choice)"
                            if which["chosen_by"] == "tournament" else "")
            )
        elif tested and cfg["train"] not in cfg["tracks"]:
            table.notes.append(f"{label}: no general model (no checkpoint laps any unseen "
                               "track cleanly)")
        elif tested:
            table.notes.append(
                f"{label}: no general model (no checkpoint with a clean {cfg['train']} lap "
                f"finishes a lap from {rate:.0%} of the starts on every unseen track)"
            )
        if tested and cfg["train"] not in cfg["tracks"]:
            table.notes.append(f"{label}, per run: {_unseen_lapped_per_run(ctx, cfg)}")
        table.records.append({"row": label, "train_track": cfg["train"], "jobs": cfg["jobs"],
                              "best": st, "general": which, "general_laps": laps})
    for blabel, bot, ref in bot_rows(ctx.data.baselines):
        row = table.add_row(blabel, "bot")
        if len(trains) == 1:
            res = bot_result(ctx.data.baselines, bot, ref, trains[0])
            _fill_single(row, best_group, res["bLT"], res["status"],
                         ctx.limits.get(trains[0], math.nan), ["bLT", "aLT", "gap"])
        else:  # one bot lap cannot stand for several train tracks
            row["text"].update({(best_group, m): NOT_APPLICABLE for m in ("bLT", "aLT", "gap")})
        for track in all_tracks:
            res = bot_result(ctx.data.baselines, bot, ref, track)
            row["values"][("General", track)] = res["bLT"]
            row["text"][("General", track)] = fmt_lap(
                res["bLT"], NOT_DRIVEN if res["status"] == "missing" else DNF)
    if any(t in ctx.limits for t in all_tracks):
        row = table.add_row(LIMIT_LABEL, "limit")
        if len(trains) == 1:
            limit = ctx.limits.get(trains[0], math.nan)
            _fill_single(row, best_group, limit, "ok" if np.isfinite(limit) else "missing",
                         limit, ["bLT", "aLT", "gap"])
        else:
            row["text"].update({(best_group, m): NOT_APPLICABLE for m in ("bLT", "aLT", "gap")})
        for track in all_tracks:
            limit = ctx.limits.get(track, math.nan)
            row["values"][("General", track)] = limit
            row["text"][("General", track)] = fmt_lap(limit, NOT_DRIVEN)
    return table


# --------------------------------------------------------------------------------------------
# probability of improvement


def comparisons(table_1: ReportTable) -> ReportTable:
    """For every Table 1 column: P(the leader by aLT beats each other entrant in one run).

    The leader is a row of its own ("leader"), so that a long entrant label never widens a
    column heading.
    """
    table = ReportTable(
        key="comparisons", title="Probability of improvement: P(leader faster than row)",
        caption=(
            "For each part, track and line: probability that a run of the leader (the entrant "
            "with the best aLT) has a faster best lap than a run of the row's entrant "
            "(Mann-Whitney U / (n_a n_b), 95% bootstrap CI, two-sided U test p-value). Runs "
            "without a clean lap are left out."
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
        title = group
        table.groups.append(title)
        table.metrics[title] = ["P(faster)", "95% CI", "p"]
        for rec in sorted(recs, key=lambda r: r is not leader):
            row = rows.get(rec["row"]) or table.add_row(rec["row"], "entrant")
            rows[rec["row"]] = row
            if rec is leader:
                row["text"].update({(title, "P(faster)"): LEADER, (title, "95% CI"): NOT_APPLICABLE,
                                    (title, "p"): NOT_APPLICABLE})
                continue
            cmp_ = stats.compare(leader["run_best_s"], rec["run_best_s"])
            row["values"][(title, "P(faster)")] = cmp_.prob
            row["values"][(title, "95% CI")] = ci_value(cmp_.low, cmp_.high)
            row["values"][(title, "p")] = cmp_.p_value
            row["text"][(title, "P(faster)")] = f"{cmp_.prob:.2f}"
            row["text"][(title, "95% CI")] = fmt_ci(cmp_.low, cmp_.high, NOT_APPLICABLE)
            row["text"][(title, "p")] = f"{cmp_.p_value:.3f}" if np.isfinite(cmp_.p_value) \
                else NOT_APPLICABLE
            table.records.append({"group": group, "leader": leader["row"], "row": rec["row"],
                                  **cmp_.as_dict()})
    status = {(r["group"], r["row"]): r["status"] for r in table_1.records}
    for group in table.groups:  # an entrant not compared in a column says why
        for label, row in rows.items():
            why = {None: NOT_RUN, "DNF": DNF, "missing": NO_RESULT}.get(
                status.get((group, label)), NOT_APPLICABLE)
            for metric in table.metrics[group]:
                row["text"].setdefault((group, metric), why)
    if not table.groups:
        table.notes.append("no column has two entrants with clean laps to compare")
    return table


def build_tables(ctx: Context) -> list[ReportTable]:
    """All report tables for one tournament, in the paper's order."""
    t1 = table1(ctx)
    return [t1, table2(ctx), table3(ctx), comparisons(t1)]
