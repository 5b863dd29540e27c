"""The claims of a results folder as a sequential run reads them after every wave.

``tourney.adaptive`` decides where a sequential run's next seeds go from the claims' verdicts,
but the tournament layer reads no report; the command line hands it :func:`judge`, which
evaluates the tournament's claims (its own ``[claims]``, else the paper's:
``report.claims.sources``) exactly as the report does (``report.claims.evaluate``) and returns
each claim's anytime-valid verdict with, per comparison, its confidence sequence and the
(part, entrant) of each side's runs: what an extra run of which entrant would add to.
"""

from __future__ import annotations

import math
from pathlib import Path

from formula_tourney.claims.sequential import pairs_to_decide
from formula_tourney.report.claims.evaluate import ClaimResult, Comparison, evaluate_all
from formula_tourney.report.claims.evidence import SEQUENTIAL
from formula_tourney.report.claims.sources import resolve_claims
from formula_tourney.report.load import load_tournament
from formula_tourney.report.paper_tables import Context
from formula_tourney.results.index import read_meta
from formula_tourney.tourney.adaptive import INCONCLUSIVE, ClaimLook, Look


def _targets(ctx: Context, job_ids: list[str]) -> tuple[tuple[str, str], ...]:
    """The (part, entrant) of each run, in first-seen order; none for a bot."""
    jobs = ctx.jobs.set_index(ctx.jobs["job_id"].astype(str))
    out = {}
    for job_id in job_ids:
        if job_id in jobs.index:
            row = jobs.loc[job_id]
            out[(str(row["part"]), str(row["entrant"]))] = None
    return tuple(out)


def _look(ctx: Context, claim_id: str, comp: Comparison) -> Look:
    seq = comp.stats.sequence
    a_fixed = any(r.startswith("bot:") for r in comp.a_runs)
    b_fixed = any(r.startswith("bot:") for r in comp.b_runs)
    return Look(
        claim=claim_id, label=comp.label, verdict=comp.stats.sequential,
        a_targets=() if a_fixed else _targets(ctx, comp.a_runs),
        b_targets=() if b_fixed else _targets(ctx, comp.b_runs),
        n_a=len(comp.a_runs), n_b=len(comp.b_runs), pairs=seq.n if seq else 0,
        mean=seq.mean if seq else math.nan, low=seq.low if seq else math.nan,
        high=seq.high if seq else math.nan,
        needed=pairs_to_decide(seq) if seq else None,
        heading=INCONCLUSIVE if seq is None or seq.mean == seq.threshold
        else SEQUENTIAL["above" if seq.mean > seq.threshold else "below"],
    )  # fmt: skip


def claim_look(ctx: Context, result: ClaimResult) -> ClaimLook:
    """One evaluated claim as the sequential run reads it."""
    return ClaimLook(
        result.claim.id,
        result.sequential,
        tuple(_look(ctx, result.claim.id, c) for c in result.comparisons),
    )


def judge(root: Path) -> list[ClaimLook]:
    """Every claim of the tournament in ``root``, read from its results now."""
    claims, _origin = resolve_claims([], read_meta(root))
    ctx = Context.build(load_tournament(root))
    return [claim_look(ctx, res) for res in evaluate_all(ctx, claims)]
