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


def test_unfinished_can_be_classified_by_distance() -> None:
    rows = jobs("WIN1-MOT", "DDPG", [None, None]) + jobs("MS2-MOT", "MS", [None, None])
    rows += jobs("PER1M-MOT", "PER", [31.0, None])
    for row, dist in zip(rows, [900.0, 1100.0, 300.0, 500.0, 2300.0, 1200.0], strict=True):
        row["test_distance_m"] = dist
    ranking = rank_entrants(rows)
    assert {r["entrant"]: r["distance_m"] for r in ranking}["WIN1-MOT"] == 1000.0
    strict, _ = promote(ranking, Promotion(best_per_family=False, min_finish_rate=0.5))
    assert strict == ["PER1M"]
    variants, decided = promote(ranking, Promotion(best_per_family=False, top_k=2,
                                                   unfinished="by_distance"))
    assert variants == ["PER1M", "WIN1"]  # finishers first, then the furthest
    decisions = {r["entrant"]: r["decision"] for r in decided}
    assert decisions["MS2-MOT"] == "no clean lap; classified by distance 400 m; outside top 2"


def test_general_model_is_best_on_train_track_among_checkpoints_finishing_unseen(
    tmp_path,
) -> None:
    """Study 2's rule (results.metrics.general_model), read from a job folder's tests.parquet as
    the trainer writes it."""
    import pandas as pd

    from formula_tourney.tourney.outcomes import general_pick

    def row(episode: int, track: str, lap: float | None, start: float = 0.0) -> dict:
        return {"episode": episode, "env_steps": episode * 100, "track": track,
                "start_s_m": start, "finished": lap is not None,
                "best_lap_s": math.nan if lap is None else lap, "laps": int(lap is not None),
                "damage": 0.0, "reward": 0.0, "steps": 10, "termination": "max_steps",
                "checkpoint": f"checkpoints/ep-{episode}.pt", "distance_m": 100.0}

    rows = [
        # episode 100: fast on the train track but does not finish 'flowing'
        row(100, "technical", 66.0), row(100, "oval", 28.0), row(100, "flowing", None),
        # episode 200: finishes everything, 68 s on the train track
        row(200, "technical", 68.0), row(200, "oval", 27.5), row(200, "flowing", 80.0),
        row(200, "flowing", None, start=1000.0),  # 1 of 2 starts: rate 0.5
        # episode 300: finishes everything but slower
        row(300, "technical", 70.0), row(300, "oval", 27.0), row(300, "flowing", 79.0),
    ]
    pd.DataFrame(rows).to_parquet(tmp_path / "tests.parquet")
    tracks = ["technical", "oval", "flowing"]
    pick = general_pick(tmp_path, "p/E/seed-0", "technical", tracks, 0.5)
    assert pick == {"job_id": "p/E/seed-0", "episode": 200, "train_track": "technical",
                    "train_lap_s": 68.0,
                    "laps": {"technical": 68.0, "oval": 27.5, "flowing": 80.0},
                    "checkpoint": "checkpoints/ep-200.pt", "unseen_lapped": 2, "unseen": 2}
    strict = general_pick(tmp_path, "j", "technical", tracks, 1.0)
    assert strict is not None and strict["episode"] == 300
    # a run trained on generated tracks, never tested on them: the checkpoint with clean laps
    # on the most unseen tracks (episodes 200 and 300 lap all three), the least sum breaking
    # the tie (300: 70 + 27 + 79 = 176 s against 68 + 27.5 + 80 = 175.5 s at 200)
    generated = general_pick(tmp_path, "j", "gen-0", tracks, 0.5)
    assert generated is not None and generated["episode"] == 200
    assert math.isnan(generated["train_lap_s"]) and generated["unseen_lapped"] == 3
    assert generated["laps"] == {"technical": 68.0, "oval": 27.5, "flowing": 80.0}
    oval_pick = general_pick(tmp_path, "j", "oval", ["oval", "flowing"], 1.0)
    assert oval_pick is not None and oval_pick["episode"] == 300
    assert general_pick(tmp_path / "missing", "j", "oval", ["oval"], 0.5) is None
    # a damaged lap is no clean lap: episode 300's oval lap no longer counts
    rows[-2]["damage"] = 1.0
    pd.DataFrame(rows).to_parquet(tmp_path / "tests.parquet")
    assert general_pick(tmp_path, "j", "oval", ["oval", "flowing"], 0.5)["train_lap_s"] == 27.5
