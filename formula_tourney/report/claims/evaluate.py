"""Evaluate claims on a tournament's results: pick each side's runs, score them, compare.

A claim (``claims.schema.Claim``) names two groups; this module finds the runs of each in the
report's :class:`~formula_tourney.report.paper_tables.Context` (the jobs of the index with their
run specs), turns every run into one score with the report's own metrics (``results.metrics``
through ``Context.runs``: a run's best clean lap on a track; the share of its unseen test tracks
it lapped cleanly; the highest moving average of its training reward, smoothed like the
figures), and hands the scores to ``report.claims.evidence``. B never holds a run of A.

Like is compared with like: each side is split into entrants (``report.claims.entrants``: runs
alike in variant, line, train track and setup, less what the claim's ``pool`` names), and each
entrant of A is compared with each entrant of B of the same setup. A claim is so several
comparisons (more again with ``split_b`` or ``per_track``) with one overall verdict: it holds
only if every comparison supports it.

A run entered again in another part with the same seed and training settings (only its tests
differ) trains the same agent step for step: it is one sample, not two, so each side keeps the
first of the runs sharing a ``results.identity.training_digest`` and B drops any run A has.

Scores are "higher is better": a lap time enters negated, so every effect is positive when A is
better (for laps: B's mean best lap minus A's, in seconds; for milestones: B's mean CPU-seconds
to it minus A's). Each side's scores are in seed order, and every comparison has its
:class:`~formula_tourney.report.claims.evidence.Scale` (the bounds of a score, from the data
model), so that it also gets its anytime-valid sequential verdict (``claims.sequential``).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.claims import sequential
from formula_tourney.claims.schema import Claim, Group
from formula_tourney.report.claims import evidence
from formula_tourney.report.claims.entrants import Entrant, entrants, first_train_track
from formula_tourney.report.claims.evidence import ClaimStats, Scale
from formula_tourney.report.claims.milestones import milestone_budget_s, milestone_score
from formula_tourney.report.paper_tables import Context, bot_result
from formula_tourney.report.plots import moving_average
from formula_tourney.results.identity import training_digest

PAPER_PRESET = "paper"
"""The preset of a run spec that names none (``RunSpec.preset``'s default)."""
REPEATED = ("run(s) repeating another run's training (same seed and settings, other tests) "
            "counted once")

UNITS = {"faster": "s", "finishes_more": "% of unseen tracks", "higher_reward": "reward",
         "learns_faster": "CPU-s"}
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
    pair_cpu_s: float = math.nan
    """Measured CPU-seconds of one more pair: the mean job of each side with runs (a bot's
    side costs nothing); what the projection of a still open comparison is priced at."""

    @property
    def pairs_to_decide(self) -> int | None:
        """Pairs its confidence sequence would need in all (``sequential.pairs_to_decide``)."""
        seq = self.stats.sequence
        return sequential.pairs_to_decide(seq) if seq is not None else None

    @property
    def cpu_h_to_decide(self) -> float:
        """CPU-hours of the pairs it still needs at the measured cost per pair (0 if
        decided; nan without a projection or a cost)."""
        need, seq = self.pairs_to_decide, self.stats.sequence
        if need is None or seq is None:
            return math.nan
        return max(0, need - seq.n) * self.pair_cpu_s / 3600.0

    def to_json(self) -> dict[str, Any]:
        return {"label": self.label, "track": self.track, "a_runs": self.a_runs,
                "b_runs": self.b_runs, "a_scores": self.a_scores, "b_scores": self.b_scores,
                **self.stats.as_dict(), "note": self.note, "pair_cpu_s": self.pair_cpu_s,
                "pairs_to_decide": self.pairs_to_decide,
                "cpu_h_to_decide": self.cpu_h_to_decide}


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

    @property
    def sequential(self) -> str:
        """The claim's anytime-valid verdict: its comparisons' sequential verdicts combined."""
        return evidence.overall([c.stats.sequential for c in self.comparisons])

    def to_json(self) -> dict[str, Any]:
        c = self.claim
        return {"id": c.id, "statement": c.statement, "source": c.source, "kind": c.kind,
                "unit": self.unit, "decide_on": c.decide_on, "a": c.a.describe(),
                "b": c.b.describe(),
                "verdict": self.verdict, "sequential": self.sequential, "notes": self.notes,
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


def preset_of(ctx: Context, job_id: str) -> str:
    """The preset a run started from ("" for a job that wrote no run spec yet)."""
    spec = ctx.data.configs.get(job_id)
    return str(spec.get("preset") or PAPER_PRESET) if spec else ""


def _labels_match(labels: list[str], patterns: list[str] | None) -> bool:
    """Each pattern matches one of the run's beyond-paper labels; [] wants none at all."""
    if patterns is None:
        return True
    if not patterns:
        return not labels
    return all(any(fnmatch.fnmatchcase(label.lower(), p.lower()) for label in labels)
               for p in patterns)


def select_jobs(ctx: Context, group: Group) -> pd.DataFrame:
    """The jobs of the index that match every selector of ``group`` (a run group)."""
    jobs = ctx.jobs
    if jobs.empty:
        return jobs
    keep = []
    for _, job in jobs.iterrows():
        job_id = str(job["job_id"])
        settings = _settings_of(ctx, job_id) if group.settings else {}
        ok = (_names_match(job["part"], group.part)
              and _names_match(job["entrant"], group.entrant)
              and _names_match(job["variant"], group.variant)
              and _names_match(job["family"], group.family)
              and (group.preset is None or _names_match(preset_of(ctx, job_id), group.preset))
              and _labels_match(ctx.data.beyond_paper.get(job_id) or [], group.beyond_paper)
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


def bot_name(ctx: Context, group: Group, track: str | None) -> str:
    """The bot side in a comparison's label, with the line whose lap it scored where the
    claim left the line open (its best line: ``follower bot on mincurv``)."""
    name = group.describe()
    if group.bot_reference is not None or group.label or track is None:
        return name
    res = bot_result(ctx.data.baselines, str(group.bot), None, track)
    return f"{name} on {res['reference']}" if res["status"] == "ok" else name


def scores(ctx: Context, claim: Claim, jobs: pd.DataFrame, track: str | None
           ) -> tuple[list[str], list[float]]:
    """(job ids, scores) of the runs in ``jobs`` that have a value for this claim."""
    ids, values = [], []
    for _, job in jobs.iterrows():
        job_id = str(job["job_id"])
        if claim.kind == "faster":
            value = lap_score(ctx, job_id, track or first_train_track(job))
        elif claim.kind == "learns_faster":
            value = milestone_score(ctx, job, str(claim.milestone))
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


def seed_ordered(ctx: Context, ids: list[str], values: list[float]
                 ) -> tuple[list[str], list[float]]:
    """The runs in seed order (the order a sequential run adds them; ties in job order), so
    that the i-th run of A meets the i-th of B in the paired differences."""
    seeds = dict(zip(ctx.jobs["job_id"].astype(str), ctx.jobs["seed"], strict=True))
    order = sorted(range(len(ids)), key=lambda k: (int(seeds.get(ids[k], 0) or 0), k))
    return [ids[k] for k in order], [values[k] for k in order]


def _longest_timed_lap_s(ctx: Context, job_id: str) -> float:
    """The longest lap a run's test can time: its test step limit times the control period."""
    spec = ctx.data.configs.get(job_id) or {}
    steps = (spec.get("schedule") or {}).get("test_max_steps")
    period = (spec.get("env") or {}).get("control_period_s")
    return float(steps) * float(period) if steps and period else math.nan


def scale_of(ctx: Context, claim: Claim, runs: list[str], values: list[float],
             track: str | None) -> Scale:
    """The bounds of a comparison's scores (``evidence.Scale``), from the data model where it
    has them. A lap is never faster than the track's reference limit (the physics' bound,
    ``lines.limit``, stored with the bots' drives), and counts at most ``bound`` seconds above
    it (default: one limit, i.e. twice the limit; never more than the longest lap a test can
    time): a slower lap, and a run without a clean lap, count as that slowest lap. Without a
    limit (no bot drove the track) laps count in [0, the longest lap a test can time]. Finish
    shares lie in [0, 100]; the CPU-s to a milestone in [0, budget] (a miss counts as the
    budget). A reward has no bound in the data model: the claim's ``bound``, else the range
    the scores span (then the sequence is only as valid as that range)."""
    if claim.kind == "faster":
        caps = [_longest_timed_lap_s(ctx, r) for r in runs if not r.startswith("bot:")]
        cap = max([c for c in caps if math.isfinite(c)], default=math.nan)
        limit = ctx.limits.get(track or "", math.nan) if track else math.nan
        if not (math.isfinite(limit) and limit > 0.0):
            floor = 0.0
            slowest = claim.bound if claim.bound is not None else cap
        else:  # a lap counts at most `bound` (default: one limit) above the limit
            floor = limit
            slowest = min(cap, limit + (claim.bound if claim.bound is not None else limit))
        return Scale(miss=-slowest, best=-floor)
    if claim.kind == "finishes_more":
        return Scale(miss=0.0, best=100.0)
    if claim.kind == "learns_faster":
        budgets = [milestone_budget_s(ctx, r) for r in runs]
        budget = max([b for b in budgets if math.isfinite(b)], default=math.nan)
        return Scale(miss=-budget, best=0.0)
    finite = [v for v in values if math.isfinite(v)]
    if claim.bound is not None:
        low = min(finite, default=0.0)
        return Scale(miss=low, best=low + claim.bound)
    low, high = min(finite, default=0.0), max(finite, default=0.0)
    return Scale(miss=low, best=high if high > low else low + 1.0)


def _compare(ctx: Context, claim: Claim, label: str, a_jobs: pd.DataFrame | None,
             b_jobs: pd.DataFrame | None, track: str | None) -> Comparison:
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
    scale = scale_of(ctx, claim, [*a_ids, *b_ids], [*a_vals, *b_vals], track)
    seq = evidence.sequence_of(seed_ordered(ctx, a_ids, a_vals)[1],
                               seed_ordered(ctx, b_ids, b_vals)[1], a_fixed, b_fixed, scale,
                               claim.decide_on)
    st = evidence.compare_scores(a_vals, b_vals, a_fixed, b_fixed, sequence=seq)
    missing = [name for name, ids in (("A", a_ids), ("B", b_ids)) if not ids]
    if missing:
        where = f" on {track}" if track else ""
        notes.insert(0, " and ".join(missing) + f": no runs with a result{where}")
    pair_s = sum(_mean_cpu_s(ctx, ids) for ids, fixed in ((a_ids, a_fixed), (b_ids, b_fixed))
                 if not fixed)
    return Comparison(label, track, a_ids, b_ids, a_vals, b_vals, st, "; ".join(notes),
                      pair_cpu_s=pair_s)


def _mean_cpu_s(ctx: Context, job_ids: list[str]) -> float:
    """Mean measured seconds of these jobs (the index's ``wall_s``: one-thread workers, so
    their CPU-seconds); nan where none has one."""
    if not job_ids or "wall_s" not in ctx.jobs.columns:
        return math.nan
    rows = ctx.jobs.loc[ctx.jobs["job_id"].isin(job_ids), "wall_s"]
    return float(pd.to_numeric(rows, errors="coerce").mean())


def _split(ctx: Context, claim: Claim, group: Group, jobs: pd.DataFrame | None
           ) -> list[Entrant | None]:
    """A side as entrants (``report.claims.entrants``, less what the claim pools); a bot side
    is one fixed value, [None]."""
    if jobs is None:
        return [None]
    return entrants(ctx, jobs, claim.pool, pooled_name=group.describe())


def _entrant_comparisons(ctx: Context, claim: Claim, base: str, a_jobs: pd.DataFrame | None,
                         b_jobs: pd.DataFrame | None, track: str | None,
                         notes: list[str]) -> list[Comparison]:
    """One comparison per entrant of A and entrant of B that are alike: the same setup unless
    the claim pools it, and runs sharing the ``pair_on`` values. ``base`` names the slice (a
    track, a family of B) where the entrants' labels do not. A side without runs is one
    comparison saying so; entrants that are never alike are a note."""
    a_ents = _split(ctx, claim, claim.a, a_jobs)
    b_ents = _split(ctx, claim, claim.b, b_jobs)
    if not a_ents or not b_ents:
        return [_compare(ctx, claim, base, a_jobs, b_jobs, track)]
    out = []
    for ent_a in a_ents:
        for ent_b in b_ents:
            if ent_a is not None and ent_b is not None and not ent_a.same_setup(ent_b):
                continue
            sub_a = None if ent_a is None else ent_a.jobs
            sub_b = None if ent_b is None else ent_b.jobs
            if claim.pair_on and sub_a is not None and sub_b is not None:
                sub_a, sub_b = paired(sub_a, sub_b, list(claim.pair_on))
                if sub_a.empty or sub_b.empty:
                    continue
            pair = (f"{bot_name(ctx, claim.a, track) if ent_a is None else ent_a.label} vs "
                    f"{bot_name(ctx, claim.b, track) if ent_b is None else ent_b.label}")
            out.append(_compare(ctx, claim, f"{base}: {pair}" if base else pair, sub_a, sub_b,
                                track))
    if not out:
        alike = "the same setup" + (f" and {'/'.join(claim.pair_on)}" if claim.pair_on else "")
        notes.append((f"{base}: " if base else "") + f"no entrant of A has one of B with {alike} "
                     "to compare with (a claim's pool names what may differ)")
    return out


def _slices(claim: Claim, a_all: pd.DataFrame | None, b_all: pd.DataFrame | None,
            fixed_track: str | None
            ) -> list[tuple[str, pd.DataFrame | None, pd.DataFrame | None, str | None]]:
    """(label, A's runs, B's runs, track) of each part of a claim: one per train track with
    ``per_track``, one per family/variant/entrant of B with ``split_b``, else the whole claim.
    The label is kept only where the entrants' own labels do not say it."""
    if claim.per_track:
        base = a_all if a_all is not None else b_all
        tracks = list(dict.fromkeys(first_train_track(j) for _, j in base.iterrows())) \
            if base is not None else []
        named = "train_track" in claim.pool or a_all is None
        out = []
        for track in tracks:
            sub_a = a_all.loc[[first_train_track(j) == track for _, j in a_all.iterrows()]] \
                if a_all is not None else None
            sub_b = b_all
            if a_all is None and b_all is not None:
                sub_b = b_all.loc[[first_train_track(j) == track for _, j in b_all.iterrows()]]
            elif b_all is not None:  # B's runs with a lap on this track: trained or tested here
                sub_b = b_all.loc[[_drives(j, track) for _, j in b_all.iterrows()]]
            out.append((f"on {track}" if named else "", sub_a, sub_b, track))
        return out
    if claim.split_b != "none" and b_all is not None:
        named = "variant" in claim.pool
        return [(f"vs {claim.split_b} {value}" if named else "", a_all, sub_b, fixed_track)
                for value, sub_b in b_all.groupby(claim.split_b, sort=False)]
    return [("", a_all, b_all, fixed_track)]


def _drives(job: pd.Series, track: str) -> bool:
    """Whether a run can have a lap on ``track``: trained there, or tested there (or planned
    to be). A per-track claim compares on each track only the runs of B that drive it, so a
    run of B trained and tested elsewhere is not a comparison without data on that track."""
    return first_train_track(job) == track or track in list(job.get("tested_tracks") or [])


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
    for label, sub_a, sub_b, track in _slices(claim, a_all, b_all, fixed_track):
        result.comparisons.extend(
            _entrant_comparisons(ctx, claim, label, sub_a, sub_b, track, result.notes))
    if claim.kind == "faster" and fixed_track is None and (claim.a.is_bot or claim.b.is_bot) \
            and not claim.per_track:
        result.notes.append("a bot needs a track: set track or per_track")
    result.verdict = evidence.overall([c.stats.verdict for c in result.comparisons])
    return result


def evaluate_all(ctx: Context, claims: list[Claim]) -> list[ClaimResult]:
    """Every claim, in the order given."""
    return [evaluate(ctx, claim) for claim in claims]
