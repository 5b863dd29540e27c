"""Evaluate claims on a tournament's results: pick each side's runs, score them, compare.

A claim (``claims.schema.Claim``) names two groups; this module finds the runs of each in the
report's :class:`~formula_tourney.report.paper_tables.Context` (the jobs of the index with their
run specs), turns every run into one score with the report's own metrics (``results.metrics``
through ``Context.runs``: a run's best clean lap on a track; the share of its unseen test tracks
it lapped cleanly; the highest moving average of its training reward, smoothed like the
figures), and hands the scores to ``report.claims.evidence``. B never holds a run of A. A claim
with ``split_b`` or ``per_track`` is several comparisons with one overall verdict.

A run entered again in another part with the same seed and training settings (only its tests
differ) trains the same agent step for step: it is one sample, not two, so each side keeps the
first of the runs sharing a ``results.identity.training_digest`` and B drops any run A has.

Scores are "higher is better": a lap time enters negated, so every effect is positive when A is
better (for laps: B's mean best lap minus A's, in seconds).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.claims.schema import Claim, Group
from formula_tourney.report.claims import evidence
from formula_tourney.report.claims.evidence import ClaimStats
from formula_tourney.report.paper_tables import Context, bot_result
from formula_tourney.report.plots import moving_average
from formula_tourney.results.identity import training_digest

REPEATED = ("run(s) repeating another run's training (same seed and settings, other tests) "
            "counted once")

UNITS = {"faster": "s", "finishes_more": "% of unseen tracks", "higher_reward": "reward"}
"""Unit of each kind's effect (laps: seconds of mean best lap; finishes: percentage points)."""


@dataclass
class Comparison:
    """One comparison of a claim: which runs, their scores and the statistics."""

    label: str
    track: str | None
    a_runs: list[str]
    b_runs: list[str]
    a_scores: list[float]
    b_scores: list[float]
    stats: ClaimStats
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"label": self.label, "track": self.track, "a_runs": self.a_runs,
                "b_runs": self.b_runs, "a_scores": self.a_scores, "b_scores": self.b_scores,
                **self.stats.as_dict(), "note": self.note}


@dataclass
class ClaimResult:
    """A claim with its comparisons and overall verdict."""

    claim: Claim
    comparisons: list[Comparison] = field(default_factory=list)
    verdict: str = evidence.NO_DATA
    notes: list[str] = field(default_factory=list)

    @property
    def unit(self) -> str:
        return UNITS[self.claim.kind]

    def to_json(self) -> dict[str, Any]:
        c = self.claim
        return {"id": c.id, "statement": c.statement, "source": c.source, "kind": c.kind,
                "unit": self.unit, "a": c.a.describe(), "b": c.b.describe(),
                "verdict": self.verdict, "notes": self.notes,
                "comparisons": [x.to_json() for x in self.comparisons]}


# ------------------------------------------------------------------------------- selecting


def _names_match(value: Any, patterns: list[str] | None) -> bool:
    if patterns is None:
        return True
    text = str(value).lower()
    return any(fnmatch.fnmatchcase(text, p.lower()) for p in patterns)


def _settings_of(ctx: Context, job_id: str) -> dict[str, Any]:
    spec = ctx.data.configs.get(job_id) or {}
    return {**(spec.get("env") or {}), **(spec.get("agent") or {})}


def first_train_track(job: pd.Series) -> str:
    """Where a run's lap times count (``RunSpec.key_track``: its first train track)."""
    tracks = job["train_tracks"]
    return str(tracks[0]) if len(tracks) else ""


def select_jobs(ctx: Context, group: Group) -> pd.DataFrame:
    """The jobs of the index that match every selector of ``group`` (a run group)."""
    jobs = ctx.jobs
    if jobs.empty:
        return jobs
    keep = []
    for _, job in jobs.iterrows():
        settings = _settings_of(ctx, str(job["job_id"])) if group.settings else {}
        ok = (_names_match(job["part"], group.part)
              and _names_match(job["entrant"], group.entrant)
              and _names_match(job["variant"], group.variant)
              and _names_match(job["family"], group.family)
              and (group.reference is None or str(job["reference"]) in group.reference)
              and (group.lac is None or bool(job["lac"]) == group.lac)
              and _names_match(first_train_track(job), group.train_track)
              and all(k in settings and settings[k] == v
                      for k, v in (group.settings or {}).items()))  # fmt: skip
        keep.append(ok)
    return jobs.loc[np.asarray(keep, dtype=bool)]


