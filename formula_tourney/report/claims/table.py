"""The claims section as a report table: one row per comparison, one note per claim.

Built as a ``ReportTable`` so that the terminal, Markdown, LaTeX, HTML and ``--json`` renderers
show it like every other table (``report.renderers``, ``report.html``); the numbers are the
``ClaimResult``'s (``report.claims.evaluate``), formatted here and never recomputed.
"""

from __future__ import annotations

import math

from formula_tourney.report.claims.evaluate import ClaimResult, Comparison
from formula_tourney.report.table_model import DASH, ReportTable

GROUP = "claims"
METRICS = ["verdict", "effect", "95% CI", "P(A better)", "P 95% CI", "runs A/B", "seeds",
           "sequential", "95% CS", "CS pairs", "CPU-h more"]
"""Columns: the verdict, A's advantage in the claim's unit with its CI, the probability that a
run of A beats a run of B with its CI, the runs compared, the seeds per group a clear answer
needs at the observed spread, the anytime-valid verdict with its confidence sequence (the
one a sequential run decides on), the pairs that sequence would need to decide at the
observed mean and the CPU-hours of those still to run."""


def _num(value: float, digits: int = 2, sign: bool = True) -> str:
    if not math.isfinite(value):
        return DASH
    return f"{value:+.{digits}f}" if sign else f"{value:.{digits}f}"


def _ci(low: float, high: float, digits: int = 2) -> str:
    if not (math.isfinite(low) and math.isfinite(high)):
        return DASH
    return f"[{low:+.{digits}f}, {high:+.{digits}f}]"


def _cs(res: ClaimResult, comp: Comparison, digits: int) -> str:
    """The confidence sequence in the claim's unit; a claim decided on wins shows it as the
    probability that a run of A beats one of B (the mean of the +1 / 0 / -1 wins is
    2 P - 1), beside the P(A better) column it makes anytime-valid."""
    seq = comp.stats.sequence
    if seq is None or not seq.n:
        return DASH
    if res.claim.decide_on == "wins":
        return "P " + _ci((seq.low + 1.0) / 2.0, (seq.high + 1.0) / 2.0).replace("+", "")
    return _ci(seq.low, seq.high, digits)


def claims_table(results: list[ClaimResult], origin: str) -> ReportTable:
    """The claims section; ``origin`` says where the claims were declared."""
    table = ReportTable(
        key="claims", title="Claims: findings checked against the runs",
        caption=(
            f"Claims from {origin}. effect: A's advantage over B (lap claims: B's mean best "
            "clean lap minus A's, s; finish claims: percentage points of unseen tracks lapped "
            "cleanly; reward claims: highest moving-average training reward; milestone claims: "
            "CPU-seconds of training to it), 95% percentile "
            "bootstrap CI over runs; P(A better): probability that a run of A beats a run of B "
            "(a run without a clean lap loses), 95% bootstrap CI; runs A/B: runs with a value "
            "(bots count 1); seeds: runs per group for a 5% two-sided test with 80% power at "
            "the observed spread. supported / contradicted: the effect's CI excludes 0; "
            "inconclusive: it does not at this sample size. sequential, 95% CS: the "
            "anytime-valid confidence sequence of the paired differences (claims.sequential: "
            "valid however often it is read, so the verdict of a run that adds seeds until it "
            "decides; a miss counts as the worst bounded value) and its verdict; for a claim "
            "decided on wins, the sequence of who wins each pair, shown as P(A better) (P ...: "
            "decided against 1/2; a miss loses to any result). CS pairs: the "
            "pairs it would need in all to decide if the values seen so far came again in the "
            "same order (a projection; - where it would never decide or need more than 1000); "
            "CPU-h more: those not yet run, at the measured CPU-seconds of a run of each side."
        ),
        groups=[GROUP] if results else [], metrics={GROUP: list(METRICS)} if results else {},
    )
    table.lap_metrics = set()
    if not results:
        table.notes.append("no claims declared")
        return table
    for res in results:
        unit = res.unit
        if not res.comparisons:
            row = table.add_row(res.claim.id, "entrant", res.claim.id)
            for metric in METRICS:
                row["text"][(GROUP, metric)] = res.verdict if metric == "verdict" else DASH
        for comp in res.comparisons:
            label = res.claim.id + (f" {comp.label}" if comp.label else "")
            row = table.add_row(label, "entrant", res.claim.id)
            st = comp.stats
            pct = unit.startswith("%")
            digits = 1 if pct or unit == "reward" else 2
            text = {
                "verdict": st.verdict,
                "effect": _num(st.effect, digits) + (f" {'pp' if pct else unit}"
                                                     if math.isfinite(st.effect) else ""),
                "95% CI": _ci(st.effect_low, st.effect_high, digits),
                "P(A better)": _num(st.prob, 2, sign=False),
                "P 95% CI": _ci(st.prob_low, st.prob_high).replace("+", ""),
                "runs A/B": f"{st.n_a}/{st.n_b}",
                "seeds": str(st.seeds_needed) if st.seeds_needed is not None else DASH,
                "sequential": st.sequential,
                "95% CS": _cs(res, comp, digits),
                "CS pairs": (str(comp.pairs_to_decide) if comp.pairs_to_decide is not None
                             else DASH),
                "CPU-h more": _num(comp.cpu_h_to_decide, 2, sign=False),
            }
            values = {"effect": st.effect, "95% CI": math.nan, "P(A better)": st.prob}
            for metric in METRICS:
                row["text"][(GROUP, metric)] = text[metric]
                row["values"][(GROUP, metric)] = values.get(metric, math.nan)
        why = "; ".join([*res.notes, *(f"{c.label or 'comparison'}: {c.note}"
                                       for c in res.comparisons if c.note)])
        table.notes.append(
            f"{res.claim.id} ({res.verdict}): {res.claim.statement}. A = {res.claim.a.describe()};"
            f" B = {res.claim.b.describe()}" + (f". {why}" if why else "")
            + (f" [{res.claim.source}]" if res.claim.source else "")
            + f" (sequential verdict: {res.sequential})"
        )
        table.records.append(res.to_json())
    return table
