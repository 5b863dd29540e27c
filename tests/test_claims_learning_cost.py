"""Claims about learning cost (kind learns_faster): CPU-seconds to a milestone from
results.competence, a miss counted as the CPU budget, and their sequential verdict."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError
from report_fixtures import build_tournament, jobs_spec, run_spec

from formula_tourney.claims.schema import Claim
from formula_tourney.report.claims.evaluate import evaluate
from formula_tourney.report.claims.evidence import Scale, compare_scores, sequence_of
from formula_tourney.report.load import load_tournament
from formula_tourney.report.paper_tables import Context
from formula_tourney.results.folder import JobFolder

BUDGET_S = 1000.0
RATE = {"win1": 1.0, "win4": 4.0, "ms3": 2.0, "per1m": 2.0}
"""CPU-seconds per episode of each part1 entrant in the synthetic timing."""


@pytest.fixture(scope="module")
def ctx(tmp_path_factory: pytest.TempPathFactory) -> Context:
    """The fixture tournament, its part1 runs timed (``cpu_s`` = episode x the entrant's rate)
    and given a CPU budget, as a budgeted part's runs are."""
    root = build_tournament(tmp_path_factory.mktemp("cost"))
    for job in jobs_spec():
        if job["part"] != "part1" or job["status"] != "done":
            continue
        folder = JobFolder(root / job["path"])
        spec = run_spec(job)
        spec["schedule"]["budget_cpu_s"] = BUDGET_S
        folder.write_config(spec)
        tests = folder.tests()
        tests = tests.assign(cpu_s=tests["episode"] * RATE[job["entrant"]])
        folder.write_tables(
            folder.episodes().to_dict("records"),
            tests.to_dict("records"),
            folder.laps().to_dict("records"),
        )
        folder.write_summary({**folder.summary(), "track": "oval"})
    return Context.build(load_tournament(root))


def claim(**kw) -> Claim:
    return Claim.model_validate(
        {
            "id": "cost",
            "statement": "s",
            "kind": "learns_faster",
            "milestone": "first_clean_lap",
            **kw,
        }
    )


def test_cpu_seconds_to_the_first_clean_lap_by_hand(ctx: Context) -> None:
    res = evaluate(
        ctx, claim(a={"part": "part1", "entrant": "win1"}, b={"part": "part1", "entrant": "win4"})
    )
    (comp,) = res.comparisons
    # win1's first clean rounds: episodes 100, 100, 200 (seed 2 had no lap at 100), 1 CPU-s
    # each; win4 laps cleanly from episode 100 in every seed, at 4 CPU-s an episode
    assert sorted(comp.a_scores) == [-200.0, -100.0, -100.0]
    assert comp.b_scores == [-400.0] * len(comp.b_scores)
    assert comp.stats.effect == pytest.approx(400.0 - 400.0 / 3)
    assert res.unit == "CPU-s" and comp.stats.sequence is not None
    assert comp.stats.sequence.bound == BUDGET_S  # [0, budget]
    assert comp.stats.verdict == "supported"  # the fixed-sample CI: 3 runs a side
    assert res.sequential == "inconclusive"  # 3 pairs cannot exclude 0 anytime-validly


def test_a_missed_milestone_counts_as_the_budget(ctx: Context) -> None:
    res = evaluate(
        ctx, claim(a={"part": "part1", "entrant": "win1"}, b={"part": "part1", "entrant": "ms3"})
    )
    (comp,) = res.comparisons
    assert all(s == -math.inf for s in comp.b_scores)  # ms3 never laps without damage
    assert comp.stats.prob == 1.0 and comp.stats.verdict == "supported"
    seq = comp.stats.sequence
    assert seq is not None and seq.mean == pytest.approx(BUDGET_S - 400.0 / 3)


def test_a_bot_milestone_needs_the_bot_in_the_part(ctx: Context) -> None:
    res = evaluate(
        ctx, claim(milestone="beat_centre_bot", a={"entrant": "win1"}, b={"entrant": "win4"})
    )
    assert res.verdict == "no data"  # part1 raced no follower on the centre line


def test_the_sequential_verdict_on_synthetic_competence_data() -> None:
    rng = np.random.default_rng(4)
    fast = -rng.uniform(80.0, 160.0, 20)  # reaches its first clean lap in 80-160 CPU-s
    slow = np.where(rng.random(20) < 0.3, -math.inf, -rng.uniform(300.0, 600.0, 20))
    scale = Scale(miss=-BUDGET_S, best=0.0)
    st = compare_scores(fast, slow, sequence=sequence_of(fast, slow, False, False, scale))
    assert st.sequential == "supported" and st.sequence is not None
    assert st.sequence.low > 0.0 and st.sequence.n == 20
    same = -rng.uniform(80.0, 400.0, 24)
    st = compare_scores(
        same[:12], same[12:], sequence=sequence_of(same[:12], same[12:], False, False, scale)
    )
    assert st.sequential == "inconclusive"
    reverse = sequence_of(slow, fast, False, False, scale)
    assert reverse is not None and reverse.verdict == "below"


def test_the_schema_of_a_cost_claim() -> None:
    with pytest.raises(ValidationError, match="needs a milestone"):
        Claim.model_validate(
            {"id": "c", "statement": "s", "kind": "learns_faster", "a": {}, "b": {}}
        )
    with pytest.raises(ValidationError, match="needs that kind"):
        Claim.model_validate(
            {
                "id": "c",
                "statement": "s",
                "kind": "faster",
                "milestone": "first_clean_lap",
                "a": {},
                "b": {},
            }
        )
    with pytest.raises(ValidationError, match="faster"):
        claim(a={}, b={"bot": "follower"})