def training_key(ctx: Context, job_id: str) -> str:
    """The run's ``results.identity.training_digest`` ("" without a stored run spec)."""
    spec = ctx.data.configs.get(job_id)
    return training_digest(spec) if isinstance(spec, dict) and spec else ""


def distinct_runs(ctx: Context, ids: list[str], values: list[float], taken: set[str]
                  ) -> tuple[list[str], list[float], int]:
    """The scored runs less those repeating the training of an earlier one (or of one whose
    digest is in ``taken``), and how many were dropped; ``taken`` gains the kept runs' digests.
    Scored first, so the repeat kept is one with a result (a run tested on unseen tracks,
    not its twin tested only where it trained)."""
    kept_ids, kept_values, dropped = [], [], 0
    for job_id, value in zip(ids, values, strict=True):
        key = training_key(ctx, job_id)
        if key and key in taken:
            dropped += 1
            continue
        if key:
            taken.add(key)
        kept_ids.append(job_id)
        kept_values.append(value)
    return kept_ids, kept_values, dropped


def _pair_key(job: pd.Series, keys: list[str]) -> tuple[Any, ...]:
    return tuple(first_train_track(job) if k == "train_track" else job[k] for k in keys)


def paired(a: pd.DataFrame, b: pd.DataFrame, keys: list[str]
           ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Only the runs of A and B whose ``keys`` values the other side has too."""
    if not keys or a.empty or b.empty:
        return a, b
    ka = [_pair_key(j, keys) for _, j in a.iterrows()]
    kb = [_pair_key(j, keys) for _, j in b.iterrows()]
    return (a.loc[np.asarray([k in set(kb) for k in ka], dtype=bool)],
            b.loc[np.asarray([k in set(ka) for k in kb], dtype=bool)])


# ------------------------------------------------------------------------------- scoring


def lap_score(ctx: Context, job_id: str, track: str) -> float:
    """-(best clean lap on ``track``); -inf when the run was tested there without one; nan
    when it has no test there (not a run of this comparison)."""
    rows = ctx.runs.loc[(ctx.runs["job_id"] == job_id) & (ctx.runs["track"].astype(str) == track)]
    if rows.empty:
        return math.nan
    lap = float(rows["run_best_s"].min())
    return -lap if math.isfinite(lap) else -math.inf


def unseen_finish_score(ctx: Context, job: pd.Series) -> float:
    """Percent of the run's unseen test tracks (tested, not trained on) with a clean lap; nan
    for a run without unseen tracks or without any test."""
    job_id = str(job["job_id"])
    mine = ctx.runs.loc[ctx.runs["job_id"] == job_id]
    unseen = [t for t in job["tested_tracks"] if t not in job["train_tracks"]]
    if mine.empty or not unseen:
        return math.nan
    best = dict(zip(mine["track"].astype(str), mine["run_best_s"], strict=True))
    return 100.0 * float(np.mean([math.isfinite(float(best.get(t, math.nan))) for t in unseen]))


def reward_score(ctx: Context, job_id: str, smooth: int) -> float:
    """The highest moving average (``smooth`` episodes, the figures' smoothing) of the run's
    training reward; nan without episodes."""
    ep = ctx.data.episodes
    mine = ep.loc[ep["job_id"] == job_id].sort_values("episode")
    rewards = pd.to_numeric(mine["reward"], errors="coerce").dropna().to_numpy(dtype=float)
    if rewards.size == 0:
        return math.nan
    return float(np.nanmax(moving_average(rewards, smooth)))


def bot_score(ctx: Context, group: Group, track: str) -> float:
    """-(the bot's best clean lap on ``track``); -inf for a DNF; nan when it did not drive."""
    res = bot_result(ctx.data.baselines, str(group.bot), group.bot_reference, track)
    if res["status"] == "missing":
        return math.nan
    return -float(res["bLT"]) if res["status"] == "ok" else -math.inf


def scores(ctx: Context, claim: Claim, jobs: pd.DataFrame, track: str | None
           ) -> tuple[list[str], list[float]]:
    """(job ids, scores) of the runs in ``jobs`` that have a value for this claim."""
    ids, values = [], []
    for _, job in jobs.iterrows():
        job_id = str(job["job_id"])
        if claim.kind == "faster":
            value = lap_score(ctx, job_id, track or first_train_track(job))
        elif claim.kind == "finishes_more":
            value = unseen_finish_score(ctx, job)
        else:
            value = reward_score(ctx, job_id, claim.smooth)
        if not math.isnan(value):
            ids.append(job_id)
            values.append(value)
    return ids, values


# ------------------------------------------------------------------------------- comparing


def _side(ctx: Context, claim: Claim, group: Group, jobs: pd.DataFrame | None,
          track: str | None) -> tuple[list[str], list[float], bool]:
    if group.is_bot:
        if track is None:
            return [], [], True
        value = bot_score(ctx, group, track)
        return ([f"bot:{group.bot}"], [value], True) if not math.isnan(value) else ([], [], True)
    ids, values = scores(ctx, claim, jobs if jobs is not None else ctx.jobs.iloc[0:0], track)
    return ids, values, False


def _compare(ctx: Context, claim: Claim, label: str, a_jobs: pd.DataFrame | None,
             b_jobs: pd.DataFrame | None, track: str | None) -> Comparison:
    if a_jobs is not None and b_jobs is not None:
        a_jobs, b_jobs = paired(a_jobs, b_jobs, list(claim.pair_on))
    notes = []
    taken: set[str] = set()  # after pairing: a repeat in an unpaired part must not win
    a_ids, a_vals, a_fixed = _side(ctx, claim, claim.a, a_jobs, track)
    b_ids, b_vals, b_fixed = _side(ctx, claim, claim.b, b_jobs, track)
    if not a_fixed:
        a_ids, a_vals, dropped = distinct_runs(ctx, a_ids, a_vals, taken)
        if dropped:
            notes.append(f"A: {dropped} {REPEATED}")
    if not b_fixed:
        b_ids, b_vals, dropped = distinct_runs(ctx, b_ids, b_vals, taken)
        if dropped:
            notes.append(f"B: {dropped} {REPEATED}")
    st = evidence.compare_scores(a_vals, b_vals, a_fixed, b_fixed)
    missing = [name for name, ids in (("A", a_ids), ("B", b_ids)) if not ids]
    if missing:
        where = f" on {track}" if track else ""
        notes.insert(0, " and ".join(missing) + f": no runs with a result{where}")
    return Comparison(label, track, a_ids, b_ids, a_vals, b_vals, st, "; ".join(notes))


def evaluate(ctx: Context, claim: Claim) -> ClaimResult:
    """Every comparison of one claim and its overall verdict; a claim whose runs do not exist
    says so in its notes (and is 'no data')."""
    result = ClaimResult(claim)
    a_all = None if claim.a.is_bot else select_jobs(ctx, claim.a)
    b_all = None if claim.b.is_bot else select_jobs(ctx, claim.b)
    if a_all is not None and b_all is not None:
        b_all = b_all.loc[~b_all["job_id"].isin(a_all["job_id"])]
    for name, group, found in (("A", claim.a, a_all), ("B", claim.b, b_all)):
        if found is not None and found.empty:
            result.notes.append(f"{name} ({group.describe()}): no run of this tournament "
                                "matches")
    fixed_track = None if claim.track == "own" else claim.track
    comparisons: list[Comparison] = []
    if claim.per_track:
        base = a_all if a_all is not None else b_all
        tracks = list(dict.fromkeys(first_train_track(j) for _, j in base.iterrows())) \
            if base is not None else []
        for track in tracks:
            sub_a = a_all.loc[[first_train_track(j) == track for _, j in a_all.iterrows()]] \
                if a_all is not None else None
            sub_b = b_all
            if a_all is None and b_all is not None:
                sub_b = b_all.loc[[first_train_track(j) == track for _, j in b_all.iterrows()]]
            comparisons.append(_compare(ctx, claim, f"on {track}", sub_a, sub_b, track))
    elif claim.split_b != "none" and b_all is not None:
        for value, sub_b in b_all.groupby(claim.split_b, sort=False):
            comparisons.append(_compare(ctx, claim, f"vs {claim.split_b} {value}", a_all,
                                        sub_b, fixed_track))
    else:
        comparisons.append(_compare(ctx, claim, "", a_all, b_all, fixed_track))
    if claim.kind == "faster" and fixed_track is None and (claim.a.is_bot or claim.b.is_bot) \
            and not claim.per_track:
        result.notes.append("a bot needs a track: set track or per_track")
    result.comparisons = comparisons
    result.verdict = evidence.overall([c.stats.verdict for c in comparisons])
    return result


def evaluate_all(ctx: Context, claims: list[Claim]) -> list[ClaimResult]:
    """Every claim, in the order given."""
    return [evaluate(ctx, claim) for claim in claims]
