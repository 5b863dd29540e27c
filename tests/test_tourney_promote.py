"""Promotion: best per family by aLT, top k overall, minimum finish rate, deterministic ties."""

from __future__ import annotations

import math

from formula_tourney.tourney.promote import promote, rank_entrants
from formula_tourney.tourney.spec import Promotion


def jobs(entrant: str, family: str, laps: list[float | None], failed: int = 0) -> list[dict]:
    variant = entrant.split("-")[0]
    rows = [
        {"entrant": entrant, "variant": variant, "family": family, "status": "done",
         "best_lap_s": math.nan if lap is None else lap}
        for lap in laps
    ]
    rows += [{"entrant": entrant, "variant": variant, "family": family, "status": "failed",
              "best_lap_s": None}] * failed
    return rows


ROWS = (
    jobs("WIN1-MOT", "DDPG", [26.75, 27.57])          # aLT 27.16, bLT 26.75
    + jobs("WIN4-MOT", "DDPG", [26.77, 27.15])        # aLT 26.96 (best DDPG by aLT)
    + jobs("MS4-MOT", "MS", [26.83, 27.25])           # aLT 27.04
    + jobs("MS2-MOT", "MS", [26.79, None])            # one seed never lapped: finish rate 0.5
    + jobs("PER1M-MOT", "PER", [27.06, 37.54])        # aLT 32.30
    + jobs("LSTM4-MOT", "LSTM", [27.35, 27.69], failed=1)  # 2 of 3 seeds: rate 0.67
    + jobs("LSTM8-MOT", "LSTM", [None, None])         # no clean lap at all
)


def test_ranking_is_alt_over_seeds_with_finish_rate() -> None:
    ranking = {r["entrant"]: r for r in rank_entrants(ROWS)}
    assert math.isclose(ranking["WIN4-MOT"]["aLT"], 26.96)
    assert ranking["WIN1-MOT"]["bLT"] == 26.75
    assert ranking["MS2-MOT"]["finish_rate"] == 0.5 and ranking["MS2-MOT"]["aLT"] == 26.79
    assert math.isclose(ranking["LSTM4-MOT"]["finish_rate"], 2 / 3)
    assert ranking["LSTM4-MOT"]["failed"] == 1
    assert ranking["LSTM8-MOT"]["aLT"] is None
    order = [r["entrant"] for r in rank_entrants(ROWS)]
    assert order[0] == "MS2-MOT" and order[-1] == "LSTM8-MOT"


def test_best_per_family_like_the_paper() -> None:
    variants, rows = promote(rank_entrants(ROWS), Promotion(min_finish_rate=0.6))
    # The paper's part 1 -> part 2: WIN4, MS4, PER1M, LSTM4 (MS2 fails the finish rate here).
    assert variants == ["WIN4", "MS4", "LSTM4", "PER1M"]
    decisions = {r["entrant"]: r["decision"] for r in rows}
    assert decisions["WIN1-MOT"] == "not best of family DDPG"
    assert decisions["MS2-MOT"] == "finish rate 0.50 < 0.6"
    assert decisions["LSTM8-MOT"] == "no clean lap"


def test_without_finish_rate_the_half_finisher_wins_its_family() -> None:
    variants, _ = promote(rank_entrants(ROWS), Promotion())
    assert variants[0] == "MS2"


def test_top_k_overall_and_bLT_metric() -> None:
    variants, rows = promote(rank_entrants(ROWS),
                             Promotion(best_per_family=False, top_k=2, min_finish_rate=1.0))
    assert variants == ["WIN4", "MS4"]
    assert {r["entrant"]: r["decision"] for r in rows}["WIN1-MOT"] == "outside top 2"
    variants, _ = promote(rank_entrants(ROWS),
                          Promotion(metric="bLT", best_per_family=False, top_k=1))
    assert variants == ["WIN1"]


def test_setups_of_one_variant_promote_it_once() -> None:
    rows = jobs("PER1M-RC", "PER", [67.2]) + jobs("PER1M-MOT", "PER", [71.8]) + jobs(
        "WIN4-RC", "DDPG", [69.9])
    variants, ranked = promote(rank_entrants(rows), Promotion(best_per_family=False, top_k=2))
    assert variants == ["PER1M", "WIN4"]  # k counts variants: PER1M's second setup is no slot
    decisions = {r["entrant"]: r["decision"] for r in ranked}
    assert decisions["PER1M-MOT"] == "variant promoted via PER1M-RC"


def test_nobody_finishing_promotes_nobody() -> None:
    variants, rows = promote(rank_entrants(jobs("WIN1-MOT", "DDPG", [None], failed=2)),
                             Promotion())
    assert variants == [] and rows[0]["decision"] == "no clean lap"
