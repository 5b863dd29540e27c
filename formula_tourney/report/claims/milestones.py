"""A run's CPU-seconds to a milestone as a claim's score: what ``learns_faster`` claims compare.

The milestones and their timing are ``results.competence``'s (the time-to-competence table
reads the same): the first test round on the run's key track with a clean lap, or with a clean
lap faster than the follower on the centre or on the min-curvature line of the run's part
(``report.competence_table.part_bots``), timed by the round's CPU-seconds of training. The
score is minus those seconds (higher is better, as every claim score). A run that never
reached the milestone scores -inf, which the fixed-sample statistics count as the worst run
and the sequential statistics as its CPU budget (``budget_cpu_s``: it trained that long and
stopped without it), or, without a budget, as its whole training time: a missed milestone
is at least that far.
"""

from __future__ import annotations

import math

import pandas as pd

from formula_tourney.report.competence_table import part_bots
from formula_tourney.report.paper_tables import Context
from formula_tourney.results import competence
from formula_tourney.results.folder import CorruptResultError, JobFolder

NO_BOTS = competence.Bots(math.inf, math.inf, math.nan)
"""Where a part raced no bot: only the first clean lap can be reached."""


def _competence(ctx: Context, job: pd.Series) -> dict | None:
    """``results.competence.job_competence`` of a finished, timed run (None otherwise)."""
    job_id = str(job["job_id"])
    if str(job.get("status")) != "done":
        return None
    folder = JobFolder(ctx.data.job_dir(job_id))
    try:
        track = str(folder.summary()["track"])
        if not competence.timed(folder.tests()):
            return None
        bots = part_bots(ctx.data.baselines, str(job["part"]), track) or NO_BOTS
        return competence.job_competence(folder, track, bots)
    except (CorruptResultError, OSError, KeyError) as err:
        ctx.data.problems.append(f"{job_id}: no time to a milestone: {err}")
        return None


def milestone_score(ctx: Context, job: pd.Series, milestone: str) -> float:
    """-(CPU-s to ``milestone``); -inf when the run missed it; nan for a run without timed
    tests (or whose part raced no bot the milestone needs)."""
    run = _competence(ctx, job)
    if run is None:
        return math.nan
    limit = run["limits_s"].get(milestone)
    if milestone != "first_clean_lap" and limit is None:
        return math.nan  # no bot to beat in this part
    cpu_s = run["cpu_s"].get(milestone)
    return -float(cpu_s) if cpu_s is not None else -math.inf


def milestone_budget_s(ctx: Context, job_id: str) -> float:
    """What a missed milestone counts as: the run's CPU budget, else its training CPU-s."""
    spec = ctx.data.configs.get(job_id) or {}
    budget = (spec.get("schedule") or {}).get("budget_cpu_s")
    if budget is not None:
        return float(budget)
    try:
        total = JobFolder(ctx.data.job_dir(job_id)).summary().get("cpu_s")
    except (CorruptResultError, OSError):
        return math.nan
    return float(total) if total is not None else math.nan
